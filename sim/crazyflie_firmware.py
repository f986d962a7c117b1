"""One simulated Crazyflie running the motor app: the firmware rules the ground station meets on real modules.

Modelled on crazyflie-firmware 2026.08 with ``firmware/crazyflie_app`` flashed, and checked against the real
firmware run natively (``firmware/crazyflie_sitl``, ``tests/firmware_sitl``):

* Supervisor (``supervisor.c``, ``supervisor_state_machine.c``), the states that matter to the ground station:
  pre-flight checks not passed (tumbled) -> passed -> (arming request, or at once on auto-arming platforms)
  arming -> ready to fly -> flying (a motor over idle in the last 2 s) -> landed (no thrust for 2 s) -> back to not
  passed on disarm or after the 3 s landing timeout. A 2.1 Brushless build (bidirectional DSHOT) stays in arming
  until every motor reports 1000-3500 RPM for 200 ms and disarms after a 2 s spin-up timeout; other builds pass
  arming at once. Ready to fly without flying for 30 s disarms (pre-flight timeout). Tumbled
  (``supervisor.tmblChckEn`` on, the module's specific force below 0.5 g along its z axis for 1 s, or below -0.2 g
  for 0.1 s) blocks arming and disarms; tumbled while flying is a crash (motors stopped until a reboot). Flying
  without a setpoint for 0.5 s levels out (WarningLevelOut, left only by fresh setpoints: it never lands by
  itself); an emergency stop (supervisor port, or the legacy localization packet), or 2 s without a setpoint while
  flying (commander watchdog), locks the module until it is rebooted. Bolt and the 2.1 Brushless need the arming
  request (``CONFIG_MOTORS_REQUIRE_ARMING``); the Crazyflie 2.x arms itself, also right after a disarm: with its
  flying hysteresis still on it is flying again at once and, left without commands, locks 2 s later (found on the
  real firmware; the ground station streams zeros until the hysteresis has run out).
* The motor app (``motor_protocol.c``), mirrored line for line by :class:`MotorApp` and checked against the C
  code in the tests: one owner at a time (a claim, refused while another session's armed commands are fresh;
  commands only with the owner's token), a 1-deep latest-wins mailbox, forces only while the supervisor can fly
  and the newest command is armed and fresh (< 100 ms); one state per batch of received commands, never
  unprompted, reporting the motor ratios; an identity report (owner, unique id, accelerometer) per claim.
* The power distribution (battery compensation and its dead zone, the cap shared by four rotors, the idle floor)
  is the platform's :class:`~groundstation.assembly.motor_map.MotorCommandMap`.
* The connection-setup and parameter services (:mod:`sim.crtp_services`), the platform version (CRTP protocol
  12), and the power switch cflib's ``PowerSwitch`` sends over a UDP link (a reboot keeps only stored
  parameters).

Real firmware never routes the null packet ``0xFF`` to an app, and neither does this model.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Literal

import numpy as np

from groundstation.assembly.motor_map import REQUIRES_ARMING, MotorCommandMap
from groundstation.backends import crtp_wire as wire
from sim.crtp_services import FirmwareParam, FirmwareServices

Platform = Literal["cf2", "cf21bl", "bolt"]
RPM_CHECK = {"cf2": False, "cf21bl": True, "bolt": False}
"""Bidirectional DSHOT (``CONFIG_MOTORS_ESC_PROTOCOL_DSHOT_BIDIRECTIONAL``, default with DSHOT): the arming RPM
check."""
ARMING_RPM = (1000.0, 3500.0)
"""``CONFIG_MOTORS_ARMING_RPM_MIN``, ``_MAX``."""
ARMING_RPM_DURATION_S = 0.2
ARMING_SPINUP_TIMEOUT_S = 2.0
TUMBLE_TILT_ACC_Z, TUMBLE_TILT_S = 0.5, 1.0
TUMBLE_UPSIDE_DOWN_ACC_Z, TUMBLE_UPSIDE_DOWN_S = -0.2, 0.1
COMMAND_TIMEOUT_TICKS = 100
"""The motor app's staleness timeout (``MOTOR_APP_COMMAND_TIMEOUT_MS``), in ticks of the 1 kHz kernel."""
PREFLIGHT_TIMEOUT_S = 30.0
LANDING_TIMEOUT_S = 3.0
IS_FLYING_HYSTERESIS_S = 2.0
COMMANDER_WDT_SHUTDOWN_S = 2.0
COMMANDER_WDT_WARNING_S = 0.5
POWER_SWITCH = 0xFE
"""Second byte of cflib's ``PowerSwitch`` packets over a non-radio link: ``0xFF 0xFE <cmd> [arg]``."""
POWER_SYSOFF, POWER_SYSON, POWER_RESET = 0x02, 0x03, 0xF0


