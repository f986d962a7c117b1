/*
 * motor_protocol.h - the motor app's wire format and command gate, free of any firmware header.
 *
 * Pure logic shared by the firmware glue (motor_app.c) and the host unit tests: packet decode/encode, the
 * 1-deep "latest wins" command mailbox, the freshness/arming gate and wrap-safe tick arithmetic. The Python
 * side of the same contract is groundstation/backends/crtp_wire.py; both are checked against one vector file
 * (test/packet_vectors.txt) so they cannot drift.
 *
 * All multi-byte fields are little-endian (the Cortex-M4 and every host we test on are little-endian, but the
 * code assembles bytes explicitly so it does not depend on that).
 */
#ifndef MOTOR_PROTOCOL_H_
#define MOTOR_PROTOCOL_H_

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Version of this contract, served read-only as the parameter motorApp.version. */
#define MP_PROTOCOL_VERSION 3u
/* 2: forces only while the supervisor can fly (flag MP_STATE_CAN_FLY); a state reports the motor ratios that
 * reach the motors; one state per batch of received commands instead of an unprompted 100 Hz stream; flags
 * can fly and flying.
 * 3: one owner at a time. A ground station claims the module with its session id and learns the owner's token,
 * which every command then carries; commands with another token are dropped. A claim is refused while another
 * session's armed commands are fresh. The answer to a claim is the identity report: the owner, the MCU's unique
 * id and the accelerometer (the direction of gravity in the module's frame, at rest). */

/* First byte of every app-channel payload. */
#define MP_KIND_COMMAND 0x01u   /* ground -> one module (unicast) */
#define MP_KIND_BROADCAST 0x02u /* ground -> up to 4 modules in one no-ack packet */
#define MP_KIND_CLAIM 0x03u     /* ground -> one module: become its owner */
#define MP_KIND_STATE 0x81u     /* module -> ground */
#define MP_KIND_IDENTITY 0x82u  /* module -> ground: the answer to a claim */

#define MP_COMMAND_SIZE 13u
#define MP_CLAIM_SIZE 5u
#define MP_IDENTITY_SIZE 25u
#define MP_BROADCAST_HEADER_SIZE 6u
#define MP_BROADCAST_COUNT_SHIFT 1u /* the broadcast's module count sits in bits 1-3 of its flags */
#define MP_BROADCAST_COUNT_MASK 0x0Eu
#define MP_BROADCAST_MODULE_SIZE 6u /* four 12-bit commands */
#define MP_BROADCAST_MAX_MODULES 4u
#define MP_STATE_SIZE 30u
#define MP_MTU 30u /* CRTP payload limit (APPCHANNEL_MTU) */

/* Command flags. */
#define MP_FLAG_ARMED 0x01u

/* State flags. */
#define MP_STATE_ARMED 0x01u            /* the newest command carried the armed flag */
#define MP_STATE_LOCKED 0x02u           /* supervisor locked (emergency stop or watchdog): reboot required */
#define MP_STATE_SUPERVISOR_ARMED 0x04u /* the firmware supervisor is armed */
#define MP_STATE_FRESH 0x08u            /* the newest command is younger than the timeout */
#define MP_STATE_CAN_FLY 0x10u          /* the supervisor lets flight setpoints through (supervisorCanFly) */
#define MP_STATE_FLYING 0x20u           /* the supervisor's Flying or WarningLevelOut state (supervisorIsFlying) */

#define MP_FULL_SCALE 65535u /* a command count of 65535 is normalized force 1.0 */
#define MP_BROADCAST_FULL_SCALE 4095u

/* One module's command: four normalized forces as fractions of full scale, in the module's rotor order. */
typedef struct {
  uint16_t sequence; /* sender's counter (wraps) */
  bool armed;
  uint8_t token;      /* the owner's token the sender was given (mp_owner_t) */
  uint16_t counts[4]; /* 0..65535 */
} mp_command_t;

typedef enum {
  MP_OK = 0,
  MP_BAD_LENGTH,  /* size does not match the kind */
  MP_BAD_KIND,    /* unknown first byte */
  MP_NOT_FOR_US,  /* a broadcast that carries no slot of this module */
} mp_status_t;

/* What the module reports, once per batch of commands it receives (never unprompted: see motor_app.c). */
typedef struct {
  uint8_t flags;      /* MP_STATE_* */
  uint16_t sequence;  /* sequence of the newest command accepted (echo: the ground station's latency probe) */
  uint16_t counts[4]; /* motor ratios that reach the motors (motorsGetRatio), 0..65535 */
  uint16_t battery_mv;
  float gyro[3];      /* body rate, rad/s, module frame */
  uint16_t received;  /* commands accepted (wraps) */
  uint16_t dropped;   /* commands not applied: older than the newest, malformed, or lost to a full queue (wraps) */
} mp_state_t;

