/*
 * FreeRTOSConfig.h for the SITL build (FreeRTOS-Kernel POSIX port, Linux). Our own file: it takes the firmware's
 * own src/config/FreeRTOSConfig.h from the checkout (next on the include path, unmodified) and overrides only what
 * the POSIX port needs otherwise.
 */
#ifndef SITL_FREERTOS_CONFIG_H
#define SITL_FREERTOS_CONFIG_H

#include "trace.h" /* ours, first: its guard keeps the firmware's ITM trace hooks out of the kernel */
#include_next <FreeRTOSConfig.h>

/* Tasks run on pthread stacks: the port cannot check them, and heap_3 is the host's malloc. */
#undef configCHECK_FOR_STACK_OVERFLOW
#define configCHECK_FOR_STACK_OVERFLOW 0
#undef configUSE_MALLOC_FAILED_HOOK
#define configUSE_MALLOC_FAILED_HOOK 0
/* The idle hook (sitl_main.c) sleeps instead of spinning a host core. */
#undef configUSE_IDLE_HOOK
#define configUSE_IDLE_HOOK 1
/* The Cortex-M port's handler names: nothing of the kind on the POSIX port. */
#undef xPortPendSVHandler
#undef xPortSysTickHandler
#undef vPortSVCHandler
/* What the firmware's sources use beyond its config (static task allocation, scheduler and task queries). */
#define configSUPPORT_DYNAMIC_ALLOCATION 1
#define configUSE_RECURSIVE_MUTEXES 1
#define configUSE_COUNTING_SEMAPHORES 1
#define configUSE_TRACE_FACILITY 1
#define configUSE_STATS_FORMATTING_FUNCTIONS 1
#define INCLUDE_xTaskGetSchedulerState 1
#define INCLUDE_xTaskGetCurrentTaskHandle 1
#define INCLUDE_eTaskGetState 1

#endif /* SITL_FREERTOS_CONFIG_H */
