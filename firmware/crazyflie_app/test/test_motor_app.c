/*
 * test_motor_app.c - host unit tests of the motor app: the pure protocol and gate (motor_protocol.c) and the
 * firmware glue (motor_app.c) against the stand-ins in fake_firmware.c.
 */
#include <math.h>
#include <string.h>

#include "check.h"
#include "controller.h"
#include "fake_firmware.h"
#include "log.h"
#include "motor_app.h"
#include "motor_protocol.h"
#include "param.h"

int check_failures = 0;
int check_count = 0;

extern const stub_param_t stub_params_motorApp[];
extern const stub_log_t stub_logs_motorApp[];

static uint8_t token = 1; /* the token the tests' ground station holds (the first claim's) */

/* A unicast command as the ground station encodes it (crtp_wire.MotorCommand.pack). */
static size_t command(uint8_t *buf, uint16_t seq, bool armed, uint16_t c0, uint16_t c1, uint16_t c2, uint16_t c3) {
  const uint16_t c[4] = {c0, c1, c2, c3};
  buf[0] = MP_KIND_COMMAND;
  buf[1] = armed ? MP_FLAG_ARMED : 0u;
  buf[2] = token;
  buf[3] = (uint8_t)(seq & 0xFF);
  buf[4] = (uint8_t)(seq >> 8);
  for (int q = 0; q < 4; q++) {
    buf[5 + 2 * q] = (uint8_t)(c[q] & 0xFF);
    buf[6 + 2 * q] = (uint8_t)(c[q] >> 8);
  }
  return MP_COMMAND_SIZE;
}

static void push_command(uint16_t seq, bool armed, uint16_t c) {
  uint8_t buf[MP_COMMAND_SIZE];
  command(buf, seq, armed, c, c, c, c);
  CHECK(fake_push(buf, sizeof buf));
}

static void push_claim(uint32_t session) {
  const uint8_t buf[MP_CLAIM_SIZE] = {MP_KIND_CLAIM, (uint8_t)session, (uint8_t)(session >> 8),
                                      (uint8_t)(session >> 16), (uint8_t)(session >> 24)};
  CHECK(fake_push(buf, sizeof buf));
}

