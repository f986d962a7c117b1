/* Host stub: what reaches the motors (the firmware's drivers/interface/motors.h). */
#ifndef STUB_MOTORS_H_
#define STUB_MOTORS_H_
#include <stdint.h>
uint16_t motorsGetRatio(uint32_t id);
#endif
