"""``fly``: load a flight config, connect, check, arm, take off, track, land, disarm; log everything to MCAP.

The backend kind (:mod:`groundstation.backend_kinds`) names the world the flight flies in: ``sim`` runs PyBullet
inside this process and publishes its physics pose over Zenoh through a virtual mocap (``sim.world``), so a dry
run exercises the same loop, Zenoh path and logging as a flight with real mocap; the simulator is advanced to the
wall time at the start of every period. ``crazyflie`` drives one cflib link per module (radio or UDP) and
``mavlink`` one pymavlink connection per PX4 module (:mod:`groundstation.runtime.hardware`); both take poses from
whatever publishes them on Zenoh: a mocap bridge, or ``groundstation sim-peer``, which simulates the modules behind
their real wire protocol in another process. A hardware flight never imports the simulator.

Operator: the first Ctrl-C (or SIGTERM) lands, a second one stops the motors at once. Every exit path ends with
the motors off and the MCAP file finalized: a normal landing disarms the modules (they can fly again at once),
every other path sends the emergency stop.
"""

from __future__ import annotations

import dataclasses
import json
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
from groundstation.errors import ConfigError, PreflightError
from groundstation.firmware.modules import check_modules, required_params
from groundstation.firmware.params import issues as param_issues
from groundstation.flightlog.mcap_log import FlightLog
from groundstation.loop_activity import LoopActivity
from groundstation.mocap.zenoh_link import PoseSubscriber, Security, SubscriberSettings, open_session, pose_key
from groundstation.runtime.closed_loop import (
    FlightVolume,
    dynamics_check,
    flight_summary,
    hover_check,
    volume_check,
)
from groundstation.runtime.flight import FailsafePolicy, Flight, MocapIntegrity, Requests
from groundstation.runtime.flight_config import FlightConfig, TrajectorySection, load_flight_config, mocap_security
from groundstation.runtime.loop import SPIN_RT_S, SPIN_S, LoopStats, WallClock, realtime_priority
from groundstation.runtime.metrics import FlightSummary

PREFLIGHT_TIMEOUT_S = 3.0
PREFLIGHT_WATCH_S = 1.0
"""Preflight watches the mocap stream at least this long (a second publisher on the key shows up), s."""
GIL_SWITCH_S = 1e-4
STILL_SPEED = 0.2
"""Preflight: the estimated speed must be below this (mocap noise alone gives a few cm/s), m/s."""


@dataclass
class Faults:
    """Fault injection for drills and tests: set these (e.g. from ``on_period``) during a simulated flight.

    ``mocap_paused``, ``link_lost`` and ``tied_down`` act on the in-process simulator only; with simulated
    Crazyflie or PX4 modules, stop the peer process to lose the link."""

    mocap_paused: bool = False
    """The virtual mocap stops publishing."""
    corrupt_pose: bool = False
    """The pose source returns NaN."""
    link_lost: bool = False
    """The backend reports its link lost."""
    tied_down: bool = False
    """The assembly is fixed where it is (a forgotten tie-down, a snagged cable): the rotors spin, it stays."""


@dataclass
class FlyResult:
    log_path: Path
    phase: Phase
    """Final state: ``done`` (landed, disarmed), ``emergency`` (motors stopped) or ``aborted`` (never armed)."""
    reason: str
    """Why the flight ended early ("" when it flew its plan; "operator land" when the operator cut it short)."""
    metrics: FlightSummary
    events: list = field(default_factory=list)
    log_error: str | None = None
    """Why the log writer failed (None: the log is complete)."""

    @property
    def nominal(self) -> bool:
        """Landed as planned or as the operator asked, with a complete log; a failsafe landing is not nominal."""
        return self.phase == Phase.DONE and self.reason in ("", "operator land") and self.log_error is None


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

    def state(self):
        for t_mono, payload, stamp in self._sub.drain_raw():
            # Log time: when the pose arrived (the flight's clock); publish time: when the mocap measured it (the
            # publisher's wall clock, the stamp inside the payload).
            self._log.raw_protobuf(self._topic, PoseInFrame, payload, self._to_log(t_mono), publish_time=stamp)
        now = time.monotonic()
        last, accepted = self._stats_at
        if now - last >= MOCAP_STATS_S:
            sub = self._sub
            rate = (sub.accepted - accepted) / (now - last) if np.isfinite(last) else float("nan")
            self._log.record("/mocap/stats", {"received": sub.received, "accepted": sub.accepted,
                                              "rejected": sub.rejected, "malformed": sub.malformed,
                                              "missed": sub.missed, "foreign": sub.foreign,
                                              "resyncs": sub.resyncs, "rate_hz": rate}, self._to_log(now))
            self._stats_at = (now, sub.accepted)
        s = self._sub.state()
        if s is not None and self._faults.corrupt_pose:
            return type(s)(np.full(3, np.nan), s.velocity, s.rotation, s.omega)
        return s

    def age(self) -> float:
        return self._sub.age()

    def set_body_rate(self, omega) -> None:
        self._sub.set_body_rate(omega)

    def fault(self) -> str:
        return self._sub.fault()

    def integrity(self) -> MocapIntegrity:
        sub = self._sub
        return MocapIntegrity(sub.rejected, sub.malformed, sub.foreign, sub.last_rejection)


