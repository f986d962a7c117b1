/*
 * motor_protocol.c - decode/encode and the command gate of the motor app (see motor_protocol.h).
 */
#include "motor_protocol.h"

#include <string.h>

static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }

static void put_u16(uint8_t *p, uint16_t v) {
  p[0] = (uint8_t)(v & 0xFFu);
  p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v) {
  put_u16(p, (uint16_t)(v & 0xFFFFu));
  put_u16(p + 2, (uint16_t)(v >> 16));
}

static uint32_t get_u32(const uint8_t *p) { return (uint32_t)get_u16(p) | ((uint32_t)get_u16(p + 2) << 16); }

static void put_f32(uint8_t *p, float v) {
  uint32_t bits;
  memcpy(&bits, &v, sizeof bits); /* IEEE 754 single on both the M4 and the host */
  p[0] = (uint8_t)(bits & 0xFFu);
  p[1] = (uint8_t)((bits >> 8) & 0xFFu);
  p[2] = (uint8_t)((bits >> 16) & 0xFFu);
  p[3] = (uint8_t)(bits >> 24);
}

/* A 12-bit broadcast command scaled to the 16-bit full scale, rounded to nearest. */
static uint16_t widen12(uint32_t v12) {
  return (uint16_t)((v12 * MP_FULL_SCALE + MP_BROADCAST_FULL_SCALE / 2u) / MP_BROADCAST_FULL_SCALE);
}

static mp_status_t decode_broadcast(const uint8_t *buf, size_t len, uint8_t slot, mp_command_t *out) {
  if (len < MP_BROADCAST_HEADER_SIZE) {
    return MP_BAD_LENGTH;
  }
  const uint8_t first = buf[4];
  const uint8_t count = (uint8_t)((buf[1] & MP_BROADCAST_COUNT_MASK) >> MP_BROADCAST_COUNT_SHIFT);
  if (count == 0u || count > MP_BROADCAST_MAX_MODULES ||
      len != MP_BROADCAST_HEADER_SIZE + (size_t)count * MP_BROADCAST_MODULE_SIZE) {
    return MP_BAD_LENGTH;
  }
  if (slot < first || (uint32_t)slot >= (uint32_t)first + count) {
    return MP_NOT_FOR_US;
  }
  const uint8_t *m = buf + MP_BROADCAST_HEADER_SIZE + (size_t)(slot - first) * MP_BROADCAST_MODULE_SIZE;
  /* Four 12-bit values packed little-endian into 48 bits: v0 | v1 << 12 | v2 << 24 | v3 << 36. */
  uint64_t packed = 0;
  for (unsigned i = 0; i < MP_BROADCAST_MODULE_SIZE; i++) {
    packed |= (uint64_t)m[i] << (8u * i);
  }
  out->sequence = get_u16(buf + 2);
  out->armed = (buf[1] & MP_FLAG_ARMED) != 0u;
  out->token = buf[5];
  for (unsigned q = 0; q < 4u; q++) {
    out->counts[q] = widen12((uint32_t)((packed >> (12u * q)) & 0xFFFu));
  }
  return MP_OK;
}

mp_status_t mp_decode_command(const uint8_t *buf, size_t len, uint8_t slot, mp_command_t *out) {
  if (len < 1u) {
    return MP_BAD_LENGTH;
  }
  if (buf[0] == MP_KIND_BROADCAST) {
    return decode_broadcast(buf, len, slot, out);
  }
  if (buf[0] != MP_KIND_COMMAND) {
    return MP_BAD_KIND;
  }
  if (len != MP_COMMAND_SIZE) {
    return MP_BAD_LENGTH;
  }
  out->armed = (buf[1] & MP_FLAG_ARMED) != 0u;
  out->token = buf[2];
  out->sequence = get_u16(buf + 3);
  for (unsigned q = 0; q < 4u; q++) {
    out->counts[q] = get_u16(buf + 5 + 2u * q);
  }
  return MP_OK;
}

