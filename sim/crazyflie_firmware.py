"""One simulated Crazyflie running the motor app: the firmware rules the ground station meets on real modules.

Modelled on crazyflie-firmware 2026.08 with ``firmware/crazyflie_app`` flashed:

* Supervisor (``supervisor.c``, ``supervisor_state_machine.c``), the states that matter to the ground station:
  pre-flight checks passed -> (arming request, or at once on auto-arming platforms) ready to fly -> flying
  (a motor over idle) -> landed (no thrust for 2 s) -> back to pre-flight checks passed on disarm or after the 3 s
  landing timeout. Ready to fly without flying for 30 s disarms (pre-flight timeout). An emergency stop (supervisor
  port, or the legacy localization packet), or 2 s without a setpoint while flying (commander watchdog), locks
  the module until it is rebooted. Bolt and the 2.1 Brushless need the arming request
  (``CONFIG_MOTORS_REQUIRE_ARMING``); the Crazyflie 2.x arms itself.
* The motor app (``motor_protocol.c``), mirrored line for line by :class:`MotorApp` and checked against the C
  code in the tests: a 1-deep latest-wins mailbox, forces only while the newest command is armed, fresh
  (< 100 ms) and the supervisor is not locked; its state streamed unprompted every 10 ms.
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

from groundstation.backends import crtp_wire as wire
from sim.crtp_services import FirmwareParam, FirmwareServices

Platform = Literal["cf2", "cf21bl", "bolt"]
REQUIRES_ARMING = {"cf2": False, "cf21bl": True, "bolt": True}
"""``CONFIG_MOTORS_REQUIRE_ARMING`` in each platform's defconfig (2026.08)."""
COMMAND_TIMEOUT_TICKS = 100
"""The motor app's staleness timeout (``MOTOR_APP_COMMAND_TIMEOUT_MS``), in ticks of the 1 kHz kernel."""
STATE_PERIOD_S = 0.01
"""The motor app's state report period, s."""
PREFLIGHT_TIMEOUT_S = 30.0
LANDING_TIMEOUT_S = 3.0
IS_FLYING_HYSTERESIS_S = 2.0
COMMANDER_WDT_SHUTDOWN_S = 2.0
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

    def _age(self, tick: int) -> int:
        return (tick - self.accepted_tick) & 0xFFFFFFFF

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

    def forces(self, tick: int, locked: bool, timeout: int = COMMAND_TIMEOUT_TICKS) -> np.ndarray:
        """Normalized forces of the four rotors (zero unless armed, fresh and not locked)."""
        if locked or self.latest is None or self._age(tick) >= timeout or not self.latest.armed:
            return np.zeros(4)
        return wire.from_counts(self.latest.counts)

    def fresh(self, tick: int, timeout: int = COMMAND_TIMEOUT_TICKS) -> bool:
        return self.latest is not None and self._age(tick) < timeout