static uint32_t u32_at(const uint8_t *p) {
  return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

/* A fresh module claimed by session 0xC0FFEE (token 1), the identity answer read and discarded. */
static void start_owned(void) {
  fake_reset();
  motorAppInit();
  push_claim(0xC0FFEEu);
  motorAppStep();
  token = 1;
}

static void run_controller(control_t *control, float gyro_deg_s) {
  setpoint_t sp;
  sensorData_t sensors;
  state_t state;
  memset(&sp, 0, sizeof sp);
  memset(&sensors, 0, sizeof sensors);
  memset(&state, 0, sizeof state);
  sensors.gyro.x = gyro_deg_s;
  sensors.gyro.y = -2.0f * gyro_deg_s;
  sensors.gyro.z = 0.5f;
  memset(control, 0, sizeof *control);
  controllerOutOfTree(control, &sp, &sensors, &state, 0);
}

/* -- pure protocol ------------------------------------------------------------------------------------------ */

static void test_decode_unicast(void) {
  uint8_t buf[32];
  mp_command_t cmd;
  token = 0xA5;
  size_t n = command(buf, 0xBEEF, true, 0, 1, 32768, 65535);
  CHECK_EQ_INT(mp_decode_command(buf, n, 0, &cmd), MP_OK);
  CHECK_EQ_INT(cmd.token, 0xA5);
  CHECK_EQ_INT(cmd.sequence, 0xBEEF);
  CHECK(cmd.armed);
  CHECK_EQ_INT(cmd.counts[0], 0);
  CHECK_EQ_INT(cmd.counts[1], 1);
  CHECK_EQ_INT(cmd.counts[2], 32768);
  CHECK_EQ_INT(cmd.counts[3], 65535);
  CHECK_EQ_INT(mp_decode_command(buf, n - 1, 0, &cmd), MP_BAD_LENGTH);
  CHECK_EQ_INT(mp_decode_command(buf, n + 1, 0, &cmd), MP_BAD_LENGTH);
  CHECK_EQ_INT(mp_decode_command(buf, 0, 0, &cmd), MP_BAD_LENGTH);
  buf[0] = 0x81;
  CHECK_EQ_INT(mp_decode_command(buf, n, 0, &cmd), MP_BAD_KIND);
  buf[0] = MP_KIND_COMMAND;
  buf[1] = 0xFE; /* other flag bits do not arm */
  CHECK_EQ_INT(mp_decode_command(buf, n, 0, &cmd), MP_OK);
  CHECK(!cmd.armed);
}

static void test_decode_broadcast(void) {
  /* Two modules, slots 3 and 4: values 0, 4095, 2048, 1 and 4095, 0, 0, 4095, packed 12 bits each. */
  const uint64_t a = 0ull | (4095ull << 12) | (2048ull << 24) | (1ull << 36);
  const uint64_t b = 4095ull | (0ull << 12) | (0ull << 24) | (4095ull << 36);
  /* flags: armed, two modules (bits 1-3); sequence 0x1234; first slot 3; token 9 */
  uint8_t buf[MP_BROADCAST_HEADER_SIZE + 2 * MP_BROADCAST_MODULE_SIZE] = {MP_KIND_BROADCAST, 1 | (2 << 1), 0x34,
                                                                          0x12, 3, 9};
  for (int i = 0; i < 6; i++) {
    buf[6 + i] = (uint8_t)(a >> (8 * i));
    buf[12 + i] = (uint8_t)(b >> (8 * i));
  }
  mp_command_t cmd;
  CHECK_EQ_INT(mp_decode_command(buf, sizeof buf, 3, &cmd), MP_OK);
  CHECK_EQ_INT(cmd.sequence, 0x1234);
  CHECK(cmd.armed);
  CHECK_EQ_INT(cmd.token, 9);
  CHECK_EQ_INT(cmd.counts[0], 0);
  CHECK_EQ_INT(cmd.counts[1], 65535);
  CHECK_EQ_INT(cmd.counts[2], 32776); /* round(2048 * 65535 / 4095) */
  CHECK_EQ_INT(cmd.counts[3], 16);
  CHECK_EQ_INT(mp_decode_command(buf, sizeof buf, 4, &cmd), MP_OK);
  CHECK_EQ_INT(cmd.counts[0], 65535);
  CHECK_EQ_INT(cmd.counts[3], 65535);
  CHECK_EQ_INT(mp_decode_command(buf, sizeof buf, 2, &cmd), MP_NOT_FOR_US);
  CHECK_EQ_INT(mp_decode_command(buf, sizeof buf, 5, &cmd), MP_NOT_FOR_US);
  CHECK_EQ_INT(mp_decode_command(buf, sizeof buf - 1, 3, &cmd), MP_BAD_LENGTH);
  buf[1] = 1 | (5 << 1); /* more modules than fit in 30 bytes */
  CHECK_EQ_INT(mp_decode_command(buf, sizeof buf, 3, &cmd), MP_BAD_LENGTH);
  buf[1] = 1; /* no module */
  CHECK_EQ_INT(mp_decode_command(buf, MP_BROADCAST_HEADER_SIZE, 3, &cmd), MP_BAD_LENGTH);
  buf[1] = 1 | (2 << 1);
  buf[4] = 254; /* slots 254, 255: no overflow of the slot range */
  CHECK_EQ_INT(mp_decode_command(buf, sizeof buf, 255, &cmd), MP_OK);
  CHECK_EQ_INT(mp_decode_command(buf, sizeof buf, 0, &cmd), MP_NOT_FOR_US);
}

static void test_encode_state(void) {
  mp_state_t st = {.flags = 0x0B, .sequence = 0x0102, .counts = {1, 2, 0xFFFF, 0x8000}, .battery_mv = 3987,
                   .gyro = {0.5f, -0.25f, 1.0f}, .received = 7, .dropped = 0xABCD};
  uint8_t buf[MP_STATE_SIZE];
  CHECK_EQ_INT(mp_encode_state(&st, buf, sizeof buf - 1), 0);
  CHECK_EQ_INT(mp_encode_state(&st, buf, sizeof buf), MP_STATE_SIZE);
  const uint8_t expect_head[14] = {0x81, 0x0B, 0x02, 0x01, 1, 0, 2, 0, 0xFF, 0xFF, 0x00, 0x80, 0x93, 0x0F};
  CHECK(memcmp(buf, expect_head, sizeof expect_head) == 0);
  const uint8_t half[4] = {0x00, 0x00, 0x00, 0x3F}; /* 0.5f */
  CHECK(memcmp(buf + 14, half, 4) == 0);
  CHECK_EQ_INT(buf[26], 7);
  CHECK_EQ_INT(buf[28], 0xCD);
  CHECK_EQ_INT(buf[29], 0xAB);
}

static void test_wrap_arithmetic(void) {
  CHECK_EQ_INT(mp_ticks_since(5u, 0xFFFFFFFBu), 10);
  CHECK_EQ_INT(mp_ticks_since(100u, 40u), 60);
  CHECK(mp_sequence_after(1, 0));
  CHECK(mp_sequence_after(0, 0xFFFF));
  CHECK(mp_sequence_after(0x7FFF, 0));
  CHECK(!mp_sequence_after(0x8000, 0));
  CHECK(!mp_sequence_after(5, 5));
  CHECK(!mp_sequence_after(4, 5));
  CHECK(!mp_sequence_after(0xFFFF, 0));
}

static void test_mailbox_latest_wins(void) {
  mp_mailbox_t box;
  mp_mailbox_init(&box);
  mp_command_t c = {.sequence = 10, .armed = true, .counts = {1, 1, 1, 1}};
  CHECK(mp_mailbox_offer(&box, &c, 1000, 100));
  c.sequence = 9; /* reordered: older */
  CHECK(!mp_mailbox_offer(&box, &c, 1001, 100));
  c.sequence = 10; /* duplicate */
  CHECK(!mp_mailbox_offer(&box, &c, 1002, 100));
  c.sequence = 12;
  c.counts[0] = 7;
  CHECK(mp_mailbox_offer(&box, &c, 1003, 100));
  CHECK_EQ_INT(box.latest.counts[0], 7);
  CHECK_EQ_INT(box.received, 2);
  CHECK_EQ_INT(box.dropped, 2);
  /* Wrap of the 16-bit sequence. */
  box.latest.sequence = 0xFFFF;
  c.sequence = 0;
  CHECK(mp_mailbox_offer(&box, &c, 1004, 100));
  /* A restarted ground station (counter anew) is accepted once the old stream is stale. */
  c.sequence = 3;
  box.latest.sequence = 20000; /* 3 is "before" 20000 on the wrapping counter */
  CHECK(!mp_mailbox_offer(&box, &c, 1004 + 99, 100));
  CHECK(mp_mailbox_offer(&box, &c, 1004 + 100, 100));
  CHECK_EQ_INT(box.latest.sequence, 3);
}

static void test_gate(void) {
  mp_mailbox_t box;
  mp_mailbox_init(&box);
  float f[4] = {9, 9, 9, 9};
  CHECK_EQ_INT(mp_gate_forces(&box, 0, 100, false, true, f), MP_GATE_NO_COMMAND);
  CHECK(f[0] == 0.0f && f[3] == 0.0f);
  mp_command_t c = {.sequence = 1, .armed = true, .counts = {0, 65535, 32768, 13107}};
  mp_mailbox_offer(&box, &c, 0xFFFFFFF0u, 100); /* arrives just before the tick counter wraps */
  CHECK_EQ_INT(mp_gate_forces(&box, 0x00000010u, 100, false, true, f), MP_GATE_RUN); /* 32 ticks later */
  CHECK(f[0] == 0.0f && f[1] == 1.0f && fabsf(f[2] - 0.5f) < 1e-4f && fabsf(f[3] - 0.2f) < 1e-6f);
  CHECK_EQ_INT(mp_gate_forces(&box, 0x00000010u, 100, true, true, f), MP_GATE_LOCKED);
  CHECK(f[1] == 0.0f);
  CHECK_EQ_INT(mp_gate_forces(&box, 0x00000010u, 100, false, false, f), MP_GATE_CANNOT_FLY); /* arming */
  CHECK(f[1] == 0.0f);
  CHECK_EQ_INT(mp_gate_forces(&box, 0x00000010u, 100, true, false, f), MP_GATE_LOCKED); /* locked names first */
  CHECK_EQ_INT(mp_gate_forces(&box, 0xFFFFFFF0u + 99u, 100, false, true, f), MP_GATE_RUN);
  CHECK_EQ_INT(mp_gate_forces(&box, 0xFFFFFFF0u + 100u, 100, false, true, f), MP_GATE_STALE);
  CHECK(f[1] == 0.0f);
  c.sequence = 2;
  c.armed = false;
  mp_mailbox_offer(&box, &c, 500, 100);
  CHECK_EQ_INT(mp_gate_forces(&box, 510, 100, false, true, f), MP_GATE_DISARMED);
  CHECK(f[1] == 0.0f);
}

/* -- firmware glue -------------------------------------------------------------------------------------------- */

static void test_commander_once_per_valid_packet(void) {
  start_owned();
  push_command(1, true, 1000);
  push_command(2, true, 2000);
  uint8_t junk[5] = {MP_KIND_COMMAND, 1, 2, 3, 4}; /* too short */
  CHECK(fake_push(junk, sizeof junk));
  uint8_t other[MP_COMMAND_SIZE];
  command(other, 3, true, 0, 0, 0, 0);
  other[0] = 0x42; /* unknown kind */
  CHECK(fake_push(other, sizeof other));
  push_command(2, true, 9999); /* duplicate sequence */
  motorAppStep();
  CHECK_EQ_INT(fake.setpoints, 2);
  CHECK_EQ_INT(fake.last_priority, 2); /* COMMANDER_PRIORITY_CRTP */
  CHECK_EQ_INT(fake.rx_count, 0);       /* the queue was drained in one step */
  control_t control;
  run_controller(&control, 0.0f);
  CHECK_EQ_INT(control.controlMode, controlModeForce);
  CHECK(fabsf(control.normalizedForces[0] - 2000.0f / 65535.0f) < 1e-7f); /* the newest valid one */
  CHECK_EQ_INT(fake.critical_depth, 0);
  CHECK_EQ_INT(fake.max_critical_depth, 1);
}

static void test_zero_unless_armed_fresh_and_unlocked(void) {
  start_owned();
  control_t control;
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] == 0.0f); /* nothing received yet */
  push_command(1, false, 30000);
  motorAppStep();
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] == 0.0f); /* not armed */
  push_command(2, true, 30000);
  motorAppStep();
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] > 0.45f);
  fake.locked = true; /* emergency stop or commander watchdog: the supervisor locked */
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] == 0.0f && control.normalizedForces[3] == 0.0f);
  fake.locked = false;
  fake_advance(MOTOR_APP_COMMAND_TIMEOUT_MS - 1);
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] > 0.45f);
  fake_advance(1); /* the ground station went silent: stop */
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] == 0.0f);
}

