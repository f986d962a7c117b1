/*
 * sitl_sensors.c - our implementation of the firmware's sensors.h (replaces the IMU/barometer drivers), fed by the
 * sensor socket, and the motor datagram (WIRE.md "Sensors in", "Motors out").
 *
 * Each sensor datagram is one IMU sample and releases one stabilizer step: sensorsWaitDataReady() returns when one
 * has arrived (the real driver waits for the IMU's data-ready interrupt), sensorsAcquire() hands it over, and the
 * gyro and accelerometer go to the estimator queue exactly as the BMI088 driver does. The battery voltage and the
 * rotor speeds of the same datagram become pm's voltage and motorsGetRPM().
 *
 * The motor datagram of a step goes out when the stabilizer task comes back to sensorsWaitDataReady() after that
 * step, i.e. right after powerDistribution/motorsSetRatio (or motorsStop) of the step.
 */
#include <errno.h>
#include <string.h>
#include <sys/socket.h>

#include "FreeRTOS.h"
#include "task.h"

#include "estimator.h"
#include "motors.h"
#include "sensors.h"
#include "supervisor.h"
#include "usec_time.h"

#include "sitl.h"

#define SENSOR_DATAGRAM_SIZE 52 /* struct <4s I d 3f 3f f 4H> */
#define MOTOR_DATAGRAM_SIZE 24

int sitlSensorSocket = -1;

static sitlSensorSample_t latest;
static bool haveSample;
static bool stepPending;        /* a step consumed a sample and its motor datagram is not sent yet */
static uint32_t stepSequence;   /* sensor sequence of that step */
static bool suspended;
static uint32_t sensorDatagrams, badDatagrams, motorDatagrams;

const sitlSensorSample_t *sitlLatestSample(void) { return haveSample ? &latest : NULL; }

static uint16_t le16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t le32(const uint8_t *p) {
  return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static float lef32(const uint8_t *p) {
  uint32_t bits = le32(p);
  float value;
  memcpy(&value, &bits, sizeof value);
  return value;
}
static double lef64(const uint8_t *p) {
  uint64_t bits = (uint64_t)le32(p) | ((uint64_t)le32(p + 4) << 32);
  double value;
  memcpy(&value, &bits, sizeof value);
  return value;
}
static void put16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put32(uint8_t *p, uint32_t v) { for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i)); }

static bool decode(const uint8_t *d, ssize_t n, sitlSensorSample_t *s) {
  if (n != SENSOR_DATAGRAM_SIZE || memcmp(d, "CFSI", 4) != 0) {
    return false;
  }
  s->sequence = le32(d + 4);
  s->simTime = lef64(d + 8);
  for (int i = 0; i < 3; i++) {
    s->acc[i] = lef32(d + 16 + 4 * i);
    s->gyro[i] = lef32(d + 28 + 4 * i);
  }
  s->vbat = lef32(d + 40);
  for (int i = 0; i < 4; i++) {
    s->rpm[i] = le16(d + 44 + 2 * i);
  }
  s->receivedUs = usecTimestamp();
  return true;
}

static void sendMotorDatagram(void) {
  uint8_t d[MOTOR_DATAGRAM_SIZE];
  memset(d, 0, sizeof d);
  memcpy(d, "CFMO", 4);
  put32(d + 4, stepSequence);
  put32(d + 8, xTaskGetTickCount());
  for (int i = 0; i < 4; i++) {
    put16(d + 12 + 2 * i, motorsGetRatio((uint32_t)i));
  }
  d[20] = (uint8_t)(supervisorGetInfoBitfield() & 0xFF);
  for (;;) {
    ssize_t n = sendto(sitlSensorSocket, d, sizeof d, 0, (const struct sockaddr *)&sitlOptions.motorAddr,
                       sizeof sitlOptions.motorAddr);
    if (n < 0 && errno == EINTR) {
      continue;
    }
    break; /* a refused or full socket drops this one: the next step sends a newer one */
  }
  motorDatagrams++;
}

void sensorsInit(void) {}
bool sensorsTest(void) { return sitlSensorSocket >= 0; }
bool sensorsAreCalibrated(void) { return true; } /* the simulator's IMU has no bias to find */
bool sensorsManufacturingTest(void) { return true; }

void sensorsWaitDataReady(void) {
  if (stepPending) {
    sendMotorDatagram();
    stepPending = false;
  }
  uint8_t d[64];
  for (;;) {
    ssize_t n = recv(sitlSensorSocket, d, sizeof d, 0);
    if (n < 0) {
      if (errno != EINTR) {
        vTaskDelay(1); /* nothing there: poll again next tick (no task may block in a system call) */
      }
      continue;
    }
    sitlSensorSample_t s;
    if (!decode(d, n, &s)) {
      badDatagrams++;
      continue;
    }
    taskENTER_CRITICAL();
    latest = s;
    haveSample = true;
    taskEXIT_CRITICAL();
    sensorDatagrams++;
    if (!suspended) {
      return;
    }
  }
}

void sensorsAcquire(sensorData_t *sensors) {
  sitlSensorSample_t s;
  taskENTER_CRITICAL();
  s = latest;
  taskEXIT_CRITICAL();
  memset(sensors, 0, sizeof *sensors);
  sensors->acc.x = s.acc[0];
  sensors->acc.y = s.acc[1];
  sensors->acc.z = s.acc[2];
  sensors->gyro.x = s.gyro[0];
  sensors->gyro.y = s.gyro[1];
  sensors->gyro.z = s.gyro[2];
  sensors->baro.pressure = 1013.25f;
  sensors->baro.temperature = 25.0f;
  sensors->baro.asl = 0.0f;
  sensors->interruptTimestamp = s.receivedUs;

  measurement_t m;
  memset(&m, 0, sizeof m);
  m.type = MeasurementTypeGyroscope;
  m.data.gyroscope.gyro = sensors->gyro;
  estimatorEnqueue(&m);
  m.type = MeasurementTypeAcceleration;
  m.data.acceleration.acc = sensors->acc;
  estimatorEnqueue(&m);

  stepSequence = s.sequence;
  stepPending = true;
}

bool sensorsReadGyro(Axis3f *gyro) {
  const sitlSensorSample_t *s = sitlLatestSample();
  if (!s) return false;
  gyro->x = s->gyro[0]; gyro->y = s->gyro[1]; gyro->z = s->gyro[2];
  return true;
}

bool sensorsReadAcc(Axis3f *acc) {
  const sitlSensorSample_t *s = sitlLatestSample();
  if (!s) return false;
  acc->x = s->acc[0]; acc->y = s->acc[1]; acc->z = s->acc[2];
  return true;
}

bool sensorsReadMag(Axis3f *mag) { (void)mag; return false; }

bool sensorsReadBaro(baro_t *baro) {
  baro->pressure = 1013.25f;
  baro->temperature = 25.0f;
  baro->asl = 0.0f;
  return false;
}

void sensorsSuspend(void) { suspended = true; }
void sensorsResume(void) { suspended = false; }
bool isSensorsSuspended(void) { return suspended; }
void sensorsSetAccMode(accModes accMode) { (void)accMode; }