class Supervisor:
    """The firmware supervisor's states as the motor app and the ground station see them."""

    def __init__(self, platform: Platform, now: float) -> None:
        self.auto_arm = not REQUIRES_ARMING[platform]
        self.state = "passed"
        self.armed = False
        self.estop = False
        self._since = now
        """Time the current state was entered, s."""
        self._last_thrust = -np.inf
        self._step(now, False, 0.0)

    @property
    def locked(self) -> bool:
        return self.state == "locked"

    @property
    def motors_allowed(self) -> bool:
        return self.state in ("ready", "flying", "landed")

    def request_arming(self, do_arm: bool) -> tuple[bool, bool]:
        """``supervisorRequestArming``: (granted, armed)."""
        if do_arm == self.armed:
            return True, self.armed
        if do_arm and self.state != "passed":
            return False, self.armed
        self.armed = do_arm
        return True, self.armed

    def _enter(self, state: str, now: float) -> None:
        self.state, self._since = state, now
        if state in ("passed", "locked"):
            self.armed = False

    def _step(self, now: float, over_idle: bool, setpoint_age: float) -> None:
        if over_idle:
            self._last_thrust = now
        flying = now - self._last_thrust < IS_FLYING_HYSTERESIS_S
        s = self.state
        if s != "locked" and (self.estop or (s == "flying" and setpoint_age > COMMANDER_WDT_SHUTDOWN_S)):
            self._enter("locked", now)
        elif s == "passed":
            if self.auto_arm:
                self.armed = True
            if self.armed:
                self._enter("ready", now)
        elif s == "ready":
            if not self.armed or now - self._since > PREFLIGHT_TIMEOUT_S:
                self._enter("passed", now)
            elif flying:
                self._enter("flying", now)
        elif s == "flying":
            if not self.armed:
                self._enter("passed", now)
            elif not flying:
                self._enter("landed", now)
        elif s == "landed":
            if flying:
                self._enter("flying", now)
            elif not self.armed or now - self._since > LANDING_TIMEOUT_S:
                self._enter("passed", now)

    def step(self, now: float, over_idle: bool, setpoint_age: float) -> None:
        self._step(now, over_idle, setpoint_age)


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
    """The firmware of one module: :meth:`handle` takes a CRTP packet and returns the replies; :meth:`forces`
    is what reaches the motors; :meth:`state_due` says when the app's next state report is due."""

    def __init__(self, build: FirmwareBuild, now: float, preset: tuple[tuple[str, float], ...] = ()) -> None:
        self.build = build
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
        self.last_state = -np.inf

    # -- packets ----------------------------------------------------------------------------------------------
    def handle(self, data: bytes, now: float) -> list[bytes]:
        """Replies (whole CRTP packets) to one packet from the ground station."""
        if not data:
            return []
        head, body = data[0], data[1:]
        if head == wire.NULL_HEADER:
            self._power(body, now)
            return []
        if not self.powered:
            return []
        if wire.same_port(head, wire.APP_HEADER):
            if self.build.motor_app:
                self._app_packet(body, now)
            return []
        if wire.same_port(head, wire.SUPERVISOR_HEADER):
            return self._supervisor(head, body)
        if wire.same_port(head, wire.LEGACY_STOP_HEADER):
            if body[:1] == bytes([wire.LEGACY_EMERGENCY_STOP]):
                self.supervisor.estop = True
            return []
        if wire.same_port(head, wire.VERSION_HEADER) and body[:1] == bytes([wire.GET_PROTOCOL_VERSION]):
            return [bytes([head]) + struct.pack("<Bi", wire.GET_PROTOCOL_VERSION, wire.MIN_PROTOCOL_VERSION)]
        return self.services.handle(head, body) or []

    def _app_packet(self, body: bytes, now: float) -> None:
        try:
            cmd = wire.MotorCommand.unpack(body)
        except ValueError:
            self.app.drop()
            return
        if self.app.offer(cmd, ticks(now)):
            self.last_setpoint = now  # commanderSetSetpoint(..., COMMANDER_PRIORITY_CRTP)

    def _supervisor(self, head: int, body: bytes) -> list[bytes]:
        if body[:1] == bytes([wire.CMD_EMERGENCY_STOP]):
            self.supervisor.estop = True
        elif body[:1] == bytes([wire.CMD_ARM_SYSTEM]) and len(body) >= 2:
            granted, armed = self.supervisor.request_arming(bool(body[1]))
            return [bytes([head, wire.CMD_RESPONSE | wire.CMD_ARM_SYSTEM, int(granted), int(armed)])]
        return []

    def _power(self, body: bytes, now: float) -> None:
        """cflib's PowerSwitch over a UDP link; anything else on the null header is ignored, as on hardware."""
        if body[:1] != bytes([POWER_SWITCH]) or len(body) < 2:
            return
        if body[1] == POWER_SYSOFF:
            self.powered = False
        elif body[1] in (POWER_SYSON, POWER_RESET):
            self.powered = True
            self._boot(now)

    # -- time ---------------------------------------------------------------------------------------------------
    def forces(self, now: float) -> np.ndarray:
        """Normalized forces reaching the motors now (the app's gate, then the supervisor's)."""
        if not self.powered or not self.build.motor_app or not self.supervisor.motors_allowed:
            return np.zeros(4)
        return self.app.forces(ticks(now), self.supervisor.locked)

    def step(self, now: float) -> None:
        """Advance the supervisor (once per physics step)."""
        if self.powered:
            over_idle = bool(np.any(self.app.forces(ticks(now), self.supervisor.locked) > 0))
            self.supervisor.step(now, over_idle, now - self.last_setpoint)

    def state_due(self, now: float) -> bool:
        return self.powered and self.build.motor_app and now - self.last_state >= STATE_PERIOD_S

    def state_packet(self, now: float, battery_v: float, gyro: np.ndarray) -> bytes:
        """The app's state report (whole CRTP packet): the forces applied now, the battery, ``gyro`` in rad/s."""
        self.last_state = now
        applied = self.forces(now)
        latest = self.app.latest
        flags = ((wire.STATE_ARMED if latest is not None and latest.armed else 0)
                 | (wire.STATE_LOCKED if self.supervisor.locked else 0)
                 | (wire.STATE_SUPERVISOR_ARMED if self.supervisor.armed else 0)
                 | (wire.STATE_FRESH if self.app.fresh(ticks(now)) else 0))
        st = wire.ModuleState(flags, latest.sequence if latest is not None else 0, wire.to_counts(applied),
                              round(battery_v * 1e3), tuple(float(g) for g in gyro), self.app.received,
                              self.app.dropped)
        return bytes([wire.APP_HEADER]) + st.pack()