static void test_state_answers_commands_only(void) {
  fake_reset();
  motorAppInit();
  fake.battery_v = 3.987f;
  for (int i = 0; i < 20; i++) {
    motorAppStep(); /* nothing arrives: nothing is sent (no backlog for the next ground station to read) */
  }
  CHECK_EQ_INT(fake.tx_count, 0);
  CHECK_EQ_INT(fake.forever_waits, 20); /* blocked, never a timed busy loop */
  push_claim(0xC0FFEEu);
  motorAppStep();
  CHECK_EQ_INT(fake.tx_count, 1); /* the identity, no state */
  CHECK_EQ_INT(fake_last_tx()->data[0], MP_KIND_IDENTITY);
  token = 1;

  push_command(76, false, 0);
  motorAppStep();
  CHECK_EQ_INT(fake.tx_count, 2); /* one command, one state */
  const fake_packet_t *p = fake_last_tx();
  CHECK(p != NULL && p->size == MP_STATE_SIZE && p->data[0] == MP_KIND_STATE);
  CHECK_EQ_INT(p->data[1], MP_STATE_SUPERVISOR_ARMED | MP_STATE_FRESH | MP_STATE_CAN_FLY); /* not armed */
  CHECK_EQ_INT(p->data[12] | (p->data[13] << 8), 3987);

  push_command(77, true, 65535);
  push_command(78, true, 65535);
  push_command(79, true, 32768);
  motorAppStep();
  CHECK_EQ_INT(fake.tx_count, 3); /* one state per batch */
  control_t control;
  fake.flying = true;
  fake.ratios[0] = 36507; /* the power distribution compensated the battery: more than the 32768 commanded */
  fake.ratios[3] = 7000;
  run_controller(&control, 180.0f); /* 180 deg/s about x */
  push_command(80, true, 32768);
  motorAppStep();
  p = fake_last_tx();
  CHECK_EQ_INT(p->data[1],
               MP_STATE_ARMED | MP_STATE_SUPERVISOR_ARMED | MP_STATE_FRESH | MP_STATE_CAN_FLY | MP_STATE_FLYING);
  CHECK_EQ_INT(p->data[2] | (p->data[3] << 8), 80);                  /* sequence echo */
  CHECK_EQ_INT(p->data[4] | (p->data[5] << 8), 36507);               /* the motor ratio, not the command */
  CHECK_EQ_INT(p->data[10] | (p->data[11] << 8), 7000);
  float gx, gy;
  memcpy(&gx, p->data + 14, 4);
  memcpy(&gy, p->data + 18, 4);
  CHECK(fabsf(gx - 3.14159265f) < 1e-5f && fabsf(gy + 6.2831853f) < 1e-5f); /* deg/s -> rad/s */
  CHECK_EQ_INT(p->data[26] | (p->data[27] << 8), 5); /* received */

  fake.can_fly = false; /* arming (brushless RPM check), or disarmed: the controller outputs nothing */
  fake.ratios[0] = 0;
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] == 0.0f && control.normalizedForces[2] == 0.0f);
  push_command(81, true, 32768);
  motorAppStep();
  p = fake_last_tx();
  CHECK_EQ_INT(p->data[1] & MP_STATE_CAN_FLY, 0);
  CHECK_EQ_INT(p->data[4] | (p->data[5] << 8), 0);
}

