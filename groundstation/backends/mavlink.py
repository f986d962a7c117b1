"""PX4 modules over MAVLink (pymavlink): one link per module, rotor commands as offboard actuator controls.

Each module runs PX4 <= 1.13 with the pass-through mixer and parameters in ``firmware_params/px4/``;
:mod:`groundstation.backends.mavlink_wire` holds the conventions. A link is a pymavlink connection string
(``udpout:127.0.0.1:14560`` for a simulated module from ``groundstation sim-peer --protocol mavlink``,
``/dev/ttyACM0,921600`` for a serial telemetry radio, ``udpin:0.0.0.0:14550`` for a vehicle that sends first).
The vehicle's system id is learnt from its first heartbeat. Sending is a socket (or serial) write on the caller's
thread; :meth:`MavlinkBackend.telemetry` parses what has arrived without blocking.

Safety at this edge: commands are bounded (``applied_command``); nothing spins before :meth:`arm`, which switches
every module to offboard and arms it, and fails (motors commanded off) unless every module confirms;
:meth:`emergency_stop` force-disarms and terminates every module; a module silent for ``link_timeout``, or one
that disarmed on its own while the flight needs it (offboard loss, a failsafe), makes ``link_ok`` False, and the
flight stops. On the vehicle, offboard loss after ``COM_OF_LOSS_T`` stops the motors if the ground station dies.

The link's round trip is measured as PX4's own tools measure it: a ``TIMESYNC`` request (``tc1`` 0, our time in
``ts1``) every ``timesync_period``, which PX4's mavlink module answers at once with its time in ``tc1`` and the
``ts1`` it got; preflight refuses a module that does not answer or answers too slowly (``max_latency``), and in
flight :attr:`~groundstation.backends.base.Telemetry.link_latency_s` carries it to the flight's link bounds. The
probes left unanswered are the link's loss (:meth:`MavlinkBackend.link_loss`). An answer counts only if it keeps
the module's own clock (its ``ATTITUDE`` stamps), and telemetry that comes older on that clock than the answers
is a delay they do not show (:meth:`MavlinkBackend.held_back`), counted into the round trip.

One flight owns a module set on this host (a lock per link, :mod:`groundstation.backends.link_lock`); PX4 <= 1.13
has no owner of its own, so a ground station on another host is kept off only by the network. Preflight refuses
two links that reach one vehicle (one system id) and reports each module's attitude for the flight's placement
check (:meth:`module_gravity`).

Every ``COMMAND_LONG`` is repeated every ``RETRY_S`` until the module acknowledges it (a radio or UDP link may
lose either): mode switch and arming within ``arm_timeout``; the emergency stop (and a normal disarm) on every
later ``send``/``telemetry`` call until confirmed or the module is lost, and for ``STOP_CONFIRM_S`` more when the
backend closes.
"""

from __future__ import annotations

import math
import statistics
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from pymavlink import mavutil

from groundstation.backends import mavlink_wire as mw
from groundstation.backends.base import (
    LOSS_CONFIDENCE_Z,
    BackendBase,
    PreflightReport,
    Telemetry,
    applied_command,
    body_rates,
    wilson_lower,
)
from groundstation.backends.link_lock import LinkLocks
from groundstation.errors import ArmingError, LinkError

mav = mavutil.mavlink


@dataclass(frozen=True)
class MavlinkSettings:
    link_timeout: float = 0.2
    """A module with no telemetry for this long is lost, s (telemetry is requested at ``telemetry_hz``)."""
    min_battery_v: float = 3.5
    """Preflight: lowest acceptable battery voltage, V (as the vehicle reports it)."""
    preflight_timeout: float = 2.0
    """Preflight: how long to wait for every module's heartbeat and telemetry, s."""
    arm_timeout: float = 2.0
    """How long :meth:`MavlinkBackend.arm` waits for every module to confirm offboard and armed, s."""
    telemetry_hz: float = 250.0
    """Rate requested for ATTITUDE (gyro) and SERVO_OUTPUT_RAW (applied motors), Hz: the control rate, as the
    attitude loop damps with these rates and an old one costs phase. Measured against ``sim-peer`` (4 ms IMU
    delay): at 100 Hz the gyro is ~19 ms old and the two-module V's pitch oscillated at 6.7 Hz (pitch rate
    60 deg/s RMS in track); at 250 Hz, ~12 ms and 9 deg/s. ~22 kB/s per module: USB, UDP, or 921600 baud serial."""
    pwm_min: int = 1000
    """us: PWM_MAIN_MIN of the modules (the mixer's output for a zero command)."""
    pwm_max: int = 2000
    """us: PWM_MAIN_MAX of the modules (full thrust)."""
    timesync_period: float = 0.01
    """A ``TIMESYNC`` probe goes to each module this often (at most once a control period), s: its answer
    measures the link's round trip."""
    latency_samples: int = 5
    """The round trip is the median of this many newest answered probes (at 250 Hz a probe every third period:
    60 ms)."""
    max_latency: float = 0.014
    """Preflight: largest acceptable round trip (the median), s."""
    command_period: float = 0.004
    """The flight's control period: preflight reads the links at it, so the round trips it measures (each a lower
    bound, short by up to one read's wait) are the flight's, s."""
    stamp_slack: float = 0.002
    """How much older than its TIMESYNC answers a module's ``ATTITUDE`` may be on its own clock (both on their
    fastest path), s: PX4 stamps the attitude when it is estimated, before it goes out; the freshest of a stretch
    went within a millisecond or two."""


