/* Host stub: the app channel calls the motor app makes (signatures as in the firmware's app API). */
#ifndef STUB_APP_CHANNEL_H_
#define STUB_APP_CHANNEL_H_
#include <stdbool.h>
#include <stddef.h>
#define APPCHANNEL_WAIT_FOREVER (-1)
#define APPCHANNEL_MTU (30)
size_t appchannelReceiveDataPacket(void *buffer, size_t max_length, int timeout_ms);
int appchannelSendDataPacket(void *data, size_t length);
bool appchannelHasOverflowOccurred(void);
#endif
