/*
 * sitl_pm.c - our implementation of the firmware's pm.h (replaces hal/src/pm_stm32f4.c: ADC, charger pins, the
 * nRF51's battery reports): the battery voltage is the simulator's (sensor datagram, under load). No charger. The
 * usual pm log variables (pm.vbat, pm.vbatMV, pm.state, pm.batteryLevel) are served.
 */
#include "FreeRTOS.h"
#include "task.h"

#include "log.h"
#include "pm.h"

#include "sitl.h"

#define LOW_VOLTAGE 3.2f   /* per cell, like the firmware's PM_BAT_LOW_VOLTAGE */
#define FULL_VOLTAGE 4.2f
#define EMPTY_VOLTAGE 3.0f

static float vbat, vbatMin, vbatMax;
static uint16_t vbatMV;
static int8_t pmState;
static uint8_t batteryLevel;

static void update(void) {
  const sitlSensorSample_t *s = sitlLatestSample();
  if (s == NULL) {
    return;
  }
  vbat = s->vbat;
  vbatMV = (uint16_t)(vbat > 0.0f ? vbat * 1000.0f : 0.0f);
  if (vbatMin == 0.0f || vbat < vbatMin) vbatMin = vbat;
  if (vbat > vbatMax) vbatMax = vbat;
  float level = (vbat - EMPTY_VOLTAGE) / (FULL_VOLTAGE - EMPTY_VOLTAGE) * 100.0f;
  batteryLevel = (uint8_t)(level < 0.0f ? 0.0f : level > 100.0f ? 100.0f : level);
  pmState = (int8_t)(vbat < LOW_VOLTAGE ? lowPower : battery);
}

void pmInit(void) {}
bool pmTest(void) { return true; }
void pmTask(void *param) { (void)param; for (;;) vTaskDelay(portMAX_DELAY); }
void pmSetChargeState(PMChargeStates chgState) { (void)chgState; }
void pmSyslinkUpdate(SyslinkPacket *slp) { (void)slp; }

float pmGetBatteryVoltage(void) {
  update();
  return vbat;
}
float pmGetBatteryVoltageMin(void) { update(); return vbatMin; }
float pmGetBatteryVoltageMax(void) { update(); return vbatMax; }
void pmBatteryUpdate(AdcGroup *adcValues) { (void)adcValues; }
bool pmIsBatteryLow(void) { update(); return vbat < LOW_VOLTAGE; }
bool pmIsChargerConnected(void) { return false; }
bool pmIsCharging(void) { return false; }
bool pmIsDischarging(void) { return true; }
void pmEnableExtBatteryVoltMeasuring(const deckPin_t pin, float multiplier) { (void)pin; (void)multiplier; }
float pmMeasureExtBatteryVoltage(void) { return 0.0f; }
void pmEnableExtBatteryCurrMeasuring(const deckPin_t pin, float ampPerVolt) { (void)pin; (void)ampPerVolt; }
float pmMeasureExtBatteryCurrent(void) { return 0.0f; }
void pmIgnoreChargedState(bool ignore) { (void)ignore; }
bool pmRegisterGracefulShutdownCallback(graceful_shutdown_callback_t cb) { (void)cb; return true; }
void pmSystemShutdownSTM(void) { sitlExit(SITL_EXIT_POWER_OFF); }

LOG_GROUP_START(pm)
LOG_ADD_CORE(LOG_FLOAT, vbat, &vbat)
LOG_ADD(LOG_UINT16, vbatMV, &vbatMV)
LOG_ADD_CORE(LOG_INT8, state, &pmState)
LOG_ADD_CORE(LOG_UINT8, batteryLevel, &batteryLevel)
LOG_GROUP_STOP(pm)
