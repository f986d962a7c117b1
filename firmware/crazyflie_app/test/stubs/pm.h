/* Host stub: battery voltage. */
#ifndef STUB_PM_H_
#define STUB_PM_H_
float pmGetBatteryVoltage(void);
#endif
