/*
 * motor_app.c - firmware glue of the motor app: per-rotor commands from the ground station, over the CRTP app
 * channel, into the out-of-tree controller in force mode.
 *
 * Two tasks touch the shared state:
 *  - the app task (appMain -> motorAppStep) blocks on the app channel, keeps only the newest command (a 1-deep
 *    mailbox, latest wins), feeds the commander watchdog with one setpoint per accepted command, and answers each
 *    batch of received commands with one state report (non-blocking send);
 *  - the stabilizer task calls controllerOutOfTree() at 1 kHz, which outputs the newest command as normalized
 *    forces, or zero unless the supervisor can fly and the command is armed and fresh.
 * The pure rules live in motor_protocol.c; this file only moves data between them and the firmware.
 *
 * Ownership (contract 3): commands count only with the token of the ground station that claimed the module
 * last, and a claim is refused while the owner flies it, so a second ground station (or a second `fly` on the
 * same links) can neither take over an airborne module nor have its commands mixed with the owner's. The answer
 * to a claim names the owner and the module (its MCU's unique id, the direction of gravity it measures), which
 * the ground station's preflight checks against the assembly.
 *
 * Why one state per batch and never unprompted: the downlink rides on the radio's acknowledgements behind a
 * 1-deep TX queue and a 200-packet CRTP FIFO. An app that streams with no ground station connected fills that
 * FIFO in about 2 s, and the next ground station to connect reads seconds-old states first. Answering commands
 * keeps the number of states in flight at most the number of commands in flight.
 */
#include <string.h>

#include "FreeRTOS.h"
#include "app.h"
#include "app_channel.h"
#include "commander.h"
#include "controller.h"
#include "log.h"
#include "motors.h"
#include "param.h"
#include "pm.h"
#include "supervisor.h"
#include "task.h"

#define DEBUG_MODULE "MOTORAPP"
#include "debug.h"

#include "motor_app.h"
#include "motor_protocol.h"

#define DEG_TO_RAD 0.017453292519943295f

static mp_mailbox_t mailbox;      /* app task writes, stabilizer task reads: under a critical section */
static float gyroRad[3];          /* stabilizer task writes, app task reads: under a critical section */
static uint16_t motorRatios[4];   /* idem: what reaches the motors after the power distribution */
static float accG[3];             /* idem: the accelerometer, g, module frame */
static mp_owner_t owner;          /* app task only */
static uint32_t uniqueId[3];      /* the MCU's unique id, read once from the cpu.id0..id2 parameters */

/* Parameters and log variables (see the PARAM/LOG groups at the end). */
static uint8_t protocolVersion = MP_PROTOCOL_VERSION;
static uint8_t broadcastSlot = 0;
static uint16_t commandTimeoutMs = MOTOR_APP_COMMAND_TIMEOUT_MS;
static uint16_t logReceived; /* copies of the mailbox counters for the log (they wrap like the wire fields) */
static uint16_t logDropped;
static uint32_t logOverflows;

static uint32_t cpuIdParam(const char *name) {
  const paramVarId_t id = paramGetVarId("cpu", name);
  return PARAM_VARID_IS_VALID(id) ? (uint32_t)paramGetUint(id) : 0u;
}

void motorAppInit(void) {
  mp_mailbox_init(&mailbox);
  memset(gyroRad, 0, sizeof gyroRad);
  memset(motorRatios, 0, sizeof motorRatios);
  memset(accG, 0, sizeof accG);
  memset(&owner, 0, sizeof owner);
  uniqueId[0] = cpuIdParam("id0");
  uniqueId[1] = cpuIdParam("id1");
  uniqueId[2] = cpuIdParam("id2");
  logReceived = 0;
  logDropped = 0;
  logOverflows = 0;
}

/* The state flags of a report sent at tick `now` with the mailbox `box`. Supervisor queries from the app task:
 * each reads (supervisorCanFly also rewrites) a flag of the stabilizer's supervisor state; a state that is one
 * step old is all a report needs. */
