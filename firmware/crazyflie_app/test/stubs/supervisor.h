/* Host stub: the supervisor queries the motor app makes. */
#ifndef STUB_SUPERVISOR_H_
#define STUB_SUPERVISOR_H_
#include <stdbool.h>
bool supervisorIsLocked(void);
bool supervisorIsArmed(void);
bool supervisorCanFly(void);
bool supervisorIsFlying(void);
#endif
