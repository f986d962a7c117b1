/*
 * sitl_motors.c - the motor speeds the SITL module reports. The firmware's own motors.c runs unmodified (its ratios,
 * battery compensation, motorPowerSet override and timer/DMA set-up, the last two on zeroed peripheral memory, see
 * sitl_main.c); only motorsGetRPM, which on hardware decodes bidirectional DSHOT captures, is ours: it returns the
 * simulator's rotor speeds from the newest sensor datagram (motors.c's definition is made weak in its object by
 * the Makefile, WEAK_motors).
 */
#include <stddef.h>

#include "autoconf.h"
#include "motors.h"

#include "sitl.h"

#ifndef MOTORS_RPM_INVALID /* motors.h defines it only for bidirectional DSHOT builds */
#define MOTORS_RPM_INVALID UINT16_MAX
#endif

uint16_t motorsGetRPM(uint32_t motorId) {
  const sitlSensorSample_t *s = sitlLatestSample();
  if (motorId >= NBR_OF_MOTORS || s == NULL) {
    return MOTORS_RPM_INVALID;
  }
  return s->rpm[motorId];
}
