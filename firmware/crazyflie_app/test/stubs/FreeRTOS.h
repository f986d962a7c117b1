/* Host stub (ours, not the firmware's): the few FreeRTOS definitions the motor app uses. Crazyflie runs the
 * kernel at 1000 Hz, so ticks are milliseconds, as M2T/T2M in the firmware's FreeRTOSConfig.h. */
#ifndef STUB_FREERTOS_H_
#define STUB_FREERTOS_H_
#include <stdint.h>
#define M2T(X) ((unsigned int)(X))
#define T2M(X) ((unsigned int)(X))
typedef uint32_t TickType_t;
#endif