static void test_send_never_blocks_and_overflow_counts(void) {
  start_owned();
  fake.tx_full = true; /* the ground station does not read: the TX queue is full */
  for (int i = 0; i < 5; i++) {
    push_command((uint16_t)(i + 1), false, 0);
    motorAppStep();
  }
  CHECK_EQ_INT(fake.tx_failed, 5);
  CHECK_EQ_INT(fake.setpoints, 5); /* commands are still taken */
  fake.tx_full = false;
  for (int i = 0; i < FAKE_RX_QUEUE + 3; i++) {
    uint8_t buf[MP_COMMAND_SIZE];
    command(buf, (uint16_t)(i + 6), true, 100, 100, 100, 100);
    fake_push(buf, sizeof buf); /* the last three do not fit */
  }
  motorAppStep();
  const fake_packet_t *p = fake_last_tx();
  CHECK_EQ_INT(p->data[26] | (p->data[27] << 8), 5 + FAKE_RX_QUEUE); /* received */
  CHECK_EQ_INT(p->data[28] | (p->data[29] << 8), 1);                 /* one overflow event */
}

static void test_claim_rules(void) {
  mp_owner_t owner;
  mp_mailbox_t box;
  memset(&owner, 0, sizeof owner);
  mp_mailbox_init(&box);
  mp_command_t c = {.sequence = 1, .armed = true, .token = 0, .counts = {100, 100, 100, 100}};
  CHECK(!mp_owner_accepts(&owner, &c)); /* nobody owns it: nothing is taken, token 0 included */
  CHECK(!mp_owner_claim(&owner, &box, 0u, 0, 100)); /* session 0 is not a session */
  CHECK(mp_owner_claim(&owner, &box, 7u, 0, 100));
  CHECK_EQ_INT(owner.token, 1);
  c.token = 1;
  CHECK(mp_owner_accepts(&owner, &c));
  CHECK(mp_owner_claim(&owner, &box, 7u, 0, 100)); /* a repeated claim keeps the token */
  CHECK_EQ_INT(owner.token, 1);
  mp_mailbox_offer(&box, &c, 1000, 100);
  CHECK(!mp_owner_claim(&owner, &box, 8u, 1050, 100)); /* flying for session 7: refused */
  CHECK_EQ_INT(owner.session, 7);
  CHECK_EQ_INT(owner.token, 1);
  CHECK(mp_owner_claim(&owner, &box, 8u, 1100, 100)); /* its commands went stale: taken over */
  CHECK_EQ_INT(owner.token, 2);
  CHECK(!box.has_command); /* the old owner's command is forgotten */
  CHECK(!mp_owner_accepts(&owner, &c));
  c.armed = false;
  c.token = 2;
  mp_mailbox_offer(&box, &c, 1200, 100);
  CHECK(mp_owner_claim(&owner, &box, 9u, 1210, 100)); /* fresh but disarmed: not flying, taken over */
  owner.token = 255;
  owner.session = 1;
  CHECK(mp_owner_claim(&owner, &box, 10u, 1300, 100));
  CHECK_EQ_INT(owner.token, 1); /* wraps past 255 to 1, never 0 */
  uint8_t buf[MP_CLAIM_SIZE] = {MP_KIND_CLAIM, 0x78, 0x56, 0x34, 0x12};
  uint32_t session = 0;
  CHECK(mp_decode_claim(buf, sizeof buf, &session));
  CHECK_EQ_INT(session, 0x12345678);
  CHECK(!mp_decode_claim(buf, sizeof buf - 1, &session));
  buf[1] = buf[2] = buf[3] = buf[4] = 0;
  CHECK(!mp_decode_claim(buf, sizeof buf, &session));
}

