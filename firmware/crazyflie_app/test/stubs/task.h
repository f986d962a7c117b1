/* Host stub: tick counter and critical sections, implemented by fake_firmware.c. */
#ifndef STUB_TASK_H_
#define STUB_TASK_H_
#include "FreeRTOS.h"
TickType_t xTaskGetTickCount(void);
void fakeEnterCritical(void);
void fakeExitCritical(void);
#define taskENTER_CRITICAL() fakeEnterCritical()
#define taskEXIT_CRITICAL() fakeExitCritical()
#endif