def code_version() -> str:
    try:
        rev = subprocess.run(["git", "describe", "--always", "--dirty"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent).stdout.strip()
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
    bad = param_issues(check_modules(cfg.backend, wanted, cache_dir=cache_dir))
    return [f"firmware parameter: {b} (fix with: groundstation params {src} --apply)" for b in bad]


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
    plan = FlightPlan((0.0, 0.0, assembly.resting_height), track, takeoff_s=t.takeoff_s, landing_s=t.landing_s)
    model = ControlModel.from_assembly(assembly)
    f = cfg.failsafe
    volume = FlightVolume(tuple(np.array(f.geofence_lower) + 0.2), tuple(np.array(f.geofence_upper) - 0.2))
    hover_check(model, plan)
    try:
        volume_check(plan, volume)
        dynamics_check(model, plan, cfg.mocap.max_speed)
    except PreflightError as exc:  # bad input: the trajectory section asks for what cannot be flown
        raise ConfigError(str(exc), path=src, key="trajectory") from None
    key = pose_key(cfg.mocap.key_prefix, cfg.mocap.body)
    security = mocap_security(cfg.mocap, base, src)
    for issue_key, issue in load(kind.config_issues)(cfg, assembly) if kind.config_issues else ():
        raise ConfigError(issue, path=src, key=issue_key)
    stamp_name = time.strftime("flight-%Y%m%d-%H%M%S.mcap")
    log_file = Path(log_path) if log_path else (base / cfg.log_dir).resolve() / stamp_name
    try:
        log_file.parent.mkdir(parents=True, exist_ok=True)
        log_file.touch()
    except OSError as exc:
        raise ConfigError(f"log directory cannot be written: {exc}", path=src, key="log_dir") from None
    return _Prepared(cfg, base, src, assembly, kind, track, plan, volume, key, security, log_file)


def fly(config_path: str | Path, *, duration: float | None = None, log_path: str | Path | None = None,
        requests: Requests | None = None, faults: Faults | None = None,
        on_period: Callable[[float], None] | None = None, on_status=None, handle_signals: bool = False,
        activity: LoopActivity | None = None, live_port: int | None = None) -> FlyResult:
    """Fly the config at ``config_path``; see the module docstring. ``activity`` lets a caller's own background
    thread (e.g. a status display) work between control periods, like the log writer does. ``live_port``: serve
    the log's channels over the Foxglove WebSocket protocol on 127.0.0.1 while flying (from the writer process).

    Stages: :func:`prepare` (input), open (the world of the backend kind, Zenoh, the log), :func:`_preflight`,
    :func:`_run`, and the summary; the ``with`` block closes everything in reverse order, motors first."""
    p = prepare(config_path, duration, log_path)
    faults = faults or Faults()
    requests = requests or Requests()
    activity = activity or LoopActivity()
    ended_cleanly = [False]
    offset = time.time() - time.monotonic()

    def to_log(mono: float) -> float:
        """Log time (s since the epoch) of a monotonic time: every record of the flight uses this one clock."""
        return mono + offset

    with ExitStack() as stack:
        m = p.cfg.mocap
        ours, theirs = ([m.endpoint], []) if m.listen else ([], [m.endpoint])
        # Before the flight's own links open (a cflib connection and the raw link cannot share a module).
        firmware_issues = _firmware_param_issues(p.cfg, p.base, p.src, p.log_file.parent)
        world = stack.enter_context(load(p.kind.world)(p.assembly, p.cfg, p.key, theirs, faults, activity,
                                                       p.security))
        gs_session = open_session(listen=ours, connect=theirs, security=p.security)
        stack.callback(gs_session.close)
        sub = PoseSubscriber(gs_session, p.key, SubscriberSettings(max_speed=m.max_speed))
        stack.callback(sub.close)
        log = FlightLog(p.log_file, {"config": json.dumps(asdict(p.cfg)), "config_path": p.src,
                                     "code_version": code_version(),
                                     "assembly": json.dumps(assembly_record(p.assembly))}, activity=activity,
                        live_port=live_port)
        stack.callback(log.close)
        # Registered last, so it runs first on the way out, before the log and Zenoh close: a flight that landed
        # is disarmed already; armed modules on any other way out (an exception, Ctrl-C) get the emergency stop.
        # Modules never armed (a refused preflight or arming) are not stopped: the stop latches until a reboot.
        stack.callback(lambda: None if ended_cleanly[0] or not world.backend.armed else world.backend.emergency_stop())
        pose = _LoggedPose(sub, log, f"/mocap/{m.body}", faults, to_log)

        plan = _preflight(p, world, sub, pose, log, firmware_issues, to_log)
        flight = Flight(p.assembly, plan, world.backend, pose, gains=Gains(**asdict(p.cfg.gains)),
                        allocation=p.cfg.allocation, policy=FailsafePolicy(**asdict(p.cfg.failsafe)), log=log,
                        requests=requests, before_period=world.before_period(on_period), to_log_time=to_log,
                        truth=world.truth, on_status=on_status, activity=activity)
        stats, wall_s = _run(flight, p.cfg, log, requests, handle_signals, to_log)
        ended_cleanly[0] = flight.phase in (Phase.DONE, Phase.ABORTED)
        metrics = flight_summary(flight, wall_s, plan.duration, stats)
        log.record("/flight/summary", {k: v for k, v in asdict(metrics).items() if k != "loop"} | {
            "phase": flight.phase, "reason": flight.reason}, to_log(time.monotonic()))
    return FlyResult(p.log_file, flight.phase, flight.reason, metrics, flight.events, log.error)


def _preflight(p: _Prepared, world, sub: PoseSubscriber, pose: _LoggedPose, log: FlightLog,
               firmware_issues: list[str], to_log: Callable[[float], float]) -> FlightPlan:
    """Stage 3: let the mocap stream start (and a simulated assembly settle), check the backend, mocap, level and
    stillness, log the scene; the plan re-anchored where mocap sees the assembly. Raises PreflightError."""
    m = p.cfg.mocap
    watch_start = time.monotonic()
    deadline = watch_start + PREFLIGHT_TIMEOUT_S
    while ((sub.latest() is None or sub.received < 10 or time.monotonic() - watch_start < PREFLIGHT_WATCH_S)
           and time.monotonic() < deadline):
        world.settle(0.02)
        time.sleep(0.005)
    s = pose.state()
    issues = list(world.backend.preflight().issues) + firmware_issues
    if sub.fault():
        issues.append(f"mocap: {sub.fault()}")
    if s is None:
        issues.append(f"mocap does not see '{m.body}' on {p.key} via {m.endpoint}")
    else:
        if s.rotation[2, 2] < np.cos(np.radians(10)):
            issues.append("assembly is not level")
        if np.linalg.norm(s.velocity) > STILL_SPEED:
            issues.append(f"assembly is moving ({np.linalg.norm(s.velocity):.2f} m/s)")
    reference = np.array([p.plan(t_ref).position for t_ref in np.arange(0.0, p.plan.duration, 0.05)])
    f = p.cfg.failsafe
    log.scene(p.assembly, to_log(time.monotonic()), reference, (tuple(f.geofence_lower), tuple(f.geofence_upper)))
    if issues:
        log.event("error", "preflight failed: " + "; ".join(issues), to_log(time.monotonic()))
        raise PreflightError("preflight failed: " + "; ".join(issues))
    # Take off from where mocap sees the assembly (hardware is never exactly at the nominal spot).
    t = p.cfg.trajectory
    plan = FlightPlan(tuple(float(v) for v in s.position), p.track, takeoff_s=t.takeoff_s, landing_s=t.landing_s)
    volume_check(plan, p.volume)
    log.event("info", "preflight passed", to_log(time.monotonic()))
    return plan


def _run(flight: Flight, cfg: FlightConfig, log: FlightLog, requests: Requests, handle_signals: bool,
         to_log: Callable[[float], float]) -> tuple[LoopStats, float]:
    """Stage 4: arm and fly at the config's rate (real-time priority if permitted); the loop's statistics and the
    wall time."""
    restore = _install_signals(requests) if handle_signals else None
    # Background threads are Python too; by default a thread may hold the GIL for 5 ms before handing it
    # over, which shows up as overruns of a 2 ms period. Hand over every 100 us.
    switch = sys.getswitchinterval()
    sys.setswitchinterval(GIL_SWITCH_S)
    wall0 = time.perf_counter()
    try:
        with realtime_priority(cfg.realtime_priority) as rt:
            if cfg.realtime_priority and not rt:
                log.event("warning", f"real-time priority {cfg.realtime_priority} not permitted (needs "
                          "CAP_SYS_NICE or an rtprio limit): the loop runs at normal priority",
                          to_log(time.monotonic()))
            stats = flight.run(WallClock(SPIN_RT_S if rt else SPIN_S), cfg.rate_hz, realtime=rt)
    finally:
        sys.setswitchinterval(switch)
        if restore is not None:
            restore()
    return stats, time.perf_counter() - wall0


def _install_signals(requests: Requests):
    """First SIGINT/SIGTERM/SIGHUP: land. Second: stop the motors. Returns a function restoring the old handlers.
    SIGHUP is an SSH connection or the terminal going away: the flight must not end with the process, rotors on."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(signum, frame):
        if requests.land.is_set():
            requests.stop.set()
        requests.land.set()

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}

    def restore():
        for s, h in old.items():
            signal.signal(s, h)

    return restore

