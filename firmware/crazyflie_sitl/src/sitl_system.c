/*
 * sitl_system.c - our implementation of the firmware's system.h (replaces src/modules/src/system.c, which reads
 * the STM32's ID registers, talks to the nRF51 over syslink and starts the watchdog), plus cfassert.h (replaces
 * cfassert.c: NVIC reset, CoreDebug registers), usec_time.h (CLOCK_MONOTONIC) and console.h (replaces console.c,
 * which inspects the Cortex-M ICSR register: lines go to stderr and to the CRTP console port).
 *
 * The system task starts the same modules, in the same order, as the firmware's system task does for a build
 * without decks: crtp, console, the supervisor's CRTP port, storage, worker, pm, the app; then comm (the firmware's
 * comm.c: our UDP link through radiolinkGetLink(), crtpservice, platformservice, log, param, localization service),
 * commander, stabilizer (sensors, estimator, controller, power distribution, motors), then the self tests and
 * systemStart(), which releases every task waiting in systemWaitStart().
 */
#include <stdarg.h>
#include <string.h>
#include <time.h>

#include "FreeRTOS.h"
#include "semphr.h"
#include "task.h"

#include "app.h"
#include "cfassert.h"
#include "comm.h"
#include "commander.h"
#include "config.h"
#include "console.h"
#include "crtp.h"
#include "crtp_mem.h"
#include "crtp_supervisor.h"
#include "mem.h"
#include "estimator.h"
#include "motors.h"
#include "param.h"
#include "platform.h"
#include "pm.h"
#include "stabilizer.h"
#include "static_mem.h"
#include "storage.h"
#include "system.h"
#include "usec_time.h"
#include "worker.h"

#include "sitl.h"

/* ---------------------------------------------------------------------------------------------- system.h */

static bool isInit;
static bool selftestPassed;
static SemaphoreHandle_t canStartMutex;
static StaticSemaphore_t canStartMutexBuffer;

STATIC_MEM_TASK_ALLOC(systemTask, SYSTEM_TASK_STACKSIZE);
static void systemTask(void *arg);

void systemLaunch(void) {
  STATIC_MEM_TASK_CREATE(systemTask, systemTask, SYSTEM_TASK_NAME, NULL, SYSTEM_TASK_PRI);
}

void systemInit(void) {
  if (isInit) {
    return;
  }
  canStartMutex = xSemaphoreCreateMutexStatic(&canStartMutexBuffer);
  xSemaphoreTake(canStartMutex, portMAX_DELAY);
  crtpInit();
  consoleInit();
  crtpSupervisorInit();
  storageInit();
  workerInit();
  pmInit();
#ifdef CONFIG_APP_ENABLE
  appInit();
#endif
  isInit = true;
}

bool systemTest(void) {
  return isInit && pmTest() && workerTest();
}

static void check(bool pass, const char *what, bool *all) {
  if (!pass) {
    sitlLog("SYS: %s [FAIL]\n", what);
    *all = false;
  }
}

static void systemTask(void *arg) {
  (void)arg;
  usecTimerInit();
  systemInit();
  commInit();
  commanderInit();
  memInit();
  stabilizerInit(StateEstimatorTypeAutoSelect);
  crtpMemInit();

  bool pass = true;
  check(systemTest(), "system", &pass);
  check(storageTest(), "storage", &pass);
  check(commTest(), "comm", &pass);
  check(commanderTest(), "commander", &pass);
  check(stabilizerTest(), "stabilizer", &pass);
  check(memTest(), "mem", &pass);
  check(crtpMemTest(), "CRTP mem", &pass);
  if (pass) {
    sitlLog("SYS: self test passed, %s (%s) up\n", platformConfigGetDeviceTypeName(), platformConfigGetPlatformName());
    selftestPassed = true;
    systemStart();
  } else {
    /* Like the firmware: do not start; system.selftestPassed can force it from a client. */
    sitlLog("SYS: self test failed, waiting for system.selftestPassed=1\n");
    while (!selftestPassed) {
      vTaskDelay(M2T(200));
    }
    systemStart();
  }
  for (;;) {
    vTaskDelay(portMAX_DELAY);
  }
}

void systemStart(void) {
  xSemaphoreGive(canStartMutex);
}

void systemWaitStart(void) {
  while (!isInit) {
    vTaskDelay(2);
  }
  xSemaphoreTake(canStartMutex, portMAX_DELAY);
  xSemaphoreGive(canStartMutex);
}

