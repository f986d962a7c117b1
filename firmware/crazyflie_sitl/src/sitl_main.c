/*
 * sitl_main.c - main() of the SITL build: options, sockets, the copy of .data param_logic.c reads defaults from,
 * then what the firmware's main() does (platformInit, systemLaunch, vTaskStartScheduler). Also the FreeRTOS hooks
 * the POSIX port needs and the process-wide log/exit helpers. Our own code.
 */
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <arpa/inet.h>
#include <sys/mman.h>
#include <sys/socket.h>

#include "FreeRTOS.h"
#include "task.h"

#include "platform.h"
#include "system.h"
#include "usec_time.h"

#include "sitl.h"

sitlOptions_t sitlOptions;

/* Linker symbols (sitl_sections.ld and ld's default script). */
extern char _sdata[], _edata[], _sidata[];

static void usage(const char *argv0) {
  fprintf(stderr,
          "usage: %s --crtp-port P --sensor-port S --motor-addr HOST:PORT [--params FILE] [--uid HEX24]\n"
          "  one Crazyflie module (crazyflie-firmware SITL); sockets on 127.0.0.1, see WIRE.md\n",
          argv0);
  exit(2);
}

static uint16_t parsePort(const char *text, const char *argv0) {
  char *end = NULL;
  long value = strtol(text, &end, 10);
  if (end == text || *end != '\0' || value <= 0 || value > 65535) {
    usage(argv0);
  }
  return (uint16_t)value;
}

static void parseOptions(int argc, char **argv) {
  bool haveCrtp = false, haveSensor = false, haveMotor = false;
  for (int i = 1; i < argc; i++) {
    const char *arg = argv[i];
    const char *value = (i + 1 < argc) ? argv[i + 1] : NULL;
    if (strcmp(arg, "--help") == 0 || strcmp(arg, "-h") == 0) {
      usage(argv[0]);
    }
    if (value == NULL) {
      usage(argv[0]);
    }
    if (strcmp(arg, "--crtp-port") == 0) {
      sitlOptions.crtpPort = parsePort(value, argv[0]);
      haveCrtp = true;
    } else if (strcmp(arg, "--sensor-port") == 0) {
      sitlOptions.sensorPort = parsePort(value, argv[0]);
      haveSensor = true;
    } else if (strcmp(arg, "--motor-addr") == 0) {
      char host[64];
      const char *colon = strrchr(value, ':');
      if (colon == NULL || (size_t)(colon - value) >= sizeof host) {
        usage(argv[0]);
      }
      memcpy(host, value, (size_t)(colon - value));
      host[colon - value] = '\0';
      memset(&sitlOptions.motorAddr, 0, sizeof sitlOptions.motorAddr);
      sitlOptions.motorAddr.sin_family = AF_INET;
      sitlOptions.motorAddr.sin_port = htons(parsePort(colon + 1, argv[0]));
      if (inet_pton(AF_INET, host, &sitlOptions.motorAddr.sin_addr) != 1) {
        usage(argv[0]);
      }
      haveMotor = true;
    } else if (strcmp(arg, "--params") == 0) {
      sitlOptions.paramsFile = value;
    } else if (strcmp(arg, "--uid") == 0) {
      /* cpu.id0 is bytes 0-3 of the 96-bit id, id1 bytes 4-7, id2 bytes 8-11: three groups of 8 hex digits */
      if (strlen(value) != 24 || strspn(value, "0123456789abcdefABCDEF") != 24) {
        usage(argv[0]);
      }
      for (int k = 0; k < 3; k++) {
        char group[9];
        memcpy(group, value + 8 * k, 8);
        group[8] = '\0';
        sitlOptions.uid[k] = (uint32_t)strtoul(group, NULL, 16);
      }
    } else {
      usage(argv[0]);
    }
    i++;
  }
  if (!haveCrtp || !haveSensor || !haveMotor) {
    usage(argv[0]);
  }
}

