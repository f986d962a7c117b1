/* Host stub: log declarations become a table the tests can read (stub_logs_<group>). */
#ifndef STUB_LOG_H_
#define STUB_LOG_H_
#define LOG_UINT16 2
#define LOG_UINT32 3
typedef struct { const char *name; int type; void *address; } stub_log_t;
#define LOG_GROUP_START(NAME) const stub_log_t stub_logs_##NAME[] = {
#define LOG_ADD(TYPE, NAME, ADDRESS) {#NAME, (TYPE), (void *)(ADDRESS)},
#define LOG_GROUP_STOP(NAME) {0, 0, 0}};
#endif
