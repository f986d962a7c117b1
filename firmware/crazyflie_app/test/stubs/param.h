/* Host stub: parameter declarations become a table the tests can read (stub_params_<group>). */
#ifndef STUB_PARAM_H_
#define STUB_PARAM_H_
#include <stdint.h>
#define PARAM_UINT8 0x08
#define PARAM_UINT16 0x09
#define PARAM_RONLY (1 << 6)
typedef struct { const char *name; int type; void *address; } stub_param_t;
#define PARAM_GROUP_START(NAME) const stub_param_t stub_params_##NAME[] = {
#define PARAM_ADD(TYPE, NAME, ADDRESS) {#NAME, (TYPE), (void *)(ADDRESS)},
#define PARAM_GROUP_STOP(NAME) {0, 0, 0}};
/* The firmware's parameter lookup (param_logic.h), served by the fake from fake.uid for group "cpu". */
typedef struct { uint16_t id; uint16_t index; } paramVarId_t;
#define PARAM_VARID_IS_VALID(varId) (varId.id != 0xffffu)
paramVarId_t paramGetVarId(const char *group, const char *name);
unsigned int paramGetUint(paramVarId_t varid);
#endif