def ticks(now: float) -> int:
    """The firmware's tick count (1 kHz, wrapping at 32 bits) at time ``now`` (s)."""
    return int(now * 1e3) & 0xFFFFFFFF


class MotorApp:
    """Python mirror of ``firmware/crazyflie_app/src/motor_protocol.c`` (mailbox and gate), on ticks like the C."""

    def __init__(self) -> None:
        self.latest: wire.MotorCommand | None = None
        self.accepted_tick = 0
        self.received = 0
        self.dropped = 0
        self.owner_session = 0
        self.owner_token = 0
        """0: nobody owns the module."""

    def _age(self, tick: int) -> int:
        return (tick - self.accepted_tick) & 0xFFFFFFFF

    def claim(self, session: int, tick: int, timeout: int = COMMAND_TIMEOUT_TICKS) -> bool:
        """``mp_owner_claim``: True if ``session`` owns the module afterwards."""
        if session == 0:
            return False
        if self.owner_token and self.owner_session == session:
            return True
        if self.owner_token and self.latest is not None and self.latest.armed and self._age(tick) < timeout:
            return False  # flying for its owner
        self.owner_session = session
        self.owner_token = self.owner_token % 255 + 1
        self.latest = None
        return True

    def accepts(self, cmd: wire.MotorCommand) -> bool:
        """``mp_owner_accepts``: the command carries the owner's token."""
        return self.owner_token != 0 and cmd.token == self.owner_token

    def offer(self, cmd: wire.MotorCommand, tick: int, timeout: int = COMMAND_TIMEOUT_TICKS) -> bool:
        stale = self.latest is None or self._age(tick) >= timeout
        ahead = (cmd.sequence - self.latest.sequence) & 0xFFFF if self.latest is not None else 1
        if not stale and not 0 < ahead < 0x8000:
            self.dropped = (self.dropped + 1) & 0xFFFF
            return False
        self.latest, self.accepted_tick = cmd, tick
        self.received = (self.received + 1) & 0xFFFF
        return True

    def drop(self) -> None:
        self.dropped = (self.dropped + 1) & 0xFFFF

    def forces(self, tick: int, locked: bool, can_fly: bool = True,
               timeout: int = COMMAND_TIMEOUT_TICKS) -> np.ndarray:
        """Normalized forces of the four rotors (zero unless not locked, able to fly, armed and fresh)."""
        if (locked or not can_fly or self.latest is None or self._age(tick) >= timeout
                or not self.latest.armed):
            return np.zeros(4)
        return wire.from_counts(self.latest.counts)

    def fresh(self, tick: int, timeout: int = COMMAND_TIMEOUT_TICKS) -> bool:
        return self.latest is not None and self._age(tick) < timeout


