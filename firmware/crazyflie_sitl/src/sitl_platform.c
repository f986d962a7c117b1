/*
 * sitl_platform.c - the platform-specific half of the firmware's platform layer (replaces platform_<p>.c,
 * platform_stm32f4.c and platform_utils.c: OTP device type, NVIC/EXTI, radio power). The firmware's platform.c is
 * compiled unmodified on top of it. The device type string is the one the real board carries in its OTP; the motor
 * maps are the firmware's own (motors_def.c), as platform_<p>.c names them.
 */
#include <string.h>

#include "autoconf.h"
#include "motors.h"
#include "platform.h"

static platformConfig_t configs[] = {
#if defined(CONFIG_PLATFORM_CF21BL)
  {
    .deviceType = "C21B",
    .deviceTypeName = "Crazyflie 2.1 Brushless (SITL)",
    .sensorImplementation = SensorImplementation_bmi088_bmp3xx,
    .physicalLayoutAntennasAreClose = true,
    .motorMap = motorMapCF21Brushless,
  },
#elif defined(CONFIG_PLATFORM_BOLT)
  {
    .deviceType = "RZ10",
    .deviceTypeName = "Crazyflie Bolt (SITL)",
    .sensorImplementation = SensorImplementation_bmi088_spi_bmp3xx,
    .physicalLayoutAntennasAreClose = false,
    .motorMap = motorMapBoltBrushless,
  },
#else
  {
    .deviceType = "CF21",
    .deviceTypeName = "Crazyflie 2.1 (SITL)",
    .sensorImplementation = SensorImplementation_bmi088_bmp3xx,
    .physicalLayoutAntennasAreClose = true,
    .motorMap = motorMapDefaultBrushed,
  },
#endif
};

const platformConfig_t *platformGetListOfConfigurations(int *nrOfConfigs) {
  *nrOfConfigs = (int)(sizeof(configs) / sizeof(configs[0]));
  return configs;
}

void platformInitHardware(void) {}

const char *platformConfigGetPlatformName(void) {
#if defined(CONFIG_PLATFORM_CF21BL)
  return "cf21bl";
#elif defined(CONFIG_PLATFORM_BOLT)
  return "bolt";
#else
  return "cf2";
#endif
}

void platformGetDeviceTypeString(char *deviceTypeString) {
  /* What platform_stm32f4.c reads from the OTP: "0;<type>" */
  strcpy(deviceTypeString, "0;");
  strcat(deviceTypeString, configs[0].deviceType);
}

void platformSetLowInterferenceRadioMode(void) {}
