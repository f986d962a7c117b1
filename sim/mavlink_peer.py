"""Simulated PX4 modules on loopback: PyBullet physics behind MAVLink, as PX4 <= 1.13 in offboard mode speaks it.

Each module is one vehicle (system id ``i + 1``, autopilot component 1) on its own UDP port, spoken to by pymavlink
on both ends, and follows :mod:`groundstation.backends.mavlink_wire`: it takes ``SET_ACTUATOR_CONTROL_TARGET``
through a pass-through mixer, accepts offboard mode only while setpoints stream (as PX4 does), arms only in
offboard, answers every ``COMMAND_LONG`` with ``COMMAND_ACK``, disarms on offboard loss after its
``COM_OF_LOSS_T`` (with a disarm action), and latches flight termination. It answers a ``TIMESYNC`` request
(``tc1`` 0) with its time in ``tc1`` and the request's ``ts1``, and sends requests of its own (10 Hz), as PX4's
mavlink module does. It streams ``HEARTBEAT`` (1 Hz),
``SYS_STATUS`` (10 Hz), ``ATTITUDE`` and ``SERVO_OUTPUT_RAW`` (``state_rate_hz``, or what
``MAV_CMD_SET_MESSAGE_INTERVAL`` asks for), and serves the parameters it uses (``PARAM_REQUEST_READ``,
``PARAM_SET``; stock PX4 values unless ``PeerConfig.params`` sets them): ``COM_OF_LOSS_T`` and the PWM range.

    groundstation sim-peer configs/assemblies/toy_v2.json --protocol mavlink --port 14560

Module i listens on ``udpin:127.0.0.1:<port + i>``; the ground station connects with ``udpout:``.
"""

from __future__ import annotations

import contextlib

import numpy as np
from pymavlink import mavutil

from groundstation.backends import mavlink_wire as mw
from groundstation.control.trajectory import roll_pitch_yaw
from sim.module_peer import ModulePeer

mav = mavutil.mavlink
STOCK_PARAMS = {"COM_OF_LOSS_T": (1.0, mav.MAV_PARAM_TYPE_REAL32), "PWM_MAIN_MIN": (1000, mav.MAV_PARAM_TYPE_INT32),
                "PWM_MAIN_MAX": (2000, mav.MAV_PARAM_TYPE_INT32), "PWM_MAIN_DISARM": (900, mav.MAV_PARAM_TYPE_INT32)}
"""Parameters a simulated module uses, at PX4 1.13's defaults: value and MAV_PARAM_TYPE."""
SETPOINT_STREAM_S = 0.5
"""Offboard is refused unless a setpoint arrived within this long, s (PX4 wants a stream before the switch)."""
HEARTBEAT_S = 1.0
SYS_STATUS_S = 0.1
TIMESYNC_S = 0.1
"""PX4's own TIMESYNC requests (its mavlink module streams them at 10 Hz)."""


class Px4Rules:
    """What one PX4 module enforces in offboard mode: thrust only while armed, not terminated, and setpoints
    fresh (``COM_OF_LOSS_T``)."""

    def __init__(self) -> None:
        self.u = np.zeros(4)
        """Rotor inputs last commanded, rad^2/s^2."""
        self.armed = False
        self.stopped = False
        """Emergency-stopped: latches until the module restarts."""
        self.last_command = -np.inf
        """Monotonic time of the last motor command, s."""

    def command(self, u: np.ndarray, now: float) -> None:
        self.last_command = now
        self.u = u if self.armed else np.zeros(4)

    def arm(self, armed: bool) -> None:
        self.armed = armed and not self.stopped
        if not self.armed:
            self.u = np.zeros(4)

    def emergency_stop(self) -> None:
        self.stopped = True
        self.arm(False)

    def enforce_timeout(self, now: float, timeout: float) -> bool:
        """Disarm when no command arrived for ``timeout`` s while armed; True if that happened now."""
        if self.armed and now - self.last_command > timeout:
            self.arm(False)
            return True
        return False

    def thrust(self) -> np.ndarray:
        return self.u if self.armed and not self.stopped else np.zeros(4)