void systemRequestShutdown(void) { sitlExit(SITL_EXIT_POWER_OFF); }
void systemRequestShutdownSTM(void) { sitlExit(SITL_EXIT_POWER_OFF); }
void systemRequestNRFVersion(void) {}
void systemSendRadioReady(void) {}
void systemSyslinkReceive(void) {}

/* The firmware's system.c serves the MCU's unique id from its ID registers; ours comes from --uid. */
PARAM_GROUP_START(cpu)
PARAM_ADD_CORE(PARAM_UINT32 | PARAM_RONLY, id0, &sitlOptions.uid[0])
PARAM_ADD_CORE(PARAM_UINT32 | PARAM_RONLY, id1, &sitlOptions.uid[1])
PARAM_ADD_CORE(PARAM_UINT32 | PARAM_RONLY, id2, &sitlOptions.uid[2])
PARAM_GROUP_STOP(cpu)

PARAM_GROUP_START(system)
/**
 * @brief All tests passed when booting (SITL: the tests of the modules the SITL starts)
 */
PARAM_ADD_CORE(PARAM_INT8 | PARAM_RONLY, selftestPassed, &selftestPassed)
PARAM_GROUP_STOP(system)

/* ---------------------------------------------------------------------------------------------- cfassert.h */

void assertFail(char *exp, char *file, int line) {
  portDISABLE_INTERRUPTS();
  sitlLog("ASSERT failed: %s at %s:%d\n", exp, file, line);
  motorsStop();
  sitlExit(SITL_EXIT_ASSERT);
}

void printAssertSnapshotData(void) { sitlLog("No assert information found\n"); }
void storeAssertFileData(const char *file, int line) { (void)file; (void)line; }
void storeAssertHardfaultData(unsigned int r0, unsigned int r1, unsigned int r2, unsigned int r3, unsigned int r12,
                              unsigned int lr, unsigned int pc, unsigned int psr) {
  (void)r0; (void)r1; (void)r2; (void)r3; (void)r12; (void)lr; (void)pc; (void)psr;
}
void storeAssertTextData(const char *text) { sitlLog("ASSERT: %s\n", text); }
bool cfAssertNormalStartTest(void) { return true; }

/* ---------------------------------------------------------------------------------------------- usec_time.h */

static uint64_t startNs;

static uint64_t monotonicNs(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

void usecTimerInit(void) {
  if (startNs == 0) {
    startNs = monotonicNs();
  }
}

void usecTimerReset(void) { startNs = monotonicNs(); }

uint64_t usecTimestamp(void) {
  if (startNs == 0) {
    usecTimerInit();
  }
  return (monotonicNs() - startNs) / 1000u;
}

/* ---------------------------------------------------------------------------------------------- console.h */

static CRTPPacket consoleLine;
static char stderrLine[128];
static size_t stderrLength;
static bool consoleIsInit;

void consoleInit(void) {
  consoleLine.size = 0;
  consoleLine.header = CRTP_HEADER(CRTP_PORT_CONSOLE, 0);
  consoleIsInit = true;
}

bool consoleTest(void) { return consoleIsInit; }

static void consoleSendCrtp(void) {
  if (consoleLine.size > 0 && consoleIsInit) {
    crtpSendPacket(&consoleLine); /* non-blocking, like the firmware's console: dropped when the queue is full */
  }
  consoleLine.size = 0;
}

static void stderrFlush(void) {
  if (stderrLength > 0) {
    sitlLog("%.*s", (int)stderrLength, stderrLine);
    stderrLength = 0;
  }
}

int consolePutchar(int ch) {
  taskENTER_CRITICAL();
  if (stderrLength < sizeof stderrLine) {
    stderrLine[stderrLength++] = (char)ch;
  }
  if (ch == '\n' || stderrLength == sizeof stderrLine) {
    stderrFlush();
  }
  consoleLine.data[consoleLine.size++] = (uint8_t)ch;
  if (ch == '\n' || consoleLine.size == CRTP_MAX_DATA_SIZE) {
    consoleSendCrtp();
  }
  taskEXIT_CRITICAL();
  return (unsigned char)ch;
}

int consolePutcharFromISR(int ch) { return consolePutchar(ch); }

int consolePuts(const char *str) {
  int n = 0;
  while (*str) {
    consolePutchar(*str++);
    n++;
  }
  return n;
}

void consoleFlush(void) {
  taskENTER_CRITICAL();
  stderrFlush();
  consoleSendCrtp();
  taskEXIT_CRITICAL();
}