static uint8_t stateFlags(const mp_mailbox_t *box, uint32_t now) {
  const bool fresh = box->has_command && mp_ticks_since(now, box->accepted_tick) < M2T(commandTimeoutMs);
  return (uint8_t)((box->has_command && box->latest.armed ? MP_STATE_ARMED : 0u) |
                   (supervisorIsLocked() ? MP_STATE_LOCKED : 0u) |
                   (supervisorIsArmed() ? MP_STATE_SUPERVISOR_ARMED : 0u) | (fresh ? MP_STATE_FRESH : 0u) |
                   (supervisorCanFly() ? MP_STATE_CAN_FLY : 0u) | (supervisorIsFlying() ? MP_STATE_FLYING : 0u));
}

static int16_t milliG(float g) {
  const float mg = g * 1000.0f;
  return mg >= 32767.0f ? (int16_t)32767 : mg <= -32767.0f ? (int16_t)-32767 : (int16_t)(mg + (mg >= 0 ? 0.5f : -0.5f));
}

/* A claim: take the module if the rule allows (mp_owner_claim), and answer with who owns it. */
static void handleClaim(uint32_t session) {
  mp_identity_t identity;
  memset(&identity, 0, sizeof identity);
  const uint32_t now = xTaskGetTickCount();
  taskENTER_CRITICAL();
  (void)mp_owner_claim(&owner, &mailbox, session, now, M2T(commandTimeoutMs));
  const mp_mailbox_t box = mailbox;
  const float acc[3] = {accG[0], accG[1], accG[2]};
  taskEXIT_CRITICAL();
  identity.flags = stateFlags(&box, now);
  identity.token = owner.token;
  identity.session = owner.session;
  memcpy(identity.uid, uniqueId, sizeof identity.uid);
  for (unsigned k = 0; k < 3u; k++) {
    identity.acc_mg[k] = milliG(acc[k]);
  }
  uint8_t buffer[MP_IDENTITY_SIZE];
  const size_t size = mp_encode_identity(&identity, buffer, sizeof buffer);
  appchannelSendDataPacket(buffer, size); /* non-blocking, like the state: a lost answer, a repeated claim */
}

/* Returns true if the packet asks for a state report (a command, or what was meant as one). */
static bool handlePacket(const uint8_t *data, size_t length) {
  uint32_t session;
  if (mp_decode_claim(data, length, &session)) {
    handleClaim(session);  /* answered with the identity, not a state */
    return false;
  }
  mp_command_t cmd;
  const mp_status_t status = mp_decode_command(data, length, broadcastSlot, &cmd);
  if (status == MP_NOT_FOR_US) {
    return false;  /* a broadcast for other modules */
  }
  bool accepted = false;
  taskENTER_CRITICAL();
  if (status == MP_OK && mp_owner_accepts(&owner, &cmd)) {
    accepted = mp_mailbox_offer(&mailbox, &cmd, xTaskGetTickCount(), M2T(commandTimeoutMs));
  } else {
    mp_mailbox_drop(&mailbox);  /* malformed, or not the owner's */
  }
  taskEXIT_CRITICAL();
  if (accepted) {
    /* One setpoint per accepted command keeps the commander watchdog (level-out 500 ms, lock 2 s) on our
     * stream: without it the idle high-level commander would keep the watchdog fed forever. The content is
     * not used: the out-of-tree controller ignores the setpoint. */
    setpoint_t setpoint;
    memset(&setpoint, 0, sizeof setpoint);
    commanderSetSetpoint(&setpoint, COMMANDER_PRIORITY_CRTP);
  }
  return true;
}

static void sendState(void) {
  mp_state_t state;
  memset(&state, 0, sizeof state);
  taskENTER_CRITICAL();
  const mp_mailbox_t box = mailbox;
  memcpy(state.gyro, gyroRad, sizeof state.gyro);
  memcpy(state.counts, motorRatios, sizeof state.counts);
  taskEXIT_CRITICAL();
  state.flags = stateFlags(&box, xTaskGetTickCount());
  state.sequence = box.latest.sequence;
  const float volts = pmGetBatteryVoltage();
  state.battery_mv = volts <= 0.0f ? 0u : volts >= 65.0f ? 65000u : (uint16_t)(volts * 1000.0f + 0.5f);
  state.received = box.received;
  state.dropped = box.dropped;
  logReceived = box.received;
  logDropped = box.dropped;
  uint8_t buffer[MP_STATE_SIZE];
  const size_t size = mp_encode_state(&state, buffer, sizeof buffer);
  /* Non-blocking: a blocking send on a full TX queue would stop this task from taking commands. A state lost
   * here is replaced by the answer to the next command. */
  appchannelSendDataPacket(buffer, size);
}

