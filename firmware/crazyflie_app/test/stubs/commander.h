/* Host stub: the commander entry the motor app feeds. */
#ifndef STUB_COMMANDER_H_
#define STUB_COMMANDER_H_
#include "stabilizer_types.h"
#define COMMANDER_PRIORITY_CRTP 2
void commanderSetSetpoint(setpoint_t *setpoint, int priority);
#endif