bool mp_decode_claim(const uint8_t *buf, size_t len, uint32_t *session) {
  if (len != MP_CLAIM_SIZE || buf[0] != MP_KIND_CLAIM) {
    return false;
  }
  *session = get_u32(buf + 1);
  return *session != 0u;
}

size_t mp_encode_identity(const mp_identity_t *identity, uint8_t *buf, size_t cap) {
  if (cap < MP_IDENTITY_SIZE) {
    return 0;
  }
  buf[0] = MP_KIND_IDENTITY;
  buf[1] = identity->flags;
  buf[2] = identity->token;
  put_u32(buf + 3, identity->session);
  for (unsigned k = 0; k < 3u; k++) {
    put_u32(buf + 7 + 4u * k, identity->uid[k]);
    put_u16(buf + 19 + 2u * k, (uint16_t)identity->acc_mg[k]);
  }
  return MP_IDENTITY_SIZE;
}

size_t mp_encode_state(const mp_state_t *state, uint8_t *buf, size_t cap) {
  if (cap < MP_STATE_SIZE) {
    return 0;
  }
  buf[0] = MP_KIND_STATE;
  buf[1] = state->flags;
  put_u16(buf + 2, state->sequence);
  for (unsigned q = 0; q < 4u; q++) {
    put_u16(buf + 4 + 2u * q, state->counts[q]);
  }
  put_u16(buf + 12, state->battery_mv);
  for (unsigned k = 0; k < 3u; k++) {
    put_f32(buf + 14 + 4u * k, state->gyro[k]);
  }
  put_u16(buf + 26, state->received);
  put_u16(buf + 28, state->dropped);
  return MP_STATE_SIZE;
}

void mp_mailbox_init(mp_mailbox_t *box) { memset(box, 0, sizeof *box); }

bool mp_mailbox_offer(mp_mailbox_t *box, const mp_command_t *cmd, uint32_t now, uint32_t timeout) {
  const bool stale = !box->has_command || mp_ticks_since(now, box->accepted_tick) >= timeout;
  if (!stale && !mp_sequence_after(cmd->sequence, box->latest.sequence)) {
    box->dropped++;
    return false;
  }
  box->latest = *cmd;
  box->has_command = true;
  box->accepted_tick = now;
  box->received++;
  return true;
}

void mp_mailbox_drop(mp_mailbox_t *box) { box->dropped++; }

bool mp_owner_claim(mp_owner_t *owner, mp_mailbox_t *box, uint32_t session, uint32_t now, uint32_t timeout) {
  if (session == 0u) {
    return false;
  }
  if (owner->token != 0u && owner->session == session) {
    return true;
  }
  const bool flying_for_owner = owner->token != 0u && box->has_command && box->latest.armed &&
                                mp_ticks_since(now, box->accepted_tick) < timeout;
  if (flying_for_owner) {
    return false;
  }
  owner->session = session;
  owner->token = (uint8_t)(owner->token % 255u + 1u); /* 1..255: never 0, never the previous owner's */
  box->has_command = false;                           /* the old owner's command is not the new owner's */
  return true;
}

mp_gate_t mp_gate_forces(const mp_mailbox_t *box, uint32_t now, uint32_t timeout, bool locked, bool can_fly,
                         float forces[4]) {
  mp_gate_t gate = MP_GATE_RUN;
  if (locked) {
    gate = MP_GATE_LOCKED;
  } else if (!can_fly) {
    gate = MP_GATE_CANNOT_FLY;
  } else if (!box->has_command) {
    gate = MP_GATE_NO_COMMAND;
  } else if (mp_ticks_since(now, box->accepted_tick) >= timeout) {
    gate = MP_GATE_STALE;
  } else if (!box->latest.armed) {
    gate = MP_GATE_DISARMED;
  }
  for (unsigned q = 0; q < 4u; q++) {
    forces[q] = gate == MP_GATE_RUN ? (float)box->latest.counts[q] / (float)MP_FULL_SCALE : 0.0f;
  }
  return gate;
}