void motorAppStep(void) {
  uint8_t buffer[APPCHANNEL_MTU];
  /* Blocks until a packet arrives: the app has nothing to do without one (the stabilizer task stops the motors
   * on the command timeout by itself), and never busy-loops, which would starve the priority-0 platform task
   * that feeds the app channel (and with it every CRTP port, the stop included). */
  size_t length = appchannelReceiveDataPacket(buffer, sizeof buffer, APPCHANNEL_WAIT_FOREVER);
  if (length == 0) {
    return;
  }
  bool answer = false;
  while (length > 0) {
    answer |= handlePacket(buffer, length);
    length = appchannelReceiveDataPacket(buffer, sizeof buffer, 0);  /* drain: the newest wins */
  }
  if (appchannelHasOverflowOccurred()) {
    logOverflows++;
    taskENTER_CRITICAL();
    mp_mailbox_drop(&mailbox);
    taskEXIT_CRITICAL();
    answer = true;
  }
  if (answer) {
    sendState();
  }
}

void appMain(void) {
  DEBUG_PRINT("motor app v%u: waiting for commands on the app channel\n", (unsigned)protocolVersion);
  motorAppInit();
  for (;;) {
    motorAppStep();
  }
}

void controllerOutOfTreeInit(void) {}

bool controllerOutOfTreeTest(void) { return true; }

void controllerOutOfTree(control_t *control, const setpoint_t *setpoint, const sensorData_t *sensors,
                         const state_t *state, const stabilizerStep_t stabilizerStep) {
  (void)setpoint;
  (void)state;
  (void)stabilizerStep;
  taskENTER_CRITICAL();
  const mp_mailbox_t box = mailbox;
  taskEXIT_CRITICAL();
  float forces[4];
  mp_gate_forces(&box, xTaskGetTickCount(), M2T(commandTimeoutMs), supervisorIsLocked(), supervisorCanFly(),
                 forces);
  control->controlMode = controlModeForce;
  /* The ratios of the previous step: the power distribution (battery compensation, dead zone, idle floor, the
   * shared cap) runs after the controller, so what reaches the motors is known one 1 ms step later. */
  uint16_t ratios[4];
  for (unsigned q = 0; q < 4u; q++) {
    control->normalizedForces[q] = forces[q];
    ratios[q] = motorsGetRatio(q);
  }
  taskENTER_CRITICAL();
  gyroRad[0] = sensors->gyro.x * DEG_TO_RAD;
  gyroRad[1] = sensors->gyro.y * DEG_TO_RAD;
  gyroRad[2] = sensors->gyro.z * DEG_TO_RAD;
  accG[0] = sensors->acc.x;
  accG[1] = sensors->acc.y;
  accG[2] = sensors->acc.z;
  memcpy(motorRatios, ratios, sizeof motorRatios);
  taskEXIT_CRITICAL();
}

/**
 * The motor app (firmware/crazyflie_app in the ground station's repository).
 */
PARAM_GROUP_START(motorApp)
/**
 * @brief Version of the ground station <-> app contract this build speaks (read-only)
 */
PARAM_ADD(PARAM_UINT8 | PARAM_RONLY, version, &protocolVersion)
/**
 * @brief Slot of this module in broadcast command packets (0..255)
 */
PARAM_ADD(PARAM_UINT8, slot, &broadcastSlot)
/**
 * @brief Motors stop when no command arrived for this long (ms, read-only)
 */
PARAM_ADD(PARAM_UINT16 | PARAM_RONLY, timeoutMs, &commandTimeoutMs)
PARAM_GROUP_STOP(motorApp)

LOG_GROUP_START(motorApp)
/**
 * @brief Commands accepted since start
 */
LOG_ADD(LOG_UINT16, rx, &logReceived)
/**
 * @brief Commands not applied: older than the newest, malformed, or lost to a full receive queue
 */
LOG_ADD(LOG_UINT16, drop, &logDropped)
/**
 * @brief Times the app channel's receive queue overflowed
 */
LOG_ADD(LOG_UINT32, overflow, &logOverflows)
LOG_GROUP_STOP(motorApp)
