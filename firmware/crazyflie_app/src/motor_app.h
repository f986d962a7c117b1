/*
 * motor_app.h - entry points of the motor app's firmware glue (motor_app.c).
 *
 * The firmware calls appMain() and the controllerOutOfTree*() functions; motorAppInit() and motorAppStep() are
 * what appMain() runs, exposed so the host tests can drive the app task one step at a time.
 */
#ifndef MOTOR_APP_H_
#define MOTOR_APP_H_

#define MOTOR_APP_COMMAND_TIMEOUT_MS 100 /* motors stop when no command arrived for this long */

void motorAppInit(void);
void motorAppStep(void);

#endif /* MOTOR_APP_H_ */
