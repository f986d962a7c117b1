/* Host stub: only the members of the firmware's stabilizer types that the motor app touches. */
#ifndef STUB_STABILIZER_TYPES_H_
#define STUB_STABILIZER_TYPES_H_
#include <stdint.h>
#define STABILIZER_NR_OF_MOTORS 4
typedef uint32_t stabilizerStep_t;
typedef struct { float x, y, z; } Axis3f;
typedef enum { controlModeLegacy = 0, controlModeForceTorque = 1, controlModeForce = 2 } control_mode_t;
typedef struct {
  float normalizedForces[STABILIZER_NR_OF_MOTORS];
  control_mode_t controlMode;
} control_t;
typedef struct { uint32_t timestamp; float thrust; } setpoint_t;
typedef struct { Axis3f acc; Axis3f gyro; } sensorData_t;
typedef struct { Axis3f position; } state_t;
#endif