int sitlUdpBind(uint16_t port) {
  int fd = socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) {
    perror("socket");
    exit(1);
  }
  struct sockaddr_in addr;
  memset(&addr, 0, sizeof addr);
  addr.sin_family = AF_INET;
  addr.sin_port = htons(port);
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (bind(fd, (struct sockaddr *)&addr, sizeof addr) != 0) {
    fprintf(stderr, "cf_sitl: bind 127.0.0.1:%u: %s\n", port, strerror(errno));
    exit(1);
  }
  return fd;
}

/* Logging from FreeRTOS tasks: no stdio (its locks could be held by a task the scheduler has suspended), one
 * write(2) per message. */
void sitlLog(const char *fmt, ...) {
  char buffer[256];
  va_list ap;
  va_start(ap, fmt);
  int n = vsnprintf(buffer, sizeof buffer, fmt, ap);
  va_end(ap);
  if (n < 0) {
    return;
  }
  size_t length = (size_t)n < sizeof buffer ? (size_t)n : sizeof buffer - 1;
  ssize_t ignored = write(STDERR_FILENO, buffer, length);
  (void)ignored;
}

void sitlExit(int status) {
  sitlLog("cf_sitl: exit %d\n", status);
  _exit(status);
}

/* The idle task would spin a host core: sleep until the next tick signal instead. */
void vApplicationIdleHook(void) {
  struct timespec ts = {0, 500 * 1000};
  nanosleep(&ts, NULL);
}

/* Zeroed memory at a fixed address (possible because the binary is not position independent and these ranges are
 * free in a Linux process). */
static void mapZeroed(uintptr_t address, size_t size, const char *what) {
  void *want = (void *)address;
  void *got = mmap(want, size, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_FIXED_NOREPLACE, -1, 0);
  if (got != want) {
    fprintf(stderr, "cf_sitl: cannot map %s at 0x%08lx: %s\n", what, (unsigned long)address, strerror(errno));
    exit(1);
  }
}

/*
 * Unmodified firmware sources touch memory-mapped hardware:
 *  - some read Cortex-M core registers in the private peripheral bus, e.g. estimator.c asks SCB->ICSR whether it
 *    runs in an interrupt: ICSR reads 0 ("thread mode");
 *  - motors.c sets up and drives its timers, GPIO and DMA through the firmware's STM32 standard peripheral library
 *    (compiled unmodified too): its writes land in zeroed memory standing for the STM32F405's APB1, APB2 and AHB1
 *    peripherals, and its status reads see "idle" (a DMA stream reads disabled), so nothing waits.
 */
static void mapHardware(void) {
  mapZeroed(0xE0000000u, 0x100000, "the Cortex-M private peripheral bus");
  mapZeroed(0x40000000u, 0x80000, "the STM32 peripherals (APB1, APB2, AHB1)");
}

int main(int argc, char **argv) {
  parseOptions(argc, argv);
  mapHardware();
  setvbuf(stdout, NULL, _IONBF, 0);

  /* param_logic.c reads a parameter's default from the flash image of .data (_sidata); keep that image. */
  memcpy(_sidata, _sdata, (size_t)(_edata - _sdata));

  sitlCrtpSocket = sitlUdpBind(sitlOptions.crtpPort);
  sitlSensorSocket = sitlUdpBind(sitlOptions.sensorPort);
  sitlStorageLoad(sitlOptions.paramsFile);
  usecTimerInit();

  if (platformInit() != 0) {
    fprintf(stderr, "cf_sitl: platformInit failed\n");
    return 1;
  }
  sitlLog("cf_sitl: %s, CRTP udp 127.0.0.1:%u, sensors udp 127.0.0.1:%u, motors to %s:%u, params %s\n",
          platformConfigGetDeviceTypeName(), sitlOptions.crtpPort, sitlOptions.sensorPort,
          inet_ntoa(sitlOptions.motorAddr.sin_addr), ntohs(sitlOptions.motorAddr.sin_port),
          sitlOptions.paramsFile ? sitlOptions.paramsFile : "(none, not persistent)");

  systemLaunch();
  vTaskStartScheduler();
  fprintf(stderr, "cf_sitl: scheduler returned\n");
  return 1;
}
