"""``fly``: load a flight config, connect, check, arm, take off, track, land, disarm; log everything to MCAP.

The backend kind (:mod:`groundstation.backend_kinds`) names the world the flight flies in: ``sim`` runs PyBullet
inside this process and publishes its physics pose over Zenoh through a virtual mocap (``sim.world``), so a dry
run exercises the same loop, Zenoh path and logging as a flight with real mocap; the simulator is advanced to the
wall time at the start of every period. ``crazyflie`` drives one cflib link per module (radio or UDP) and
``mavlink`` one pymavlink connection per PX4 module (:mod:`groundstation.runtime.hardware`); both take poses from
whatever publishes them on Zenoh: a mocap bridge, or ``groundstation sim-peer``, which simulates the modules behind
their real wire protocol in another process. A hardware flight never imports the simulator.

Operator: the first Ctrl-C (or SIGTERM, SIGHUP) lands, a second one stops the motors at once; before arming, the
first ends the flight unarmed (``aborted``), a second interrupts whatever it waits for. Every exit path ends with
the motors off and the MCAP file finalized, its end (phase and reason) in it: a normal landing disarms the modules
(they can fly again at once), every other path sends the emergency stop. The log file is claimed exclusively: an
existing file is never overwritten. A flight that landed as planned but beyond its :class:`QualityBounds` is
``degraded`` (:attr:`FlyResult.degraded`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from groundstation import __version__, config
from groundstation.assembly.assembly import Assembly
from groundstation.assembly.assembly_file import assembly_record, load_assembly
from groundstation.backend_kinds import BackendKind, backend_kind, load
from groundstation.control.geometric import Gains
from groundstation.control.model import ControlModel
from groundstation.control.phase import Phase
from groundstation.control.trajectory import Circle, Figure8, FlightPlan, Hover, make_track
from groundstation.errors import ConfigError, PreflightError, UsageError
from groundstation.estimation.filter import RigidBodyFilter
from groundstation.estimation.measurement import PoseMeasurement
from groundstation.firmware.modules import check_modules, required_params
from groundstation.firmware.params import issues as param_issues
from groundstation.flightlog.mcap_log import WRITER_START_S, FlightLog, claim
from groundstation.loop_activity import LoopActivity
from groundstation.mocap.auth import MocapKey
from groundstation.mocap.codec import challenge_key
from groundstation.mocap.stamp_clock import StampClockSettings
from groundstation.mocap.zenoh_link import (
    PoseSubscriber,
    Security,
    SubscriberSettings,
    check_listenable,
    open_session,
    pose_key,
)
from groundstation.runtime.closed_loop import (
    FlightVolume,
    dynamics_check,
    flight_summary,
    hover_check,
    volume_check,
)
from groundstation.runtime.flight import (
    FailsafePolicy,
    Flight,
    MocapIntegrity,
    QualityBounds,
    Requests,
    degradation,
    operator_landing,
    poses_kept_up,
)
from groundstation.runtime.flight_config import (
    FlightConfig,
    TrajectorySection,
    estimator_settings,
    load_flight_config,
    log_directory,
    mocap_mac_key,
    mocap_security,
)
from groundstation.runtime.loop import SPIN_RT_S, SPIN_S, LoopStats, WallClock, realtime_priority
from groundstation.runtime.metrics import FlightMetrics, FlightSummary
from groundstation.runtime.placement import placement_issues
from groundstation.runtime.signals import LANDING_SIGNALS, NEVER_A_STOP, TOOL_SIGNALS, signal_name
from groundstation.runtime.terminal import forget_lost_terminal

MIN_LOG_ROOM_BYTES = 200_000
"""Preflight: room left on the log's disk at least this, bytes: about a second of the log (the main command's: 4.2 MB
for 18 s at 250 Hz, two modules). On 24 KiB the writer's header fit and the flight armed and took off with a log
that held nothing of it (hostile campaign 34); a disk that fills later lands the flight (``on_log_failure``)."""
PREFLIGHT_TIMEOUT_S = 3.0
PREFLIGHT_POLL_S = 0.005
"""Preflight reads the mocap stream this often, s (a keyed stream's challenges go out at its reads)."""
GIL_SWITCH_S = 1e-4
STILL_SPEED = 0.2
"""Preflight: the estimated speed must be below this (mocap noise alone gives a few cm/s), m/s."""


@dataclass
class Faults:
    """Fault injection for drills and tests: set these (e.g. from ``on_period``) during a simulated flight.

    ``mocap_*``, ``link_lost``, ``gyro_failed``, ``gyros_stuck``, ``gyros_flipped``, ``tied_down`` and ``push_n`` act on
    the in-process simulator only; with simulated Crazyflie or PX4 modules, stop the peer process to lose the link."""

    mocap_paused: bool = False
    """The virtual mocap stops publishing."""
    mocap_frozen: bool = False
    """The virtual mocap publishes its last pose again and again, freshly stamped."""
    mocap_decoy: bool = False
    """The virtual mocap measures another body, resting where the assembly stood (``mocap.body`` naming the wrong
    one), with its noise and stamps..."""
    mocap_decoy_climb_mps: float = 0.0
    """...rising at this rate meanwhile, m/s."""
    mocap_restarts: int = 0
    """Each increase restarts the virtual mocap's publisher: a new one (a new entity id, its sequence from 1), as a
    restarted bridge (pause it meanwhile with ``mocap_paused``: a restart takes a while)."""
    corrupt_pose: bool = False
    """The pose source hands the estimator NaN positions."""
    link_lost: bool = False
    """The backend reports its link lost."""
    gyro_failed: int | None = None
    """This module's gyro reads full scale (2000 deg/s) about its x axis (a failed IMU)."""
    gyros_stuck: float | None = None
    """Every module's gyro reads this rate about each body axis, rad/s, the same every time (NaN: not a number):
    the modules agree with each other, and are all wrong."""
    gyros_flipped: bool = False
    """Every module's gyro reads the body rate with its sign flipped (a firmware or configuration error common to
    all): they agree with each other, and are all wrong."""
    tied_down: bool = False
    """The assembly is fixed where it is (a forgotten tie-down, a snagged cable): the rotors spin, it stays."""
    push_n: tuple[float, float, float] | None = None
    """A force on the assembly meanwhile, world frame, N (a shove, a gust)."""
    pose_stamp: float | None = None
    """The mocap samples logged meanwhile carry this publish stamp instead of theirs (a source whose clock is broken:
    NaN, negative, in milliseconds); the log writer must reject them, not fail. The estimate is not affected."""


@dataclass
class FlyResult:
    log_path: Path
    phase: Phase
    """Final state: ``done`` (landed, disarmed), ``emergency`` (motors stopped) or ``aborted`` (ended before
    take-off: never armed, or disarmed while arming)."""
    reason: str
    """Why the flight ended early ("" when it flew its plan; "operator land" when the operator cut it short)."""
    metrics: FlightSummary
    events: list = field(default_factory=list)
    log_error: str | None = None
    """Why the log writer failed or hung (None: the log is complete)."""
    log_rejected: dict = field(default_factory=dict)
    """Messages the log writer did not write, by topic and why (a stamp that is not a time): counted, not fatal."""
    degraded: tuple[str, ...] = ()
    """What went beyond the flight's :class:`QualityBounds`, one phrase each (empty: within them; judged only for a
    flight that landed as planned or as the operator asked)."""

    @property
    def nominal(self) -> bool:
        """Landed as planned or as the operator asked, with a complete log; a failsafe landing is not nominal. (A
        nominal flight may still be :attr:`degraded`.)"""
        return self.phase == Phase.DONE and (self.reason == "" or operator_landing(self.reason)) and \
            self.log_error is None


MOCAP_STATS_S = 1.0
"""Interval of the mocap counters in the log, s."""


class _LoggedPose:
    """The Zenoh subscriber as the flight's pose source; logs every received payload unchanged, and the
    subscriber's counters about once a second (``/mocap/stats``)."""

    def __init__(self, sub: PoseSubscriber, log: FlightLog, topic: str, faults: Faults,
                 to_log: Callable[[float], float]) -> None:
        self._sub, self._log, self._topic, self._faults = sub, log, topic, faults
        self._to_log = to_log
        self._stats_at = (-np.inf, 0)
        """(monotonic time, accepted count) of the last /mocap/stats record."""
        self._handovers = 0
        """Source changes already logged as events."""

    def now(self) -> float:
        return self._sub.now()

    def keep_up(self) -> None:
        self._sub.poll()

    def measurements(self) -> list[PoseMeasurement]:
        for t_mono, payload, stamp in self._sub.drain_raw():
            # Log time: when the pose arrived (the flight's clock); publish time: when the mocap measured it (the
            # publisher's wall clock, the stamp inside the payload).
            bad = self._faults.pose_stamp
            self._log.raw_protobuf(self._topic, PoseInFrame, payload, self._to_log(t_mono),
                                   publish_time=stamp if bad is None else bad)
        now = time.monotonic()
        if self._sub.handovers > self._handovers:
            self._handovers = self._sub.handovers
            self._log.event("warning", f"mocap source changed: {self._sub.last_handover}", self._to_log(now))
        last, accepted = self._stats_at
        if now - last >= MOCAP_STATS_S:
            sub = self._sub
            rate = (sub.accepted - accepted) / (now - last) if np.isfinite(last) else float("nan")
            self._log.record("/mocap/stats", {"received": sub.received, "accepted": sub.accepted,
                                              "rejected": sub.rejected, "malformed": sub.malformed,
                                              "missed": sub.missed, "foreign": sub.foreign,
                                              "unauthenticated": sub.unauthenticated, "bad_stamps": sub.bad_stamps,
                                              "unechoed": sub.unechoed, "conflicts": sub.conflicts,
                                              "resyncs": sub.resyncs, "duplicates": sub.duplicates,
                                              "handovers": sub.handovers,
                                              "rate_hz": rate},
                             self._to_log(now))
            self._stats_at = (now, sub.accepted)
        out = self._sub.measurements()
        if self._faults.corrupt_pose:
            return [PoseMeasurement(m.t, np.full(3, np.nan), m.rotation) for m in out]
        return out

    def fault(self) -> str:
        return self._sub.fault()

    def untrusted_since(self) -> float | None:
        return self._sub.untrusted_since()

    def integrity(self) -> MocapIntegrity:
        sub = self._sub
        return MocapIntegrity(sub.rejected, sub.malformed, sub.foreign, sub.last_rejection, sub.missed)


def code_version() -> str:
    try:
        # A session of its own: the terminal's Ctrl-Z would stop git (the flight's own handler lands instead) and
        # hold the preflight for the whole timeout.
        rev = subprocess.run(["git", "describe", "--always", "--dirty"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent, start_new_session=True,
                             stdin=subprocess.DEVNULL).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        rev = ""
    return f"{__version__}" + (f" ({rev})" if rev else "")


def _firmware_param_issues(cfg: FlightConfig, base: Path, src: str, cache_dir: Path) -> list[str]:
    """Preflight: every module's firmware parameters as ``backend.firmware_params`` requires (none set, or a kind
    without module firmware: no check)."""
    if backend_kind(cfg.backend.kind).check_params is None or cfg.backend.firmware_params is None:
        return []
    try:
        wanted = required_params(cfg.backend, base)
    except ConfigError as exc:
        raise ConfigError(str(exc), path=src, key="backend.firmware_params") from None
    checks = check_modules(cfg.backend, wanted, cache_dir=cache_dir)
    fixable = [c for c in checks if not c.unreachable]  # --apply cannot fix a module it cannot reach
    return ([f"firmware parameter: {b} (fix with: groundstation params {src} --apply)" for b in param_issues(fixable)]
            + [f"firmware parameter: {b}" for b in param_issues([c for c in checks if c.unreachable])])


@dataclass(frozen=True)
class _Prepared:
    """Everything a flight needs that comes from its input, checked before anything is opened."""

    cfg: FlightConfig
    base: Path
    """Directory the config's relative paths start from."""
    src: str
    """The config path as given (named in errors)."""
    assembly: Assembly
    kind: BackendKind
    track: Hover | Circle | Figure8
    plan: FlightPlan
    """From the resting height; preflight re-anchors it where mocap sees the assembly."""
    volume: FlightVolume
    key: str
    """Zenoh key of the body's pose."""
    security: Security | None
    log_file: Path
    log_id: tuple[int, int]
    """The claimed log file's (device, inode): at the end the path must still lead to it."""
    mac_key: MocapKey | None = None
    """The mocap key (``mocap.key_file``): the subscriber uses no sample without its MAC."""


def prepare(config_path: str | Path, duration: float | None = None, log_path: str | Path | None = None) -> _Prepared:
    """Stage 1: load and check the input (config, assembly, trajectory against the assembly and the geofence,
    what the backend kind needs); only then make the log file, so bad input leaves nothing behind."""
    cfg, base = load_flight_config(config_path)
    src = str(config_path)
    if duration is not None:
        try:
            track = config.validate(TrajectorySection, {**asdict(cfg.trajectory), "duration": duration})
        except ConfigError as exc:
            raise ConfigError(str(exc).split(": ", 1)[-1], path=src, key="--duration") from None
        cfg = dataclasses.replace(cfg, trajectory=track)
    try:
        assembly, _ = load_assembly(base / cfg.assembly)
    except ConfigError as exc:
        raise ConfigError(f"{exc}", path=src, key="assembly") from None
    if cfg.backend.modules and len(cfg.backend.modules) != assembly.n:
        raise ConfigError(f"{len(cfg.backend.modules)} module links for an assembly of {assembly.n} modules",
                          path=src, key="backend.modules")
    kind = backend_kind(cfg.backend.kind)
    if kind.links is not None and not cfg.backend.modules:
        raise ConfigError(f"the {kind.name} backend needs one link per module", path=src, key="backend.modules")
    t = cfg.trajectory
    track = make_track(t.kind, t.duration, t.height, t.size, t.period, t.roll_deg)
    plan = FlightPlan((0.0, 0.0, assembly.resting_height), track, takeoff_s=t.takeoff_s, settle_s=t.settle_s,
                      landing_s=t.landing_s)
    model = ControlModel.from_assembly(assembly)
    f = cfg.failsafe
    volume = FlightVolume(tuple(np.array(f.geofence_lower) + 0.2), tuple(np.array(f.geofence_upper) - 0.2))
    hover_check(model, plan)
    try:
        volume_check(plan, volume)
        dynamics_check(model, plan, cfg.mocap.max_speed, cfg.gains.max_tilt_deg)
    except PreflightError as exc:  # bad input: the trajectory section asks for what cannot be flown
        given = f" with --duration {duration:g}" if duration is not None else ""  # named: the file did not ask it
        raise ConfigError(f"{exc}{given}", path=src, key="trajectory") from None
    key = pose_key(cfg.mocap.key_prefix, cfg.mocap.body)
    security = mocap_security(cfg.mocap, base, src)
    for issue_key, issue in load(kind.config_issues)(cfg, assembly) if kind.config_issues else ():
        raise ConfigError(issue, path=src, key=issue_key)
    mac_key = mocap_mac_key(cfg.mocap, base, src)
    log_file, log_id = _claim_log(log_path, base, cfg, src)
    return _Prepared(cfg, base, src, assembly, kind, track, plan, volume, key, security, log_file, log_id, mac_key)


AUTO_NAMES = 1000
"""Most logs one log directory takes in one second (``flight-<date>-<time>[-k].mcap``)."""


def _claim_log(log_path: str | Path | None, base: Path, cfg: FlightConfig, src: str) -> tuple[Path, tuple[int, int]]:
    """Claim the flight's log file: created empty and exclusively, so a log is never overwritten and of two flights
    given one ``--log`` only one gets it. ``--log`` naming a file that exists is refused; in the config's
    ``log_dir`` (not looked at with ``--log``) a name taken (two flights in one second) gets the next free ``-k``."""
    if log_path:
        path = Path(log_path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            identity = claim(path)
        except FileExistsError:
            raise UsageError(f"--log {path}: the file exists; a flight log is never overwritten") from None
        except OSError as exc:
            raise ConfigError(f"the log file cannot be written: {exc}", path=src, key="--log") from None
        return path, identity
    stamp = time.strftime("flight-%Y%m%d-%H%M%S")
    log_dir = log_directory(cfg, base, src)
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
        for k in range(AUTO_NAMES):
            path = log_dir / (f"{stamp}-{k}.mcap" if k else f"{stamp}.mcap")
            with contextlib.suppress(FileExistsError):
                return path, claim(path)
    except OSError as exc:
        raise ConfigError(f"log directory cannot be written: {exc}", path=src, key="log_dir") from None
    raise ConfigError(f"{AUTO_NAMES} logs named {stamp}* exist already", path=src, key="log_dir")


def fly(config_path: str | Path, *, duration: float | None = None, log_path: str | Path | None = None,
        requests: Requests | None = None, faults: Faults | None = None,
        on_period: Callable[[float], None] | None = None, on_status=None, handle_signals: bool = False,
        activity: LoopActivity | None = None, live_port: int | None = None) -> FlyResult:
    """Fly the config at ``config_path``; see the module docstring. ``activity`` lets a caller's own background
    thread (e.g. a status display) work between control periods, like the log writer does. ``live_port``: serve
    the log's channels over the Foxglove WebSocket protocol on 127.0.0.1 while flying (from the writer process).
    ``handle_signals``: SIGINT, SIGTERM, SIGTSTP and SIGHUP land (or, before arming, end the flight unarmed), from the
    start. How far a flight may degrade and still be nominal (:attr:`FlyResult.degraded`): the config's
    ``[quality]``.

    Stages: :func:`prepare` (input), open (the world of the backend kind, Zenoh, the log), :func:`_preflight`,
    :func:`_run`, and the end; the ``with`` block closes everything in reverse order, motors first. The end (phase,
    reason, figures) is logged on every way out once the log is open: a landing, an emergency, a refused
    preflight, the operator before arming, a crash of the loop (re-raised after)."""
    requests = requests or Requests()
    waits = _Waits()
    restore = _install_signals(requests, waits) if handle_signals else None
    try:
        return _fly(config_path, duration, log_path, requests, faults or Faults(), on_period, on_status,
                    activity or LoopActivity(), live_port, waits)
    finally:
        if restore is not None:
            restore()


class _Stopped(Exception):
    """The operator ended the flight before it armed (the reason is the message)."""


class _Waits:
    """Where the operator's second signal before arming interrupts what the flight waits for (``KeyboardInterrupt``):
    only in waits that look at no request, the world's links opening (before the log) and the modules' own checks.
    Everywhere else the signal sets the stop, which the preflight's next check sees. Raised anywhere, it could land
    while the log opened or between the preflight's end and its handler, and the command said "interrupted" (exit
    130, no summary) or not by the signal's timing (a Ctrl-C storm in CI)."""

    def __init__(self) -> None:
        self.open = True
        """A signal may raise now; from the start until the log opens, and in :meth:`interruptible` blocks."""

    @contextlib.contextmanager
    def interruptible(self):
        self.open = True
        try:
            yield
        finally:
            self.open = False

    def take(self) -> bool:
        """Whether the signal arriving now raises (once: the next one, in the same wait, only stops)."""
        was, self.open = self.open, False
        return was


def _fly(config_path, duration, log_path, requests: Requests, faults: Faults, on_period, on_status,
         activity: LoopActivity, live_port: int | None, waits: _Waits) -> FlyResult:
    p = prepare(config_path, duration, log_path)
    bounds = QualityBounds(**asdict(p.cfg.quality))
    ended_cleanly = [False]
    offset = time.time() - time.monotonic()

    def to_log(mono: float) -> float:
        """Log time (s since the epoch) of a monotonic time: every record of the flight uses this one clock."""
        return mono + offset

    log: FlightLog | None = None
    try:
        with ExitStack() as stack:
            m = p.cfg.mocap
            ours, theirs = ([m.endpoint], []) if m.listen else ([], [m.endpoint])
            for endpoint in ours:  # before a simulated world connects to it: its session took 10 s to close
                check_listenable(endpoint)
            # Before the flight's own links open (a cflib connection and the raw link cannot share a module).
            firmware_issues = _firmware_param_issues(p.cfg, p.base, p.src, p.log_file.parent)
            world = stack.enter_context(load(p.kind.world)(p.assembly, p.cfg, p.key, theirs, faults, activity,
                                                           p.security, p.mac_key))
            gs_session = open_session(listen=ours, connect=theirs, security=p.security)
            stack.callback(gs_session.close)
            stamps = StampClockSettings(max_rise_s=m.clock_drift_s)
            sub = PoseSubscriber(gs_session, p.key,
                                 SubscriberSettings(max_speed=m.max_speed, latency=m.latency_s, stamps=stamps),
                                 mac_key=p.mac_key)
            stack.callback(sub.close)
            waits.open = False  # from here on a log is written, and the end must be in it
            log = FlightLog(p.log_file, {"config": json.dumps(asdict(p.cfg)), "config_path": p.src,
                                         "code_version": code_version(),
                                         "assembly": json.dumps(assembly_record(p.assembly))}, activity=activity,
                            live_port=live_port)
            stack.callback(log.close)
            # Registered last, so it runs first on the way out, before the log and Zenoh close: a flight that
            # landed is disarmed already; armed modules on any other way out (an exception, Ctrl-C) get the
            # emergency stop. Modules never armed (a refused preflight or arming) are not stopped: the stop latches
            # until a reboot.
            stack.callback(lambda: None if ended_cleanly[0] or not world.backend.armed
                           else world.backend.emergency_stop())
            pose = _LoggedPose(sub, log, f"/mocap/{m.body}", faults, to_log)
            flight: Flight | None = None
            why_not = ""
            """Why the flight never ran (preflight refused, the operator, an error), for the end."""
            wall0 = None
            try:
                estimator = RigidBodyFilter(estimator_settings(p.cfg), p.assembly.mass)
                plan = _preflight(p, world, sub, pose, estimator, log, firmware_issues, to_log, requests, waits)
                flight = Flight(p.assembly, plan, world.backend, pose, gains=Gains(**asdict(p.cfg.gains)),
                                allocation=p.cfg.allocation, policy=FailsafePolicy(**asdict(p.cfg.failsafe)),
                                log=log, requests=requests, before_period=world.before_period(on_period),
                                to_log_time=to_log, truth=world.truth, on_status=on_status, activity=activity,
                                estimator=estimator)
                wall0 = time.perf_counter()
                _run(flight, p.cfg, log, to_log)
            except _Stopped as exc:
                why_not = str(exc)
            except BaseException as exc:
                if isinstance(exc, KeyboardInterrupt) and requests.stop.is_set() and flight is None:
                    # The operator's second signal interrupted the modules' checks (_Waits): the same end as one
                    # the preflight saw (_Stopped).
                    why_not = requests.abort_reason("in preflight")
                else:
                    why_not = str(exc) if isinstance(exc, PreflightError) else (
                        requests.abort_reason("in preflight") if isinstance(exc, KeyboardInterrupt)
                        else f"{type(exc).__name__}: {exc}")
                    _end(p, flight, why_not, _since(wall0), bounds, log, to_log)
                    raise
            ended_cleanly[0] = flight is None or flight.phase in (Phase.DONE, Phase.ABORTED)
            phase, reason, metrics, degraded = _end(p, flight, why_not, _since(wall0), bounds, log, to_log)
    except BaseException:
        if log is None:  # failed before its log opened: the claimed file, empty, goes (bad input leaves nothing)
            _release(p.log_file)
        raise
    log_error = log.error
    try:
        st = p.log_file.lstat()
        if (st.st_dev, st.st_ino) != p.log_id:  # another file in its place: that one is not this flight's log
            log_error = log_error or (f"{p.log_file} is another file now: this flight's log was removed or replaced "
                                      f"during the flight")
    except FileNotFoundError:  # the writer wrote to a file no path leads to now
        log_error = log_error or f"{p.log_file} is gone: it, or its directory, was removed or renamed during the flight"
    except OSError:  # cannot tell (a directory made unreadable, a stale NFS handle): not a verdict
        pass
    return FlyResult(p.log_file, phase, reason, metrics, flight.events if flight is not None else [], log_error,
                     getattr(log, "rejected", {}), degraded)  # (benchmarks.sdk_log's stand-in counts none)


def _end(p: _Prepared, flight: Flight | None, why_not: str, wall_s: float, bounds: QualityBounds, log: FlightLog,
         to_log: Callable[[float], float]) -> tuple[Phase, str, FlightSummary, tuple[str, ...]]:
    """The flight's end (phase, reason, figures, what degraded beyond ``bounds``), logged (``/flight/summary``)."""
    now = to_log(time.monotonic())
    if flight is None or flight.phase == Phase.PREFLIGHT:  # never ran: nothing armed
        phase, reason = Phase.ABORTED, why_not
        metrics = FlightSummary.of(FlightMetrics(p.assembly.n).result(), realtime_factor=float("nan"),
                                   planned_s=p.plan.duration, crashed=False, stalls=0)
        log.event("warning", f"{Phase.PREFLIGHT} -> {phase}: {reason}", now)
    else:
        phase, reason = flight.phase, flight.reason
        metrics = flight_summary(flight, wall_s, flight.plan.duration, flight.stats)
    landed = phase == Phase.DONE and (reason == "" or operator_landing(reason))
    degraded = degradation(metrics, bounds) if landed else ()
    if degraded:
        log.event("warning", "degraded beyond the flight's bounds: " + "; ".join(degraded), now)
    log.record("/flight/summary", {k: v for k, v in asdict(metrics).items() if k != "loop"} | {
        "phase": phase, "reason": reason, "degraded": list(degraded)}, now)
    return phase, reason, metrics, degraded


def _since(t0: float | None) -> float:
    return time.perf_counter() - t0 if t0 is not None else 0.0


def _release(path: Path) -> None:
    """Remove a claimed log file nothing was written to."""
    with contextlib.suppress(OSError):
        if path.stat().st_size == 0:
            path.unlink()


def _log_issues(log: FlightLog, requests: Requests) -> list[str]:
    """Preflight: the log's start (header and metadata) is on disk, or why not. Its writer is a process of its own
    that may still be starting: waited for up to ``WRITER_START_S``. A log directory on a full disk armed and took
    off with an empty log before (then landed on the writer's failure)."""
    deadline = time.monotonic() + WRITER_START_S
    while log.error is None and _size(log.path) == 0 and time.monotonic() < deadline:
        time.sleep(0.02)
        _stop_if_asked(requests)
    if log.error is not None:
        return [f"the log: {log.error}"]
    if _size(log.path) == 0:
        return [f"the log: nothing of {log.path} is on disk after {WRITER_START_S:g} s (a full disk?)"]
    try:
        fs = os.statvfs(log.path)
    except OSError as exc:
        return [f"the log: cannot tell the room left for {log.path}: {exc.strerror}"]
    room = fs.f_bavail * fs.f_frsize
    if room < MIN_LOG_ROOM_BYTES:
        return [f"the log: {room // 1024} KiB left on the disk of {log.path}, under {MIN_LOG_ROOM_BYTES // 1000} kB "
                f"(about a second of flight)"]
    return []


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _preflight(p: _Prepared, world, sub: PoseSubscriber, pose: _LoggedPose, est: RigidBodyFilter, log: FlightLog,
               firmware_issues: list[str], to_log: Callable[[float], float], requests: Requests,
               waits: _Waits) -> FlightPlan:
    """Stage 3: let the mocap stream start (and a simulated assembly settle), check the backend, mocap, level and
    stillness, log the scene; the plan re-anchored where mocap sees the assembly; ``est`` follows the poses from
    here on (the flight goes on with it). Raises PreflightError, or :class:`_Stopped` when the operator asks to
    land or stop meanwhile (a signal, a key)."""
    m = p.cfg.mocap
    _stop_if_asked(requests)
    # First, before the stream is watched: waited for after it, the watch's poses went stale meanwhile (a dry run's
    # world stands still while nobody settles it) and the flight took off on a pose 0.3 s old.
    log_issues = _log_issues(log, requests)
    watch_start = time.monotonic()
    deadline = watch_start + PREFLIGHT_TIMEOUT_S
    # The assembly rests: the estimator, on mocap alone (no command, no gyro yet), says where it is, how it is
    # oriented and whether it moves.
    first_seen = None  # the watch counts from the first sample: a stream that starts late is still watched in full
    while ((first_seen is None or sub.received < 10 or time.monotonic() - first_seen < m.preflight_watch_s)
           and time.monotonic() < deadline):
        if first_seen is None and sub.latest() is not None:
            first_seen = time.monotonic()
            deadline = max(deadline, first_seen + m.preflight_watch_s + 0.5)
        world.settle(time.monotonic() - watch_start)
        time.sleep(PREFLIGHT_POLL_S)
        _stop_if_asked(requests)
        est.predict(pose.now(), None)
        for sample in pose.measurements():
            est.correct(sample)
    _stop_if_asked(requests)
    with poses_kept_up(pose, PREFLIGHT_POLL_S), waits.interruptible():  # a second or more on hardware
        report = world.backend.preflight()
    est.predict(pose.now(), None)  # and what arrived meanwhile is the newest the estimate knows
    for sample in pose.measurements():
        est.correct(sample)
    s = est.state()
    issues = list(report.issues) + firmware_issues + log_issues
    _stop_if_asked(requests)
    if sub.fault():
        issues.append(f"mocap: {sub.fault()}")
    if est.fault():  # latched: the flight would take off blind on an estimate its poses disown
        issues.append(f"mocap: {est.fault()}")
    if s is None:
        unseen = f"mocap does not see '{m.body}' on {p.key} via {m.endpoint}"
        if sub.unauthenticated:  # a bridge with another key (or none): its samples arrive, and are never used
            unseen += (f": {sub.unauthenticated} samples arrived but failed authentication against mocap.key_file "
                       f"({m.key_file}): their publisher has another key, or none")
        elif sub.bad_stamps:  # they arrive, from the key's holder, and none was on time
            why = (f"the bridge hears no challenge of this ground station (access control must let it put on "
                   f"{challenge_key(p.key)} and the bridge subscribe to it)"
                   if sub.unechoed == sub.bad_stamps
                   else "held back on the way, or the bridge's clock is not this host's")
            unseen += (f": {sub.bad_stamps} samples arrived and were refused as late (last: {sub.last_rejection}): "
                       f"{why}")
        issues.append(unseen)
    else:
        if s.rotation[2, 2] < np.cos(np.radians(10)):
            issues.append("assembly is not level")
        if np.linalg.norm(s.velocity) > STILL_SPEED:
            issues.append(f"assembly is moving ({np.linalg.norm(s.velocity):.2f} m/s)")
        measured_up = world.backend.module_gravity()
        if measured_up is not None:  # link i reaches the module at place i
            names = [f"module {i} ({link})" for i, link in enumerate(p.cfg.backend.modules)]
            issues += placement_issues(measured_up, p.assembly.module_rotations, s.rotation, names)
    reference = np.array([p.plan(t_ref).position for t_ref in np.arange(0.0, p.plan.duration, 0.05)])
    f = p.cfg.failsafe
    log.scene(p.assembly, to_log(time.monotonic()), reference, (tuple(f.geofence_lower), tuple(f.geofence_upper)))
    if issues:
        log.event("error", "preflight failed: " + "; ".join(issues), to_log(time.monotonic()))
        raise PreflightError("preflight failed: " + "; ".join(issues))
    # Take off from where mocap sees the assembly (hardware is never exactly at the nominal spot).
    t = p.cfg.trajectory
    plan = FlightPlan(tuple(float(v) for v in s.position), p.track, takeoff_s=t.takeoff_s, settle_s=t.settle_s,
                      landing_s=t.landing_s)
    volume_check(plan, p.volume)
    now = to_log(time.monotonic())
    log.event("info", "preflight passed", now)
    # The counts so far are the preflight's: every period's record holds them too, and a replayed window from the
    # first period subtracts these.
    log.record("/flight/start", {"mocap": pose.integrity().logged(),
                                 "estimate": {"rejected": est.rejected, "late": est.late}}, now)
    return plan


def _stop_if_asked(requests: Requests) -> None:
    if requests.land.is_set() or requests.stop.is_set():
        raise _Stopped(requests.abort_reason("in preflight"))


def _run(flight: Flight, cfg: FlightConfig, log: FlightLog, to_log: Callable[[float], float]) -> LoopStats:
    """Stage 4: arm and fly at the config's rate (real-time priority if permitted); the loop's statistics."""
    # Background threads are Python too; by default a thread may hold the GIL for 5 ms before handing it
    # over, which shows up as overruns of a 2 ms period. Hand over every 100 us.
    switch = sys.getswitchinterval()
    sys.setswitchinterval(GIL_SWITCH_S)
    try:
        with realtime_priority(cfg.realtime_priority, (log.writer_pid,)) as rt:
            if cfg.realtime_priority and not rt:
                log.event("warning", f"real-time priority {cfg.realtime_priority} not permitted (needs "
                          "CAP_SYS_NICE or an rtprio limit): the loop runs at normal priority",
                          to_log(time.monotonic()))
            stats = flight.run(WallClock(SPIN_RT_S if rt else SPIN_S), cfg.rate_hz, realtime=rt)
    finally:
        sys.setswitchinterval(switch)
    return stats


def _install_signals(requests: Requests, waits: _Waits):
    """First SIGINT/SIGTERM/SIGTSTP/SIGHUP (or another of :data:`LANDING_SIGNALS`): land (before the loop starts: end
    the flight unarmed, at the next check). A second one (not of :data:`NEVER_A_STOP`): stop the motors; before
    the loop starts, nothing is armed, so it also interrupts a wait that looks at no request (a link that does not
    open, the modules' checks: :class:`_Waits`). The signal's name goes into the reason. Returns a function
    restoring the old handlers.

    * SIGHUP is an SSH connection or the terminal going away: the flight must not end with the process, rotors on.
      It never escalates to a stop, nor does a SIGTERM after it: one hang-up can deliver two (the kernel's to the
      foreground group and the shell's to its jobs), a session's end a SIGTERM after it (systemd-logind with
      ``KillUserProcesses``), and nobody is left at the terminal to have asked for a stop (Ctrl-C and Ctrl-Z
      still do).
    * SIGTSTP is Ctrl-Z: by default it stops the process, the modules' watchdogs cut the motors and the assembly
      falls (measured: from 1 m, 3.9 m/s at impact); here it is Ctrl-C.
    * SIGTTIN and SIGTTOU stop a background process that touches its terminal (``fly ... &`` reading its keys):
      ignored, so such a read fails (EIO) and a write goes through instead."""
    if threading.current_thread() is not threading.main_thread():
        return None

    hung_up = []  # a hang-up, whenever it came: not only one that began the landing (Ctrl-C, hang-up, SIGTERM)

    def handler(signum, frame):
        if signum == signal.SIGHUP:
            forget_lost_terminal()  # every later write to it would fail (EIO) and end the command in a traceback
            hung_up.append(True)
        if hung_up and requests.land.is_set() and signum not in (signal.SIGINT, signal.SIGTSTP, signal.SIGQUIT):
            return  # a session ending sends SIGTERM after the hang-up (systemd-logind): the landing goes on
        if requests.land.is_set() and signum in NEVER_A_STOP:
            return  # the landing goes on: repeated by a tool (log rotation, a timer), not asked by an operator
        # A landing a tool's signal or a hang-up began was not the operator's first request: their first Ctrl-C
        # only lands (a Ctrl-C after the hang-up stopped the motors 0.8 m up).
        not_asked = requests.source in TOOL_SIGNALS or requests.source == "SIGHUP"
        requests.source = signal_name(signum)
        if requests.land.is_set() and signum != signal.SIGHUP and not not_asked:
            requests.stop.set()
            if waits.take():
                raise KeyboardInterrupt
        requests.land.set()

    old = {s: signal.signal(s, handler) for s in LANDING_SIGNALS}
    old |= {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGTTIN, signal.SIGTTOU)}

    def restore():
        for s, h in old.items():
            signal.signal(s, h)

    return restore