static void test_encode_identity(void) {
  const mp_identity_t id = {.flags = 0x14, .token = 3, .session = 0xA1B2C3D4u,
                            .uid = {0x00370041u, 0x3236510Du, 0x38383432u}, .acc_mg = {-17, 342, -1000}};
  uint8_t buf[MP_IDENTITY_SIZE];
  CHECK_EQ_INT(mp_encode_identity(&id, buf, sizeof buf - 1), 0);
  CHECK_EQ_INT(mp_encode_identity(&id, buf, sizeof buf), MP_IDENTITY_SIZE);
  CHECK_EQ_INT(buf[0], MP_KIND_IDENTITY);
  CHECK_EQ_INT(buf[1], 0x14);
  CHECK_EQ_INT(buf[2], 3);
  CHECK_EQ_INT(u32_at(buf + 3), 0xA1B2C3D4u);
  CHECK_EQ_INT(u32_at(buf + 7), 0x00370041u);
  CHECK_EQ_INT(u32_at(buf + 15), 0x38383432u);
  CHECK_EQ_INT((int16_t)(buf[19] | (buf[20] << 8)), -17);
  CHECK_EQ_INT((int16_t)(buf[23] | (buf[24] << 8)), -1000);
}

static void test_one_owner_at_a_time(void) {
  fake_reset();
  fake.uid[0] = 0x11111111u;
  fake.uid[2] = 0x33333333u;
  motorAppInit();
  control_t control;
  token = 1;
  push_command(1, true, 30000); /* before any claim: dropped */
  motorAppStep();
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] == 0.0f);
  CHECK_EQ_INT(fake_last_tx()->data[28], 1); /* answered, counted as dropped */
  sensorData_t sensors;
  memset(&sensors, 0, sizeof sensors);
  sensors.acc.x = -0.1f; /* a module mounted tilted: gravity partly along -x */
  sensors.acc.z = 0.995f;
  controllerOutOfTree(&control, NULL, &sensors, NULL, 0);

  push_claim(0xAAAA0001u);
  motorAppStep();
  const fake_packet_t *p = fake_last_tx();
  CHECK(p->size == MP_IDENTITY_SIZE && p->data[0] == MP_KIND_IDENTITY);
  CHECK_EQ_INT(p->data[2], 1);
  CHECK_EQ_INT(u32_at(p->data + 3), 0xAAAA0001u);
  CHECK_EQ_INT(u32_at(p->data + 7), 0x11111111u);
  CHECK_EQ_INT(u32_at(p->data + 15), 0x33333333u);
  CHECK_EQ_INT((int16_t)(p->data[19] | (p->data[20] << 8)), -100);
  CHECK_EQ_INT((int16_t)(p->data[23] | (p->data[24] << 8)), 995);
  push_command(2, true, 30000);
  motorAppStep();
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] > 0.45f); /* the owner flies it */

  push_claim(0xBBBB0002u); /* a second ground station: refused while the owner's armed commands are fresh */
  motorAppStep();
  p = fake_last_tx();
  CHECK_EQ_INT(p->data[2], 1);
  CHECK_EQ_INT(u32_at(p->data + 3), 0xAAAA0001u);
  token = 2; /* it guesses the next token: still not the owner's */
  push_command(200, true, 0);
  motorAppStep();
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] > 0.45f);
  token = 0;
  push_command(201, true, 0); /* a sender that never claimed */
  motorAppStep();
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] > 0.45f);

  fake_advance(MOTOR_APP_COMMAND_TIMEOUT_MS); /* the owner went silent: motors stop, the module may be taken */
  push_claim(0xBBBB0002u);
  motorAppStep();
  p = fake_last_tx();
  CHECK_EQ_INT(p->data[2], 2);
  CHECK_EQ_INT(u32_at(p->data + 3), 0xBBBB0002u);
  token = 1;
  push_command(3, true, 30000); /* the old owner comes back: not its module any more */
  motorAppStep();
  run_controller(&control, 0.0f);
  CHECK(control.normalizedForces[0] == 0.0f);
}

