/* Host stub: console prints go nowhere. */
#ifndef STUB_DEBUG_H_
#define STUB_DEBUG_H_
#define DEBUG_PRINT(...) ((void)0)
#endif