OVERTAKEN_SEQS = 16
"""Sequence numbers skipped that a later message may still fill (overtaken on a reordering link), at most."""
OVERTAKEN_S = 0.2
"""How late an overtaken message may come, s (a sequence number recurs every 256 messages, ~0.5 s)."""
SEQUENCE_RESYNC = 4
"""A module's messages this many in a row in order, all behind its newest, are where its sequence went on after
128 or more were lost (a duplicate or an overtaken message comes alone)."""
HEARTBEAT_S = 1.0
"""Ground-station heartbeat interval, s (PX4's data-link loss check listens for it)."""
ARM_GRACE_S = 1.0
"""A disarmed heartbeat this soon after a module acknowledged arming is stale (one PX4 heartbeat interval), s."""
RETRY_S = 0.1
"""Interval between repeats of an unacknowledged command, s."""
STOP_CONFIRM_S = 0.5
"""How long closing the backend repeats an unconfirmed stop or disarm, s."""
LOSS_WINDOW_S = 0.5
"""The loss is taken over the probes sent in this stretch (ending ``link_timeout`` ago: younger ones may still be
answered), s."""
MIN_LOSS_PROBES = 20
"""Fewer probes in the window measure no loss."""
CLOCK_WINDOW_S = 0.2
"""The module's clock is compared with ours over the newest stretch this long, s."""
FOREIGN_CLOCK_S = 0.05
"""An answer whose ``tc1`` is this far off the module's own ``ATTITUDE`` stamps (on the fastest path) was not
made by it, s."""
SETPOINT_LEAD_S = 1.0
"""Zero setpoints streamed before the switch to offboard, s: PX4 refuses offboard without a setpoint stream, and
its documentation (v1.14 on) asks for more than 1 s of it before arming in offboard."""


class _Module:
    def __init__(self, conn) -> None:
        self.conn = conn
        self.system_id: int | None = None
        """Learnt from the first autopilot heartbeat."""
        self.component_id = mav.MAV_COMP_ID_AUTOPILOT1
        self.heard = -np.inf
        self.gyro_heard = -np.inf
        """When the newest ATTITUDE (the body rate) arrived, s."""
        self.battery_heard = -np.inf
        """When SYS_STATUS last came (it is slower than the rest: 10 Hz on PX4)."""
        self.armed = False
        self.disarm_heard = False
        """In flight a heartbeat said the module disarmed: its next outputs confirm it (or not)."""
        self.terminated = False
        self.armed_at = -np.inf
        """When the module acknowledged arming."""
        self.acks: dict[int, int] = {}
        """Last COMMAND_ACK result per command id."""
        self.stop_acked = False
        self.arm_wanted = False
        """The last arm/disarm command asked to arm (its ACK then means armed)."""
        self.pending: list[tuple[int, tuple[float, ...]]] = []
        """Commands to repeat until acknowledged: (command, params) (the stop or a normal disarm)."""
        self.pending_sent = -np.inf
        self.up: np.ndarray | None = None
        """Up in the module's frame from its newest ATTITUDE (unit)."""
        self.probes: dict[int, float] = {}
        """``ts1`` of each TIMESYNC probe sent since the newest answered one -> when it was sent, s (oldest first:
        an answer drops the probes before its own, lost or overtaken)."""
        self.sent: deque[tuple[float, bool]] = deque()
        """(when, answered) of each probe of the loss window, oldest first."""
        self.answer_clock: deque[tuple[float, float]] = deque()
        self.attitude_clock: deque[tuple[float, float]] = deque()
        """(when found, the module's clock in the message less that) of each TIMESYNC answer and ATTITUDE of
        :data:`CLOCK_WINDOW_S`, s: on the fastest path the largest of each is the clocks' offset less the
        way back, the same for both when both come from the module as they are sent."""
        self.rtts: deque[float] = deque()
        """The newest round trips measured, s."""
        self.last_seq: int | None = None
        """The MAVLink sequence number of the module autopilot's newest message (its link counts them, mod 256)."""
        self.behind = 0
        """The module's newest messages in a row that came in order behind :attr:`last_seq`."""
        self.behind_seq = 0
        """The newest of them."""
        self.skipped: deque[tuple[int, float]] = deque(maxlen=OVERTAKEN_SEQS)
        """(sequence number, when) of the newest skipped (counted missing): one that comes within
        :data:`OVERTAKEN_S` was overtaken, not lost."""
        self.seq_gaps: deque[tuple[float, int]] = deque()
        """(when, messages missing just before it) of each of the module's messages in order, oldest first: what
        its way to us loses, which a relay answering the probes itself does not hide (hostile campaign 31)."""
        self.route: int | None = None
        """The other link this module's messages came on (a relay swapped links in flight), or None: its commands
        go down that link too (its own may still reach it, if only one way was swapped)."""


