/*
 * trace.h for the SITL build: shadows the firmware's src/config/trace.h, whose FreeRTOS trace hooks write to the
 * Cortex-M ITM registers at 0xE0000000 (a segfault on Linux). Our FreeRTOSConfig.h includes this file before the
 * firmware's config.h, and the shared include guard keeps config.h's own trace.h out. No trace hooks here.
 */
#ifndef SITL_TRACE_H_
#define SITL_TRACE_H_
#define __TRACE_H__
#endif