static void test_params_and_logs(void) {
  const stub_param_t *version = NULL;
  for (const stub_param_t *p = stub_params_motorApp; p->name != NULL; p++) {
    if (strcmp(p->name, "version") == 0) {
      version = p;
    }
  }
  CHECK(version != NULL);
  CHECK((version->type & PARAM_RONLY) != 0);
  CHECK_EQ_INT(*(const uint8_t *)version->address, MP_PROTOCOL_VERSION);
  int logs = 0;
  for (const stub_log_t *l = stub_logs_motorApp; l->name != NULL; l++) {
    logs += strcmp(l->name, "rx") == 0 || strcmp(l->name, "drop") == 0;
  }
  CHECK_EQ_INT(logs, 2);
}

int main(void) {
  test_decode_unicast();
  test_decode_broadcast();
  test_encode_state();
  test_wrap_arithmetic();
  test_mailbox_latest_wins();
  test_gate();
  test_commander_once_per_valid_packet();
  test_zero_unless_armed_fresh_and_unlocked();
  test_state_answers_commands_only();
  test_send_never_blocks_and_overflow_counts();
  test_claim_rules();
  test_encode_identity();
  test_one_owner_at_a_time();
  test_params_and_logs();
  printf("%d checks, %d failed\n", check_count, check_failures);
  return check_failures == 0 ? 0 : 1;
}