class Supervisor:
    """The firmware supervisor's states as the motor app and the ground station see them."""

    def __init__(self, platform: Platform, now: float) -> None:
        self.auto_arm = not REQUIRES_ARMING[platform]
        self.rpm_check = RPM_CHECK[platform]
        self.state = "not_passed"
        self.armed = False
        self.estop = False
        self.tumble_check = True
        """``supervisor.tmblChckEn``."""
        self.tumbled = False
        self.last_event = ""
        """Why the newest transition out of a flight state happened (disarm, spin-up timeout, tumbled, ...)."""
        self._since = now
        """Time the current state was entered, s."""
        self._last_thrust = -np.inf
        self._tilt_since: float | None = None
        self._rpm_ok_since: float | None = None

    @property
    def locked(self) -> bool:
        return self.state == "locked"

    @property
    def motors_allowed(self) -> bool:
        """``supervisorAreMotorsAllowedToRun``: the idle floor applies, forces reach the motors."""
        return self.state in ("arming", "ready", "flying", "level_out", "landed")

    @property
    def can_fly(self) -> bool:
        """``supervisorCanFly``."""
        return self.state in ("ready", "flying", "level_out", "landed")

    @property
    def flying(self) -> bool:
        """``supervisorIsFlying``: Flying or WarningLevelOut."""
        return self.state in ("flying", "level_out")

    def request_arming(self, do_arm: bool) -> tuple[bool, bool]:
        """``supervisorRequestArming``: (granted, armed)."""
        if do_arm == self.armed:
            return True, self.armed
        if do_arm and self.state != "passed":
            return False, self.armed
        self.armed = do_arm
        return True, self.armed

    def _enter(self, state: str, now: float, why: str = "") -> None:
        self.state, self._since = state, now
        self.last_event = why or self.last_event
        if state in ("not_passed", "locked", "crashed"):
            self.armed = False
        self._rpm_ok_since = None

    def _tumble(self, now: float, acc_z_g: float) -> bool:
        if acc_z_g >= TUMBLE_TILT_ACC_Z:
            self._tilt_since = None
            return False
        if self._tilt_since is None:
            self._tilt_since = now
        held = now - self._tilt_since
        return held > TUMBLE_TILT_S or (acc_z_g < TUMBLE_UPSIDE_DOWN_ACC_Z and held > TUMBLE_UPSIDE_DOWN_S)

    def _rpm_valid(self, now: float, rpm) -> bool:
        if not self.rpm_check:
            return True
        lo, hi = ARMING_RPM
        if rpm is None or np.any(np.asarray(rpm) < lo) or np.any(np.asarray(rpm) > hi):
            self._rpm_ok_since = None
            return False
        if self._rpm_ok_since is None:
            self._rpm_ok_since = now
        return now - self._rpm_ok_since >= ARMING_RPM_DURATION_S

    def step(self, now: float, over_idle: bool, setpoint_age: float, acc_z_g: float = 1.0, rpm=None) -> None:
        """One supervisor update: ``over_idle`` a motor above idle, ``acc_z_g`` the specific force along the
        module's z axis (g), ``rpm`` the four motors' speeds (bidirectional DSHOT)."""
        if over_idle:
            self._last_thrust = now
        flying = now - self._last_thrust < IS_FLYING_HYSTERESIS_S
        self.tumbled = self.tumble_check and self._tumble(now, acc_z_g)
        s = self.state
        if s in ("locked", "crashed"):
            return
        if self.estop or (self.flying and setpoint_age > COMMANDER_WDT_SHUTDOWN_S):
            self._enter("locked", now, "emergency stop" if self.estop else "commander watchdog")
        elif s == "level_out":  # no way out but fresh setpoints: it never lands by itself
            if self.tumbled:
                self._enter("locked", now, "tumbled in flight")
            elif setpoint_age <= COMMANDER_WDT_WARNING_S:
                self._enter("flying", now)
        elif s == "not_passed":
            if not self.tumbled:
                self._enter("passed", now)
        elif s == "passed":
            if self.auto_arm:
                self.armed = True
            if self.tumbled:
                self._enter("not_passed", now, "tumbled")
            elif self.armed:
                self._enter("arming", now)
        elif s == "arming":
            if self.tumbled or not self.armed:
                self._enter("not_passed", now, "tumbled" if self.tumbled else "disarmed")
            elif now - self._since > ARMING_SPINUP_TIMEOUT_S:
                self._enter("not_passed", now, "motors did not reach the arming RPM within 2 s")
            elif self._rpm_valid(now, rpm):
                self._enter("ready", now)
        elif s == "ready":
            if self.tumbled or not self.armed or now - self._since > PREFLIGHT_TIMEOUT_S:
                why = "tumbled" if self.tumbled else "disarmed" if not self.armed else "pre-flight timeout"
                self._enter("not_passed", now, why)
            elif flying:
                self._enter("flying", now)
        elif s == "flying":
            if self.tumbled:
                self._enter("crashed", now, "tumbled in flight")
            elif not self.armed:
                self._enter("not_passed", now, "disarmed")
            elif setpoint_age > COMMANDER_WDT_WARNING_S:
                self._enter("level_out", now, "no setpoint for 0.5 s (commander watchdog)")
            elif not flying:
                self._enter("landed", now)
        elif s == "landed":
            if flying:
                self._enter("flying", now)
            elif not self.armed or now - self._since > LANDING_TIMEOUT_S:
                self._enter("not_passed", now, "disarmed" if not self.armed else "landing timeout")


@dataclass(frozen=True)
class FirmwareBuild:
    """What is flashed on a simulated module."""

    platform: Platform = "bolt"
    motor_app: bool = True
    """The motor app is flashed (False: stock firmware: no app channel state, stock controller)."""


