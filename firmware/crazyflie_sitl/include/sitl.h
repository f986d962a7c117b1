/*
 * sitl.h - what the SITL HAL files share (our own code). The wire formats are in WIRE.md.
 */
#ifndef SITL_H_
#define SITL_H_

#include <stdbool.h>
#include <stdint.h>
#include <netinet/in.h>

#define SITL_EXIT_REBOOT 3   /* cflib PowerSwitch reboot (0xFF 0xFE 0xF0): the parent restarts us */
#define SITL_EXIT_POWER_OFF 4 /* 0xFF 0xFE 0x02 */
#define SITL_EXIT_ASSERT 70  /* a firmware ASSERT failed (EX_SOFTWARE) */

typedef struct {
  uint16_t crtpPort;
  uint16_t sensorPort;
  struct sockaddr_in motorAddr;
  const char *paramsFile;
  uint32_t uid[3]; /* the MCU's unique id (--uid, 24 hex digits): served as the parameters cpu.id0..id2 */
} sitlOptions_t;

extern sitlOptions_t sitlOptions;

/* One sensor datagram (WIRE.md "Sensors in"), decoded. */
typedef struct {
  uint32_t sequence;
  double simTime;
  float acc[3];   /* g */
  float gyro[3];  /* deg/s */
  float vbat;     /* V */
  uint16_t rpm[4];
  uint64_t receivedUs; /* usecTimestamp() at reception */
} sitlSensorSample_t;

/* sitl_main.c */
void sitlExit(int status) __attribute__((noreturn));
void sitlLog(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
int sitlUdpBind(uint16_t port);

/* sitl_sensors.c */
extern int sitlSensorSocket;
const sitlSensorSample_t *sitlLatestSample(void);

/* sitl_link.c */
extern int sitlCrtpSocket;

/* sitl_storage.c */
void sitlStorageLoad(const char *path);

#endif /* SITL_H_ */