class _Vehicle:
    def __init__(self, conn, system_id: int, state_interval: float, params: dict[str, list]) -> None:
        self.conn = conn
        self.system_id = system_id
        self.params = params
        """name -> [value, MAV_PARAM_TYPE]."""
        self.offboard = False
        self.last_setpoint = -np.inf
        self.heard = False
        """The ground station has spoken (udpin only knows where to reply after that)."""
        self.intervals = {mav.MAVLINK_MSG_ID_ATTITUDE: state_interval,
                          mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: state_interval,
                          mav.MAVLINK_MSG_ID_HEARTBEAT: HEARTBEAT_S,
                          mav.MAVLINK_MSG_ID_SYS_STATUS: SYS_STATUS_S,
                          mav.MAVLINK_MSG_ID_TIMESYNC: TIMESYNC_S}
        self.last_sent = dict.fromkeys(self.intervals, -np.inf)


class SimulatedPx4(ModulePeer):
    """PX4 modules in offboard mode with a pass-through mixer, one MAVLink link (UDP port) each."""

    def _open_links(self) -> None:
        c = self.config
        self.modules = [Px4Rules() for _ in range(self.assembly.n)]
        self._vehicles: list[_Vehicle] = []
        for i in range(self.assembly.n):
            params = {name: [value, kind] for name, (value, kind) in STOCK_PARAMS.items()}
            for name, value in c.params:
                if name not in params:
                    raise ValueError(f"a simulated PX4 module has no parameter {name}")
                params[name][0] = value
            conn = mavutil.mavlink_connection(f"udpin:{c.host}:{c.port + i}", source_system=i + 1,
                                              source_component=mav.MAV_COMP_ID_AUTOPILOT1)
            self._vehicles.append(_Vehicle(conn, i + 1, 1.0 / c.state_rate_hz, params))

    def param(self, i: int, name: str) -> float:
        """Module i's parameter ``name``."""
        return self._vehicles[i].params[name][0]

    def command_timeout(self, i: int) -> float:
        """Offboard loss: module i disarms when no setpoint arrived for this long, s."""
        return self.param(i, "COM_OF_LOSS_T")

    def _rotor_inputs(self, now: float) -> np.ndarray:
        for i, m in enumerate(self.modules):
            m.enforce_timeout(now, self.command_timeout(i))
        return np.concatenate([m.thrust() for m in self.modules])

    def armed(self, i: int) -> bool:
        return self.modules[i].armed

    def locked(self, i: int) -> bool:
        return self.modules[i].stopped

    def _close_links(self) -> None:
        for v in getattr(self, "_vehicles", []):
            v.conn.close()
        self._vehicles = []

    def _serve(self, now: float) -> None:
        for i, (v, m) in enumerate(zip(self._vehicles, self.modules, strict=True)):
            while (msg := v.conn.recv_match(blocking=False)) is not None:
                self.packets += 1
                v.heard = True
                self._handle(v, m, msg, now)
            if m.armed and now - m.last_command > self.command_timeout(i):
                v.offboard = False  # offboard loss: the rules below disarm; PX4 leaves offboard too
            if v.heard:
                with contextlib.suppress(OSError):  # the ground station went away: offboard loss stops the motors
                    self._stream(i, v, m, now)

    def _handle(self, v: _Vehicle, m, msg, now: float) -> None:
        kind = msg.get_type()
        if kind == "SET_ACTUATOR_CONTROL_TARGET":
            if msg.target_system != v.system_id or msg.group_mlx != mw.ACTUATOR_GROUP:
                return
            v.last_setpoint = now
            if v.offboard:
                m.command(mw.from_controls(msg.controls, self.assembly.params.u_max), now)
        elif kind == "TIMESYNC" and msg.tc1 == 0:  # a request (tc1 > 0 answers one of ours): answered at once
            v.conn.mav.timesync_send(self._time_ns(now), msg.ts1)
        elif kind == "COMMAND_LONG" and msg.target_system == v.system_id:
            v.conn.mav.command_ack_send(msg.command, self._command(v, m, msg, now))
        elif kind in ("PARAM_REQUEST_READ", "PARAM_SET") and msg.target_system == v.system_id:
            entry = v.params.get(msg.param_id)
            if entry is None:
                return  # PX4 stays silent about a parameter it does not have
            if kind == "PARAM_SET":
                entry[0] = mw.param_from_wire(msg.param_value, entry[1])
            index = list(v.params).index(msg.param_id)
            v.conn.mav.param_value_send(msg.param_id.encode(), mw.param_to_wire(*entry), entry[1], len(v.params),
                                        index)

    def _command(self, v: _Vehicle, m, msg, now: float) -> int:
        """Carry out one COMMAND_LONG; returns the MAV_RESULT."""
        if msg.command == mav.MAV_CMD_DO_SET_MODE:
            if int(msg.param2) != mw.PX4_MAIN_MODE_OFFBOARD:
                v.offboard = False
                return mav.MAV_RESULT_ACCEPTED
            if now - v.last_setpoint > SETPOINT_STREAM_S or m.stopped:
                return mav.MAV_RESULT_TEMPORARILY_REJECTED
            v.offboard = True
            return mav.MAV_RESULT_ACCEPTED
        if msg.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            if msg.param1 < 0.5:
                m.arm(False)
                return mav.MAV_RESULT_ACCEPTED
            if m.stopped or not v.offboard:
                return mav.MAV_RESULT_DENIED
            m.arm(True)
            m.last_command = now  # arming starts the offboard-loss clock
            return mav.MAV_RESULT_ACCEPTED
        if msg.command == mav.MAV_CMD_DO_FLIGHTTERMINATION:
            if msg.param1 > 0.5:
                m.emergency_stop()
                v.offboard = False
            return mav.MAV_RESULT_ACCEPTED
        if msg.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id, interval_us = int(msg.param1), msg.param2
            if msg_id not in v.intervals or interval_us <= 0:
                return mav.MAV_RESULT_DENIED
            v.intervals[msg_id] = interval_us * 1e-6
            return mav.MAV_RESULT_ACCEPTED
        return mav.MAV_RESULT_UNSUPPORTED

    @staticmethod
    def _time_ns(now: float) -> int:
        """The module's clock (PX4's time since boot), ns: positive."""
        return max(int(now * 1e9), 1)

    def _stream(self, i: int, v: _Vehicle, m, now: float) -> None:
        due = [k for k, dt in v.intervals.items() if now - v.last_sent[k] >= dt]
        for k in due:
            v.last_sent[k] = now
        t_us, t_ms = int(now * 1e6), int(now * 1e3) & 0xFFFFFFFF
        send = v.conn.mav
        if mav.MAVLINK_MSG_ID_HEARTBEAT in due:
            base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if m.armed else 0)
            status = (mav.MAV_STATE_FLIGHT_TERMINATION if m.stopped
                      else mav.MAV_STATE_ACTIVE if m.armed else mav.MAV_STATE_STANDBY)
            send.heartbeat_send(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base,
                                mw.PX4_OFFBOARD_CUSTOM_MODE if v.offboard else 0, status)
        if mav.MAVLINK_MSG_ID_TIMESYNC in due:
            send.timesync_send(0, self._time_ns(now))
        if mav.MAVLINK_MSG_ID_SYS_STATUS in due:
            send.sys_status_send(0, 0, 0, 0, int(self.config.battery_v * 1e3), -1, -1, 0, 0, 0, 0, 0, 0)
        if mav.MAVLINK_MSG_ID_ATTITUDE in due:
            rotation = self.sim.true_state().rotation @ self.assembly.module_rotations[i]
            w = mw.FRD_TO_FLU @ self.module_gyro(i)
            send.attitude_send(t_ms, *roll_pitch_yaw(mw.px4_attitude(rotation)), *(float(x) for x in w))
        if mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW in due:
            lo, hi = int(self.param(i, "PWM_MAIN_MIN")), int(self.param(i, "PWM_MAIN_MAX"))
            pwm = (mw.to_pwm(self.module_motors(i), self.assembly.params.u_max, lo, hi) if m.armed
                   else [int(self.param(i, "PWM_MAIN_DISARM"))] * 4)
            send.servo_output_raw_send(t_us & 0xFFFFFFFF, 0, *pwm, 0, 0, 0, 0)
