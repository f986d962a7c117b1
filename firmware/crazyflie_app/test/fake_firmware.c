/*
 * fake_firmware.c - host stand-ins for the firmware functions declared in test/stubs/ (see fake_firmware.h).
 */
#include "fake_firmware.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app_channel.h"
#include "commander.h"
#include "motors.h"
#include "param.h"
#include "pm.h"
#include "supervisor.h"
#include "task.h"

fake_firmware_t fake;

void fake_reset(void) {
  memset(&fake, 0, sizeof fake);
  fake.battery_v = 4.0f;
  fake.supervisor_armed = true;
  fake.can_fly = true;
}

void fake_advance(uint32_t ticks) { fake.tick += ticks; }

bool fake_push(const uint8_t *data, size_t size) {
  if (fake.rx_count == FAKE_RX_QUEUE) {
    fake.overflow = true;
    return false;
  }
  fake_packet_t *p = &fake.rx[(fake.rx_head + fake.rx_count) % FAKE_RX_QUEUE];
  memcpy(p->data, data, size);
  p->size = size;
  p->tick = fake.tick;
  fake.rx_count++;
  return true;
}

const fake_packet_t *fake_last_tx(void) {
  return fake.tx_count == 0 ? NULL : &fake.tx[(fake.tx_count - 1) % FAKE_TX_KEEP];
}

TickType_t xTaskGetTickCount(void) { return fake.tick; }

paramVarId_t paramGetVarId(const char *group, const char *name) {
  paramVarId_t id = {0xffffu, 0u};
  if (!fake.no_cpu_params && strcmp(group, "cpu") == 0 && strncmp(name, "id", 2) == 0 && name[2] >= '0' &&
      name[2] <= '2' && name[3] == '\0') {
    id.id = (uint16_t)(name[2] - '0');
    id.index = id.id;
  }
  return id;
}

unsigned int paramGetUint(paramVarId_t varid) { return varid.id < 3u ? fake.uid[varid.id] : 0u; }

void fakeEnterCritical(void) {
  fake.critical_depth++;
  if (fake.critical_depth > fake.max_critical_depth) {
    fake.max_critical_depth = fake.critical_depth;
  }
}

void fakeExitCritical(void) {
  if (fake.critical_depth <= 0) {
    fprintf(stderr, "critical section exited more often than entered\n");
    abort();
  }
  fake.critical_depth--;
}

size_t appchannelReceiveDataPacket(void *buffer, size_t max_length, int timeout_ms) {
  fake.receive_calls++;
  if (timeout_ms == APPCHANNEL_WAIT_FOREVER) {
    fake.forever_waits++;
  } else if (timeout_ms > fake.max_wait_ms) {
    fake.max_wait_ms = timeout_ms;
  }
  if (fake.rx_count == 0) {
    if (timeout_ms > 0) {
      fake.tick += (uint32_t)timeout_ms; /* blocked until the timeout */
    }
    return 0;
  }
  fake_packet_t *p = &fake.rx[fake.rx_head];
  fake.rx_head = (fake.rx_head + 1) % FAKE_RX_QUEUE;
  fake.rx_count--;
  const size_t n = p->size < max_length ? p->size : max_length;
  memcpy(buffer, p->data, n);
  return n;
}

int appchannelSendDataPacket(void *data, size_t length) {
  if (fake.tx_full) {
    fake.tx_failed++;
    return 0; /* errQUEUE_FULL */
  }
  fake_packet_t *p = &fake.tx[fake.tx_count % FAKE_TX_KEEP];
  memcpy(p->data, data, length);
  p->size = length;
  p->tick = fake.tick;
  fake.tx_count++;
  return 1; /* pdTRUE */
}

bool appchannelHasOverflowOccurred(void) {
  const bool was = fake.overflow;
  fake.overflow = false;
  return was;
}

void commanderSetSetpoint(setpoint_t *setpoint, int priority) {
  (void)setpoint;
  fake.setpoints++;
  fake.last_priority = priority;
}

bool supervisorIsLocked(void) { return fake.locked; }

bool supervisorIsArmed(void) { return fake.supervisor_armed; }

bool supervisorCanFly(void) { return fake.can_fly && !fake.locked; }

bool supervisorIsFlying(void) { return fake.flying; }

uint16_t motorsGetRatio(uint32_t id) { return id < 4u ? fake.ratios[id] : 0u; }

float pmGetBatteryVoltage(void) { return fake.battery_v; }