/* Who owns the module: the session that claimed it last, and the token its commands carry (0: nobody). */
typedef struct {
  uint32_t session;
  uint8_t token; /* 1..255, a new one at every change of owner */
} mp_owner_t;

/* What the module answers to a claim. */
typedef struct {
  uint8_t flags;       /* MP_STATE_* */
  uint8_t token;       /* the owner's token (the claimant's if the claim succeeded) */
  uint32_t session;    /* the owner's session */
  uint32_t uid[3];     /* the MCU's unique id (parameters cpu.id0..id2) */
  int16_t acc_mg[3];   /* accelerometer, milli-g, module frame (at rest: gravity's direction, up) */
} mp_identity_t;

/* Decode an app-channel payload addressed to the module in broadcast slot `slot`. */
mp_status_t mp_decode_command(const uint8_t *buf, size_t len, uint8_t slot, mp_command_t *out);

/* Decode a claim: true and the session id (never 0) if `buf` is one. */
bool mp_decode_claim(const uint8_t *buf, size_t len, uint32_t *session);

/* Encode an identity report into buf (at least MP_IDENTITY_SIZE bytes); returns the size, 0 if cap is too small. */
size_t mp_encode_identity(const mp_identity_t *identity, uint8_t *buf, size_t cap);

/* Encode a state report into buf (at least MP_STATE_SIZE bytes); returns the size, 0 if cap is too small. */
size_t mp_encode_state(const mp_state_t *state, uint8_t *buf, size_t cap);

/* Ticks elapsed from `then` to `now` on a wrapping 32-bit tick counter. */
static inline uint32_t mp_ticks_since(uint32_t now, uint32_t then) { return now - then; }

/* True if `candidate` comes after `last` on a wrapping 16-bit counter (less than half the range ahead). */
static inline bool mp_sequence_after(uint16_t candidate, uint16_t last) {
  return (uint16_t)(candidate - last) != 0u && (uint16_t)(candidate - last) < 0x8000u;
}

/* The newest command and the counters, written by the app task and read by the stabilizer task. */
typedef struct {
  mp_command_t latest;
  bool has_command;
  uint32_t accepted_tick; /* tick at which `latest` arrived */
  uint16_t received;
  uint16_t dropped;
} mp_mailbox_t;

void mp_mailbox_init(mp_mailbox_t *box);

/*
 * Offer a decoded command at tick `now`. It replaces the newest (latest wins) if it comes after it in sequence,
 * or if the newest is older than `timeout` ticks (a restarted ground station starts its counter anew). A
 * duplicate or a reordered older command is counted as dropped. Returns true if accepted.
 */
bool mp_mailbox_offer(mp_mailbox_t *box, const mp_command_t *cmd, uint32_t now, uint32_t timeout);

/* Count a packet that never became a command (malformed, another owner's, or lost to a full receive queue). */
void mp_mailbox_drop(mp_mailbox_t *box);

/*
 * A claim by `session` at tick `now`. The same session keeps its token (a repeated claim whose answer was lost).
 * Another session is refused while the owner's newest command is armed and younger than `timeout` (the module
 * is flying for it); otherwise it becomes the owner with a new token and the mailbox forgets the old owner's
 * command (its counters go on). Returns true if `session` owns the module afterwards.
 */
bool mp_owner_claim(mp_owner_t *owner, mp_mailbox_t *box, uint32_t session, uint32_t now, uint32_t timeout);

/* A command is the owner's: it carries the owner's token (never so before the first claim). */
static inline bool mp_owner_accepts(const mp_owner_t *owner, const mp_command_t *cmd) {
  return owner->token != 0u && cmd->token == owner->token;
}

typedef enum {
  MP_GATE_RUN = 0,     /* forces are the newest command's */
  MP_GATE_NO_COMMAND,  /* nothing received since start */
  MP_GATE_STALE,       /* the newest command is `timeout` ticks old or older */
  MP_GATE_DISARMED,    /* the newest command does not carry the armed flag */
  MP_GATE_LOCKED,      /* the supervisor is locked */
  MP_GATE_CANNOT_FLY,  /* the supervisor does not let flight setpoints through (not armed, arming, tumbled) */
} mp_gate_t;

/*
 * The normalized forces (0..1) the controller outputs at tick `now`: the newest command's, or zero unless the
 * supervisor is not locked and can fly, and the command exists, is armed and is fresh (younger than `timeout`
 * ticks). Zero while the supervisor cannot fly is what the stock controllers do: during the Arming state of a
 * brushless build the motors must idle at the idle thrust for the RPM check, and any more fails it.
 */
mp_gate_t mp_gate_forces(const mp_mailbox_t *box, uint32_t now, uint32_t timeout, bool locked, bool can_fly,
                         float forces[4]);

#endif /* MOTOR_PROTOCOL_H_ */