class MavlinkBackend(BackendBase):
    """``n`` PX4 modules of one assembly, in assembly order (module i drives rotors 4i..4i+3)."""

    def __init__(self, links: list[str] | tuple[str, ...], u_max: float, module_rotations: np.ndarray,
                 settings: MavlinkSettings | None = None, clock=time.monotonic) -> None:
        if len(links) != len(module_rotations):
            raise ValueError(f"{len(links)} links for {len(module_rotations)} modules")
        self.links = tuple(links)
        self.u_max = u_max
        self.settings = settings or MavlinkSettings()
        self._rotations = np.asarray(module_rotations, float)
        self._clock = clock
        self._modules: list[_Module] = []
        n = len(links)
        self._armed = False
        self._applied = np.zeros(4 * n)
        self._battery = np.zeros(n)
        self._gyro = np.zeros((n, 3))
        self._stop_sent = False
        self._last_heartbeat = -np.inf
        self._last_probe = -np.inf
        self._polled = -np.inf
        """When the link was last read: an answer found now arrived after that (a lower bound on its time)."""
        self._locks = LinkLocks(self.links)
        self.rerouted = ""
        """Which modules' messages came on another module's link (see :attr:`Telemetry.rerouted`)."""

    # -- Backend protocol ---------------------------------------------------------------------------------------
    def connect(self) -> None:
        if self._modules:
            return
        self._locks.acquire()
        for link in self.links:
            try:
                conn = mavutil.mavlink_connection(link, source_system=mw.GCS_SYSTEM_ID,
                                                  source_component=mw.GCS_COMPONENT_ID)
            except Exception as exc:  # pymavlink raises per transport (serial, socket, bad string)
                self.close()
                raise LinkError(f"cannot open {link}: {exc}") from None
            self._modules.append(_Module(conn))
        self._heartbeat(force=True)

    def preflight(self) -> PreflightReport:
        if not self._modules:
            return PreflightReport(False, ("not connected",))
        s = self.settings
        since = self._clock()
        deadline = since + s.preflight_timeout
        requested = [False] * len(self._modules)
        for m in self._modules:
            m.rtts.clear()  # measured afresh: the link as it is now
            m.probes.clear()
            m.sent.clear()
            m.answer_clock.clear()
            m.attitude_clock.clear()
            m.seq_gaps.clear()
            m.last_seq, m.behind = None, 0
            m.skipped.clear()
        # PX4 switches to offboard only while setpoints stream: stream zeros (disarmed, nothing spins).
        while self._clock() < deadline and not all(m.battery_heard >= since and r and len(m.rtts) >= s.latency_samples
                                                   for m, r in zip(self._modules, requested, strict=True)):
            self._heartbeat(force=True)
            self._send_controls(np.zeros_like(self._applied))
            self._probe()
            time.sleep(s.command_period)
            self._drain()
            for i, m in enumerate(self._modules):
                if m.system_id is not None and not requested[i]:
                    self._request_streams(m)
                    requested[i] = True
        issues = [f"module {i} ({self.links[i]}) does not answer" for i, m in enumerate(self._modules)
                  if m.system_id is None or m.heard < since]
        issues += [f"module {i} ({self.links[i]}) does not report its battery" for i, m in enumerate(self._modules)
                   if m.system_id is not None and m.heard >= since and m.battery_heard < since]
        issues += [f"module {i} battery {v:.2f} V < {self.settings.min_battery_v:g} V"
                   for i, v in enumerate(self._battery)
                   if self._modules[i].battery_heard >= since and v < self.settings.min_battery_v]
        answering = [m.system_id is not None and m.heard >= since for m in self._modules]
        issues += [f"module {i} ({self.links[i]}) does not answer TIMESYNC: its link's round trip cannot be measured"
                   for i, m in enumerate(self._modules) if answering[i] and not m.rtts]
        latency = self.link_latency()
        issues += [f"module {i} ({self.links[i]}) link round trip {latency[i] * 1e3:.0f} ms > "
                   f"{s.max_latency * 1e3:g} ms" for i in range(len(self._modules))
                   if answering[i] and self._modules[i].rtts and latency[i] > s.max_latency]
        issues += [f"module {i} is flight-terminated (reboot it)" for i, m in enumerate(self._modules) if m.terminated]
        issues += [f"module {i} is already armed" for i, m in enumerate(self._modules) if m.armed]
        if self.rerouted:  # each link must reach its own module alone: a router or a shared network would land
            # the flight at take-off (and a swap in preflight is a swap)
            issues.append(f"{self.rerouted}: each link must carry its own module's messages alone")
        first: dict[int, int] = {}
        for i, m in enumerate(self._modules):
            if m.system_id is not None and first.setdefault(m.system_id, i) != i:
                j = first[m.system_id]
                issues.append(f"module {j} ({self.links[j]}) and module {i} ({self.links[i]}) are one vehicle "
                              f"(system id {m.system_id}): two links reach it")
        return PreflightReport(not issues, tuple(issues))

    def module_gravity(self) -> np.ndarray | None:
        """Per module, up in its own frame from its newest attitude (unit), or None until every module sent one."""
        if not self._modules or any(m.up is None for m in self._modules):
            return None
        return np.array([m.up for m in self._modules])

    def arm(self) -> None:
        """Switch every module to offboard and arm it; raises ArmingError (motors off) unless all confirm."""
        deadline = self._clock() + self.settings.arm_timeout
        while self._clock() < deadline and any(m.system_id is None for m in self._modules):
            self._heartbeat(force=True)  # a module learns where we are from our first packet
            time.sleep(0.005)
            self._drain()
        for i, m in enumerate(self._modules):
            if m.system_id is None:
                raise ArmingError(f"module {i} ({self.links[i]}): no heartbeat within "
                                      f"{self.settings.arm_timeout:g} s")
        lead_end = self._clock() + SETPOINT_LEAD_S
        while self._clock() < lead_end:  # PX4 enters offboard only once setpoints stream
            self._send_controls(np.zeros_like(self._applied))
            time.sleep(0.01)
            self._drain()
        for m in self._modules:
            m.acks.clear()
            m.arm_wanted = True
        self._await(mav.MAV_CMD_DO_SET_MODE, "switch to offboard", mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                    mw.PX4_MAIN_MODE_OFFBOARD)
        self._await(mav.MAV_CMD_COMPONENT_ARM_DISARM, "arm", 1.0)
        self._armed = True

    def send(self, u: np.ndarray) -> None:
        """Command rotor inputs (4n,), rad^2/s^2; bounded to [0, u_max]; zero unless armed."""
        self._send_controls(applied_command(u, self._applied.size, self._armed, self.u_max))
        self._heartbeat()
        self._probe()
        self._repeat_pending()

    def telemetry(self) -> Telemetry:
        self._drain()
        self._repeat_pending()
        now = self._clock()
        # In flight the body rate must keep coming too: a module whose ATTITUDE stopped while its heartbeats go
        # on leaves the attitude loop without its gyros (the estimator holds a stale reading, it does not fly on it).
        fresh = all(now - m.heard <= self.settings.link_timeout and
                    (not self._armed or now - m.gyro_heard <= self.settings.link_timeout) for m in self._modules)
        # A module that disarmed itself (offboard loss, a failsafe) no longer flies: the flight must stop.
        holding = not self._armed or all(m.armed for m in self._modules)
        rates = body_rates(self._rotations, self._gyro)
        heard = max((m.heard for m in self._modules), default=-np.inf)
        gyro_heard = min((m.gyro_heard for m in self._modules), default=-np.inf)
        return Telemetry(stamp=float(heard) if np.isfinite(heard) else 0.0,
                         link_ok=bool(self._modules) and fresh and holding, motors=self._applied.copy(),
                         gyro_age_s=float(now - gyro_heard),
                         module_gyro_ages_s=now - np.array([m.gyro_heard for m in self._modules]),
                         battery_v=self._battery.copy(), gyro=rates.mean(axis=0), module_gyros=rates,
                         link_latency_s=self.link_latency(), link_loss=self.link_loss(), rerouted=self.rerouted)

    def link_latency(self) -> np.ndarray:
        """Per module, the median of its newest round trips (``latency_samples``), s; NaN until one is measured.
        Each is a lower bound: from the probe's send to the last read of the link that had not found its answer (a
        busy ground station's late reads are not the link's). Plus twice what the module's ``ATTITUDE`` is older
        on its own clock than its answers beyond ``stamp_slack`` (:meth:`held_back`): a relay answering the probes
        itself and holding the rest back 10 ms each way read 0 ms, and the V flipped (hostile campaign 29)."""
        held = self.held_back()
        return np.array([(statistics.median(m.rtts) if m.rtts else np.nan) + (2.0 * h if h > 0 else 0.0)
                         for m, h in zip(self._modules, held, strict=True)])

    def held_back(self) -> np.ndarray:
        """Per module, how much older its ``ATTITUDE`` comes than its TIMESYNC answers, on its own clock, s, when
        that is more than ``stamp_slack`` (else 0; NaN until both came): what the link holds back that the answers
        do not show (the way there taken as long again)."""
        out = []
        since = self._polled - CLOCK_WINDOW_S  # a stream that stopped says nothing of the link as it is now
        for m in self._modules:
            answers = [q for t, q in m.answer_clock if t >= since]
            attitudes = [q for t, q in m.attitude_clock if t >= since]
            if not (answers and attitudes):
                out.append(np.nan)
                continue
            held = max(answers) - max(attitudes)
            out.append(held if held > self.settings.stamp_slack else 0.0)
        return np.array(out)

    def link_loss(self) -> np.ndarray:
        """Per module, the fraction of packets lost each way over :data:`LOSS_WINDOW_S`, from the probes left
        unanswered ``link_timeout`` after they went (an answer that comes later still marks its probe answered),
        both ways taken alike: 1 - sqrt(answered), the share answered taken at the upper end of its confidence
        interval (:data:`LOSS_CONFIDENCE_Z`); or, if more, the share of the module's own messages missing from
        their sequence numbers (the way back alone, which forged answers to the probes do not hide). NaN under
        :data:`MIN_LOSS_PROBES` of both. Answers that stop while the rest of the link flows (or a round trip
        beyond the timeout) read as 100 %: a degraded link, never an old median held (nor a silence taken for a
        round trip: 30 % loss made runs of ten probes in a row go unanswered, read as 100 ms round trips that
        stopped the motors 0.95 m up; hostile campaign 29)."""
        out = []
        for m in self._modules:
            end = self._polled - self.settings.link_timeout
            judged = [answered for t, answered in m.sent if end - LOSS_WINDOW_S <= t < end]
            each_way = np.nan
            if len(judged) >= MIN_LOSS_PROBES:
                lost = wilson_lower(len(judged) - sum(judged), len(judged), LOSS_CONFIDENCE_Z)
                each_way = 1.0 - math.sqrt(1.0 - lost)
            # The way back, counted by the module's own numbers (a link gone quiet keeps no old window).
            gaps = [gap for t, gap in m.seq_gaps if t >= self._polled - LOSS_WINDOW_S]
            # An overtaken message's -1 may fall in the window without the gap it takes back: never below none.
            missing, came = max(sum(gaps), 0), len(gaps)
            back = wilson_lower(missing, missing + came, LOSS_CONFIDENCE_Z) if came >= MIN_LOSS_PROBES else np.nan
            out.append(np.nan if np.isnan(each_way) and np.isnan(back) else np.nanmax([each_way, back]))
        return np.array(out)

    def disarm(self) -> None:
        """End a flight normally: zero controls and a plain disarm (no termination: the modules can fly again)."""
        self._armed = False
        self._send_controls(np.zeros_like(self._applied))
        for m in self._modules:
            m.arm_wanted = False
            m.acks.pop(mav.MAV_CMD_COMPONENT_ARM_DISARM, None)
            self._until_acked(m, [(mav.MAV_CMD_COMPONENT_ARM_DISARM, (0.0,))])

    def emergency_stop(self) -> None:
        """Force-disarm and terminate every module, and command zero, at once (no waiting for answers)."""
        self._armed = False
        self._stop_sent = True
        for m in self._modules:
            m.stop_acked = False
            m.arm_wanted = False
            for c in (mav.MAV_CMD_COMPONENT_ARM_DISARM, mav.MAV_CMD_DO_FLIGHTTERMINATION):
                m.acks.pop(c, None)
            self._until_acked(m, [(mav.MAV_CMD_COMPONENT_ARM_DISARM, (0.0, mw.FORCE_DISARM)),
                                  (mav.MAV_CMD_DO_FLIGHTTERMINATION, (1.0,))])
        self._send_controls(np.zeros_like(self._applied))
        self._applied[:] = 0.0

    def close(self) -> None:
        deadline = self._clock() + STOP_CONFIRM_S
        while any(m.pending for m in self._modules) and self._clock() < deadline:
            time.sleep(0.01)
            self._drain()
            self._repeat_pending()
        for m in self._modules:
            m.conn.close()
        self._modules = []
        self._locks.release()

    def unconfirmed(self) -> list[int]:
        """Modules that have not acknowledged the stop or disarm sent to them."""
        return [i for i, m in enumerate(self._modules) if m.pending]


    # -- wire ---------------------------------------------------------------------------------------------------
    def _heartbeat(self, force: bool = False) -> None:
        now = self._clock()
        if not force and now - self._last_heartbeat < HEARTBEAT_S:
            return
        self._last_heartbeat = now
        for m in self._modules:
            m.conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)

    def _probe(self) -> None:
        """A ``TIMESYNC`` request (``tc1`` 0) to each module every ``timesync_period``: PX4 answers at once with its
        own time in ``tc1`` and ``ts1`` as sent, which names the probe."""
        now = self._clock()
        if now - self._last_probe < self.settings.timesync_period:
            return
        self._last_probe = now
        ts1 = time.monotonic_ns()
        for m in self._modules:
            if m.system_id is None:
                continue
            m.probes[ts1] = now
            m.sent.append((now, False))
            while m.sent[0][0] < now - self.settings.link_timeout - LOSS_WINDOW_S:
                m.sent.popleft()
            while len(m.probes) > len(m.sent):  # answers stopped: what left the window is no longer awaited
                del m.probes[next(iter(m.probes))]
            m.conn.mav.timesync_send(0, ts1)

    def _send_controls(self, u: np.ndarray) -> None:
        t_us = int(self._clock() * 1e6)
        for i, m in enumerate(self._modules):
            if m.system_id is None:
                continue  # not heard yet: nothing to address (and nothing armed)
            if m.armed and not m.arm_wanted and not self._stop_sent:
                # Armed, not by us: another ground station flies it (through a relay, past this host's link
                # locks). Our preflight's zeros would reach it: they disturbed the airborne first flight, 1 in 4.
                continue
            for conn in self._conns(m):
                conn.mav.set_actuator_control_target_send(t_us, mw.ACTUATOR_GROUP, m.system_id, m.component_id,
                                                          mw.to_controls(u[4 * i:4 * i + 4], self.u_max))

    def _command(self, m: _Module, command: int, *params: float) -> None:
        p = (list(params) + [0.0] * 7)[:7]
        for conn in self._conns(m):
            conn.mav.command_long_send(m.system_id or 0, m.component_id, command, 0, *p)

    def _conns(self, m: _Module) -> list:
        """The links ``m``'s commands go down: its own, and the one its messages came on if another (a module
        drops what is addressed to another system, so the copy down the wrong link is harmless)."""
        return [m.conn] if m.route is None else [m.conn, self._modules[m.route].conn]

    def _until_acked(self, m: _Module, commands: list[tuple[int, tuple[float, ...]]]) -> None:
        """Send ``commands`` now and repeat them until acknowledged (:meth:`_repeat_pending`)."""
        m.pending = list(commands)
        for command, params in commands:
            self._command(m, command, *params)
        m.pending_sent = self._clock()

    def _repeat_pending(self) -> None:
        now = self._clock()
        for m in self._modules:
            m.pending = [(c, p) for c, p in m.pending if c not in m.acks]
            if not m.pending or now - m.pending_sent < RETRY_S:
                continue
            if now - m.heard > self.settings.link_timeout * 10:
                continue  # lost: nothing gets through (the flight knows: link_ok is False)
            for command, params in m.pending:
                self._command(m, command, *params)
            m.pending_sent = now

    def _request_streams(self, m: _Module) -> None:
        interval_us = 1e6 / self.settings.telemetry_hz
        for msg_id in (mav.MAVLINK_MSG_ID_ATTITUDE, mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW):
            self._command(m, mav.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us)

    def _await(self, command: int, what: str, *params: float) -> None:
        """Send ``command`` to every module and repeat it every ``RETRY_S`` to those that have not acknowledged,
        until all have or ``arm_timeout`` passed (keeping setpoints and heartbeats flowing)."""
        deadline = self._clock() + self.settings.arm_timeout
        sent = -np.inf
        while self._clock() < deadline and not all(command in m.acks for m in self._modules):
            if self._clock() - sent >= RETRY_S:
                for m in self._modules:
                    if command not in m.acks:
                        self._command(m, command, *params)
                sent = self._clock()
            self._send_controls(np.zeros_like(self._applied))
            self._heartbeat()
            time.sleep(0.005)
            self._drain()
        for i, m in enumerate(self._modules):
            if command not in m.acks:
                raise ArmingError(f"module {i} ({self.links[i]}): no answer to '{what}' within "
                                      f"{self.settings.arm_timeout:g} s")
            if m.acks[command] != mav.MAV_RESULT_ACCEPTED:
                result = mav.enums["MAV_RESULT"][m.acks[command]].name
                raise ArmingError(f"module {i} ({self.links[i]}) refused to {what}: {result}")

    def _drain(self) -> None:
        now = self._clock()
        s = self.settings
        polled, self._polled = self._polled, now
        for link, on_link in enumerate(self._modules):
            while (msg := on_link.conn.recv_match(blocking=False)) is not None:
                kind = msg.get_type()
                i = None if kind == "BAD_DATA" else self._sender(link, msg.get_srcSystem())
                if i is None:
                    continue
                m = self._modules[i]
                if m.system_id is not None and msg.get_srcComponent() == m.component_id:
                    self._count_sequence(m, msg.get_seq(), now)
                if kind == "HEARTBEAT":
                    if msg.type == mav.MAV_TYPE_GCS or msg.autopilot == mav.MAV_AUTOPILOT_INVALID:
                        continue  # another ground station or a peripheral, not the module's autopilot
                    m.system_id, m.component_id = msg.get_srcSystem(), msg.get_srcComponent()
                    armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
                    # PX4 acknowledges on its receive thread and sends heartbeats from another: a heartbeat built
                    # just before arming may arrive after the ACK. Only a later one says the module disarmed; in
                    # flight, once its own outputs say so too (below): one forged heartbeat, unsigned as MAVLink 2
                    # is here, or another vehicle's of the same system id on a shared radio, stopped the motors
                    # 0.77 m up (hostile campaign 34).
                    if armed:
                        m.armed, m.disarm_heard = True, False
                    elif now - m.armed_at > ARM_GRACE_S:
                        m.disarm_heard = m.armed and self._armed
                        m.armed = m.armed and self._armed
                    m.terminated = msg.system_status == mav.MAV_STATE_FLIGHT_TERMINATION
                elif m.system_id is None:
                    continue  # until the autopilot's heartbeat says who the module is
                elif kind == "COMMAND_ACK":
                    m.acks[msg.command] = msg.result
                    if msg.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
                        m.armed = msg.result == mav.MAV_RESULT_ACCEPTED and m.arm_wanted and not self._stop_sent
                        m.armed_at = now if m.armed else m.armed_at
                        m.stop_acked = m.stop_acked or self._stop_sent
                elif kind == "ATTITUDE":
                    self._gyro[i] = mw.FRD_TO_FLU @ np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])
                    m.gyro_heard = now
                    m.up = mw.up_in_module(msg.roll, msg.pitch)
                    _clock_sample(m.attitude_clock, now, msg.time_boot_ms * 1e-3 - now)  # uint32 ms: wraps
                elif kind == "SERVO_OUTPUT_RAW":
                    pwm = (msg.servo1_raw, msg.servo2_raw, msg.servo3_raw, msg.servo4_raw)
                    if m.disarm_heard:  # a disarmed module outputs PWM_MAIN_DISARM, below the armed range
                        m.armed, m.disarm_heard = not all(p < s.pwm_min for p in pwm), False
                    # Outputs sent before the module saw the stop still show thrust; the disarm's ACK comes
                    # after them on the same link, so only later outputs say what is applied now.
                    if not self._stop_sent or m.stop_acked:
                        self._applied[4 * i:4 * i + 4] = mw.from_pwm(pwm, self.u_max, s.pwm_min, s.pwm_max)
                elif kind == "SYS_STATUS":
                    self._battery[i] = msg.voltage_battery * 1e-3
                    m.battery_heard = now
                elif kind == "TIMESYNC":
                    # An answer names one of our probes (ts1) and carries the module's time (tc1 > 0); the
                    # module's own requests (tc1 0), a repeated answer, one for a probe we did not send, and one
                    # from another component of the vehicle (TIMESYNC is broadcast: a companion computer answers
                    # too, and would measure only the way to itself) do not measure anything.
                    if msg.tc1 <= 0 or msg.get_srcComponent() != m.component_id or msg.ts1 not in m.probes:
                        continue
                    clock = _wrapped_ms(msg.tc1) * 1e-3 - now  # as ATTITUDE's time_boot_ms wraps (49.7 days)
                    # Not the module's clock (or none of its ATTITUDE yet to tell): something else on the link may
                    # answer for it (lost).
                    if not m.attitude_clock or abs(clock - max(q for _, q in m.attitude_clock)) > FOREIGN_CLOCK_S:
                        continue
                    _clock_sample(m.answer_clock, now, clock)
                    sent = m.probes[msg.ts1]
                    m.probes = {k: t for k, t in m.probes.items() if t > sent}
                    m.rtts.append(max(polled - sent, 0.0))
                    for j in range(len(m.sent) - 1, -1, -1):  # its entry in the loss window, found from the newest
                        if m.sent[j][0] == sent:
                            m.sent[j] = (sent, True)
                            break
                    if len(m.rtts) > s.latency_samples:
                        m.rtts.popleft()
                else:
                    continue
                m.heard = now

    @staticmethod
    def _count_sequence(m: _Module, seq: int, now: float) -> None:
        """Count one of the module's messages into :attr:`_Module.seq_gaps` by its MAVLink sequence number."""
        gap = (seq - m.last_seq - 1) & 0xFF if m.last_seq is not None else 0
        if gap >= 128:
            late = next((k for k in m.skipped if k[0] == seq and now - k[1] < OVERTAKEN_S), None)
            if late is not None:  # overtaken: counted missing when skipped, it came after all
                m.skipped.remove(late)
                m.seq_gaps.append((now, -1))  # one more came, one fewer missing (30 % reordered read 10 % lost)
                return
            # Behind the newest: a duplicate; unless such messages run on in order, from where the sequence went
            # on after a burst of 128 or more lost (read as behind, the rest of the flight's messages counted
            # nothing).
            m.behind = m.behind + 1 if m.behind and seq == (m.behind_seq + 1) & 0xFF else 1
            m.behind_seq = seq
            if m.behind < SEQUENCE_RESYNC:
                return
            gap = (seq - SEQUENCE_RESYNC + 1 - m.last_seq - 1) & 0xFF  # at least: a multiple of 256 may hide too
        elif 0 < gap <= OVERTAKEN_SEQS and m.last_seq is not None:
            m.skipped.extend(((m.last_seq + k) & 0xFF, now) for k in range(1, gap + 1))
        m.behind = 0
        m.last_seq = seq
        m.seq_gaps.append((now, gap))
        while m.seq_gaps[0][0] < now - LOSS_WINDOW_S:
            m.seq_gaps.popleft()

    def _sender(self, link: int, system_id: int) -> int | None:
        """The module that sent a message from ``system_id`` on ``link``: the link's own until its heartbeat named
        it (preflight learns each link's system id), else the module of that system id, wherever it came (a relay
        that swapped links in flight: noted in :attr:`rerouted`, which lands the flight); None for other systems."""
        own = self._modules[link].system_id
        if own is None or own == system_id:
            return link
        i = next((k for k, m in enumerate(self._modules) if m.system_id == system_id), None)
        if i is not None and self._modules[i].route != link:
            self._modules[i].route = link
            note = (f"module {i}'s messages (system id {system_id}) came on module {link}'s link ({self.links[link]}):"
                    f" its commands go down both")
            self.rerouted = f"{self.rerouted}; {note}" if self.rerouted else note
        return i


def _clock_sample(samples: deque[tuple[float, float]], now: float, clock: float) -> None:
    """Add one (``now``, ``clock``) to ``samples``, forgetting those older than :data:`CLOCK_WINDOW_S`."""
    samples.append((now, clock))
    while samples[0][0] < now - CLOCK_WINDOW_S:
        samples.popleft()


def _wrapped_ms(ns: int) -> float:
    """A time in ns as a uint32 ms count wraps (``time_boot_ms``), keeping its fraction, ms."""
    return (ns / 1e6) % 2.0**32