def module_params(build: FirmwareBuild) -> list[FirmwareParam]:
    """The parameters the ground station reads, at their values after boot.

    ``stabilizer.controller`` reads 1 (PID, chosen by auto-select) on stock firmware and 6 (out-of-tree) on a
    motor-app build, where ``CONFIG_CONTROLLER_OOT`` makes auto-select pick it; it is not persistent.
    ``supervisor.tmblChckEn`` is persistent."""
    params = [FirmwareParam("supervisor", "tmblChckEn", "uint8", 1, persistent=True),
              FirmwareParam("stabilizer", "controller", "uint8", 6 if build.motor_app else 1),
              FirmwareParam("motorPowerSet", "enable", "uint8", 0)]
    if build.motor_app:
        params += [FirmwareParam("motorApp", "version", "uint8", wire.APP_VERSION, read_only=True),
                   FirmwareParam("motorApp", "slot", "uint8", 0),
                   FirmwareParam("motorApp", "timeoutMs", "uint16", COMMAND_TIMEOUT_TICKS, read_only=True)]
    return params


class SimulatedCrazyflie:
    """The firmware of one module: :meth:`handle` takes a CRTP packet and returns the replies; :meth:`ratios` is
    what reaches the motors; :meth:`step` advances the supervisor."""

    def __init__(self, build: FirmwareBuild, now: float, preset: tuple[tuple[str, float], ...] = (),
                 motor_map: MotorCommandMap | None = None, battery_v: float = 4.0,
                 uid: tuple[int, int, int] = (0x00370041, 0x3236510D, 0x38383432)) -> None:
        self.build = build
        self.uid = uid
        """The MCU's unique id (``cpu.id0..id2``)."""
        self.acc_g = np.array([0.0, 0.0, 1.0])
        """The accelerometer's newest sample, g, module frame (:meth:`step`)."""
        self.motor_map = motor_map or _stock_map(build.platform)
        if self.motor_map.platform != build.platform:
            raise ValueError(f"a {build.platform} build with the thrust map of a {self.motor_map.platform}")
        self.battery_v = battery_v
        """Battery under load, V (the power distribution compensates it)."""
        self.services = FirmwareServices(module_params(build))
        for name, value in preset:  # configured before this run (an earlier params --apply stored them)
            self.services.set(name, value)
            if self.services.is_persistent(name):
                self.services.store(name)
        self.powered = True
        self.boots = 0
        self._boot(now)

    def _boot(self, now: float) -> None:
        self.boots += 1
        self.services.reboot()
        self.supervisor = Supervisor(self.build.platform, now)
        self.app = MotorApp()
        self.last_setpoint = -np.inf
        self._answer_due = False

    # -- packets ----------------------------------------------------------------------------------------------
    def handle(self, data: bytes, now: float) -> list[bytes]:
        """Replies (whole CRTP packets) to one packet from the ground station."""
        if not data:
            return []
        head, body = data[0], data[1:]
        if head == wire.NULL_HEADER:
            return self._power(body, now)
        if not self.powered:
            return []
        if wire.same_port(head, wire.APP_HEADER):
            return self._app_packet(body, now) if self.build.motor_app else []
        if wire.same_port(head, wire.SUPERVISOR_HEADER):
            return self._supervisor(head, body)
        if wire.same_port(head, wire.LEGACY_STOP_HEADER):
            if body[:1] == bytes([wire.LEGACY_EMERGENCY_STOP]):
                self.supervisor.estop = True
            return []
        if wire.same_port(head, wire.VERSION_HEADER) and body[:1] == bytes([wire.GET_PROTOCOL_VERSION]):
            return [bytes([head]) + struct.pack("<Bi", wire.GET_PROTOCOL_VERSION, wire.MIN_PROTOCOL_VERSION)]
        return self.services.handle(head, body) or []

    def _app_packet(self, body: bytes, now: float) -> list[bytes]:
        claim = wire.Claim.unpack(body)
        if claim is not None:  # answered with the identity, not a state
            self.app.claim(claim.session, ticks(now))
            ident = wire.Identity(self._flags(now), self.app.owner_token, self.app.owner_session, self.uid,
                                  tuple(int(np.clip(round(a * 1000), -32767, 32767)) for a in self.acc_g))
            return [bytes([wire.APP_HEADER]) + ident.pack()]
        self._answer_due = True  # the app answers each batch of received packets with one state
        try:
            cmd = wire.MotorCommand.unpack(body)
        except ValueError:
            self.app.drop()
            return []
        if not self.app.accepts(cmd):
            self.app.drop()  # another owner's
        elif self.app.offer(cmd, ticks(now)):
            self.last_setpoint = now  # commanderSetSetpoint(..., COMMANDER_PRIORITY_CRTP)
        return []

    def _supervisor(self, head: int, body: bytes) -> list[bytes]:
        if body[:1] == bytes([wire.CMD_EMERGENCY_STOP]):
            self.supervisor.estop = True
        elif body[:1] == bytes([wire.CMD_ARM_SYSTEM]) and len(body) >= 2:
            granted, armed = self.supervisor.request_arming(bool(body[1]))
            return [bytes([head, wire.CMD_RESPONSE | wire.CMD_ARM_SYSTEM, int(granted), int(armed)])]
        return []

    def _power(self, body: bytes, now: float) -> list[bytes]:
        """cflib's PowerSwitch over a UDP link, answered with a null packet (cflib waits for any packet back, as
        the radio's acknowledgement; the app no longer streams one unprompted); anything else on the null header
        is ignored, as on hardware."""
        if body[:1] != bytes([POWER_SWITCH]) or len(body) < 2:
            return []
        if body[1] == POWER_SYSOFF:
            self.powered = False
        elif body[1] in (POWER_SYSON, POWER_RESET):
            self.powered = True
            self._boot(now)
        return [bytes([wire.NULL_HEADER])]

    # -- time ---------------------------------------------------------------------------------------------------
    def _forces(self, now: float) -> np.ndarray:
        sup = self.supervisor
        return self.app.forces(ticks(now), sup.locked, sup.can_fly)

    def ratios(self, now: float) -> np.ndarray:
        """Motor ratios (0..1) reaching the four motors now: the app's gate, then the power distribution."""
        if not self.powered or not self.build.motor_app:
            return np.zeros(4)
        forces = self._forces(now)[None, :]
        return self.motor_map.motor_ratios(forces, [self.battery_v], armed=self.supervisor.motors_allowed)[0]

    def step(self, now: float, acc_g=(0.0, 0.0, 1.0), rpm=None) -> None:
        """Advance the supervisor (once per physics step) with the module's specific force (g, module frame) and
        its motors' speeds (RPM)."""
        if self.powered:
            self.acc_g = np.asarray(acc_g, float)
            sup = self.supervisor
            sup.tumble_check = bool(self.services.value("supervisor.tmblChckEn"))
            over_idle = bool(np.any(self.ratios(now) > self.motor_map.idle + 1e-9))
            sup.step(now, over_idle, now - self.last_setpoint, float(acc_g[2]), rpm)

    def state_due(self) -> bool:
        """A batch of app packets arrived since the last state: the app answers it."""
        return self.powered and self.build.motor_app and self._answer_due

    def _flags(self, now: float) -> int:
        latest, sup = self.app.latest, self.supervisor
        return ((wire.STATE_ARMED if latest is not None and latest.armed else 0)
                | (wire.STATE_LOCKED if sup.locked else 0)
                | (wire.STATE_SUPERVISOR_ARMED if sup.armed else 0)
                | (wire.STATE_FRESH if self.app.fresh(ticks(now)) else 0)
                | (wire.STATE_CAN_FLY if sup.can_fly else 0)
                | (wire.STATE_FLYING if sup.flying else 0))

    def state_packet(self, now: float, gyro: np.ndarray) -> bytes:
        """The app's state report (whole CRTP packet): the motor ratios now, the battery, ``gyro`` in rad/s."""
        self._answer_due = False
        latest = self.app.latest
        st = wire.ModuleState(self._flags(now), latest.sequence if latest is not None else 0,
                              wire.to_counts(self.ratios(now)),
                              round(self.battery_v * 1e3), tuple(float(g) for g in gyro), self.app.received,
                              self.app.dropped)
        return bytes([wire.APP_HEADER]) + st.pack()


def _stock_map(platform: Platform) -> MotorCommandMap:
    """The firmware's own map of a platform at its defaults (the bolt fit is the paper module's)."""
    if platform == "bolt":
        return MotorCommandMap(platform="bolt", thrust_poly_n=(0.0, 0.0, 1.548), reference_battery_v=3.5)
    return MotorCommandMap(platform=platform, thrust_max_n={"cf2": 0.12, "cf21bl": 0.2}[platform])
