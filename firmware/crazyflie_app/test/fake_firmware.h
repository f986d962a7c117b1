/*
 * fake_firmware.h - controls of the host stand-ins for the firmware functions the motor app calls.
 *
 * Time only moves when a test moves it (fake_advance) or when the app waits on an empty app channel: a
 * receive with timeout T on an empty queue returns 0 after advancing the tick by T, as the real call would.
 */
#ifndef FAKE_FIRMWARE_H_
#define FAKE_FIRMWARE_H_

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define FAKE_RX_QUEUE 10 /* the firmware's app-channel receive queue holds 10 packets */
#define FAKE_TX_KEEP 64

typedef struct {
  uint8_t data[32];
  size_t size;
  uint32_t tick;
} fake_packet_t;

typedef struct {
  uint32_t tick;
  int critical_depth;
  int max_critical_depth;
  /* app channel, ground -> module */
  fake_packet_t rx[FAKE_RX_QUEUE];
  size_t rx_head, rx_count;
  bool overflow;
  int receive_calls;
  int max_wait_ms;      /* longest timeout the app asked for */
  int forever_waits;    /* receives with APPCHANNEL_WAIT_FOREVER */
  /* app channel, module -> ground */
  fake_packet_t tx[FAKE_TX_KEEP];
  size_t tx_count;      /* packets sent (the last FAKE_TX_KEEP kept) */
  bool tx_full;         /* the TX queue is full: non-blocking sends fail */
  int tx_failed;
  /* commander, supervisor, power */
  int setpoints;
  int last_priority;
  bool locked;
  bool supervisor_armed;
  bool can_fly;
  bool flying;
  uint16_t ratios[4]; /* what motorsGetRatio returns: the power distribution's output */
  float battery_v;
  /* parameters */
  uint32_t uid[3];     /* cpu.id0..id2 */
  bool no_cpu_params;  /* a build without the cpu group: lookups fail */
} fake_firmware_t;

extern fake_firmware_t fake;

void fake_reset(void);
void fake_advance(uint32_t ticks);
/* Queue a packet on the app channel as the platform task would; false (and the overflow flag) when full. */
bool fake_push(const uint8_t *data, size_t size);
const fake_packet_t *fake_last_tx(void);

#endif /* FAKE_FIRMWARE_H_ */
