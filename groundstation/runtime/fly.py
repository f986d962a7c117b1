"""``fly``: load a flight config, connect, check, arm, take off, track, land, disarm; log everything to MCAP.

Backends: ``sim`` runs PyBullet inside this process and publishes its physics pose over Zenoh through a virtual
mocap, so a dry run exercises the same loop, Zenoh path and logging as a flight with real mocap; the simulator is
advanced to the wall time at the start of every period. ``crazyflie`` drives one cflib link per module (radio
or UDP) and ``mavlink`` one pymavlink connection per PX4 module; both take poses from whatever publishes them on
Zenoh: a mocap bridge, or ``groundstation sim-peer``, which simulates the modules behind their real wire protocol
in another process.

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
from groundstation.assembly.assembly_file import assembly_record, load_assembly
from groundstation.backends.crazyflie import CrazyflieBackend, CrazyflieSettings
from groundstation.backends.mavlink import MavlinkBackend, MavlinkSettings
from groundstation.backends.radio_budget import radio_budget_issues
from groundstation.control.geometric import Gains
from groundstation.control.model import ControlModel
from groundstation.control.phase import Phase
from groundstation.control.trajectory import FlightPlan, make_track
from groundstation.errors import ConfigError
from groundstation.firmware.modules import check_modules, required_params
from groundstation.firmware.params import issues as param_issues
from groundstation.flightlog.mcap_log import FlightLog
from groundstation.loop_activity import LoopActivity
from groundstation.mocap.zenoh_link import PosePublisher, PoseSubscriber, SubscriberSettings, open_session, pose_key
from groundstation.runtime.closed_loop import (
    FlightVolume,
    PreflightError,
    dynamics_check,
    flight_summary,
    hover_check,
    volume_check,
)
from groundstation.runtime.flight import FailsafePolicy, Flight, MocapIntegrity, Requests
from groundstation.runtime.flight_config import FlightConfig, TrajectorySection, load_flight_config, mocap_security
from groundstation.runtime.loop import SPIN_RT_S, SPIN_S, WallClock, realtime_priority

PREFLIGHT_TIMEOUT_S = 3.0
PREFLIGHT_WATCH_S = 1.0
"""Preflight watches the mocap stream at least this long (a second publisher on the key shows up), s."""
GIL_SWITCH_S = 1e-4
STILL_SPEED = 0.2
"""Preflight: the estimated speed must be below this (mocap noise alone gives a few cm/s), m/s."""


@dataclass
class Faults:
    """Fault injection for drills and tests: set these (e.g. from ``on_period``) during a simulated flight.

    ``mocap_paused`` and ``link_lost`` act on the in-process simulator only; with simulated Crazyflie or PX4
    modules, stop the peer process to lose the link."""

    mocap_paused: bool = False
    """The virtual mocap stops publishing."""
    corrupt_pose: bool = False
    """The pose source returns NaN."""
    link_lost: bool = False
    """The backend reports its link lost."""


@dataclass
class FlyResult:
    log_path: Path
    phase: Phase
    """Final state: ``done`` (landed, disarmed), ``emergency`` (motors stopped) or ``aborted`` (never armed)."""
    reason: str
    """Why the flight ended early ("" when it flew its plan; "operator land" when the operator cut it short)."""
    metrics: dict
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
    """Preflight: every module's firmware parameters as ``backend.firmware_params`` requires (none set: no check)."""
    if cfg.backend.firmware_params is None:
        return []
    try:
        wanted = required_params(cfg.backend, base)
    except ConfigError as exc:
        raise ConfigError(str(exc), path=src, key="backend.firmware_params") from None
    bad = param_issues(check_modules(cfg.backend, wanted, cache_dir=cache_dir))
    return [f"firmware parameter: {b} (fix with: groundstation params {src} --apply)" for b in bad]


def _check_crazyflie_config(cfg: FlightConfig, assembly, src: str) -> None:
    """What a Crazyflie flight needs of its config: the modules' thrust map, and a radio that carries the rate."""
    if assembly.params.motor_command is None:
        raise ConfigError("the assembly's module_params has no motor_command (the thrust map of the modules' "
                          "platform, see configs/modules/paper_table2.toml)", path=src, key="assembly")
    budget = radio_budget_issues(cfg.backend.modules, cfg.rate_hz, cfg.backend.radio_capacity_hz)
    if budget:
        raise ConfigError("; ".join(budget), path=src, key="backend.modules")


def _hardware_backend(cfg: FlightConfig, assembly) -> CrazyflieBackend | MavlinkBackend:
    b = cfg.backend
    if b.kind == "crazyflie":
        f = cfg.failsafe
        return CrazyflieBackend(b.modules, assembly.params, assembly.module_rotations,
                                CrazyflieSettings(link_timeout=b.link_timeout_s, min_battery_v=b.min_battery_v,
                                                  command_period=1.0 / cfg.rate_hz,
                                                  max_latency=f.max_link_latency_s, max_loss=f.max_link_loss))
    return MavlinkBackend(b.modules, assembly.params.u_max, assembly.module_rotations,
                          MavlinkSettings(link_timeout=b.link_timeout_s, min_battery_v=b.min_battery_v,
                                          pwm_min=b.pwm_min, pwm_max=b.pwm_max))


def fly(config_path: str | Path, *, duration: float | None = None, log_path: str | Path | None = None,
        requests: Requests | None = None, faults: Faults | None = None,
        on_period: Callable[[float], None] | None = None, on_status=None, handle_signals: bool = False,
        activity: LoopActivity | None = None, live_port: int | None = None) -> FlyResult:
    """Fly the config at ``config_path``; see the module docstring. ``activity`` lets a caller's own background
    thread (e.g. a status display) work between control periods, like the log writer does. ``live_port``: serve
    the log's channels over the Foxglove WebSocket protocol on 127.0.0.1 while flying (from the writer process)."""
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
    faults = faults or Faults()
    requests = requests or Requests()
    t = cfg.trajectory
    track = make_track(t.kind, t.duration, t.height, t.size, t.period, t.roll_deg)
    gains = Gains(**asdict(cfg.gains))
    policy = FailsafePolicy(**asdict(cfg.failsafe))

    from sim.pybullet_backend import resting_height

    if cfg.backend.kind != "sim" and not cfg.backend.modules:
        raise ConfigError(f"the {cfg.backend.kind} backend needs one link per module", path=src,
                          key="backend.modules")
    plan = FlightPlan((0.0, 0.0, resting_height(assembly)), track, takeoff_s=t.takeoff_s, landing_s=t.landing_s)
    model = ControlModel.from_assembly(assembly)
    volume = FlightVolume(tuple(np.array(policy.geofence_lower) + 0.2), tuple(np.array(policy.geofence_upper) - 0.2))
    hover_check(model, plan)
    try:
        volume_check(plan, volume)
        dynamics_check(model, plan, cfg.mocap.max_speed)
    except PreflightError as exc:  # bad input: the trajectory section asks for what cannot be flown
        raise ConfigError(str(exc), path=src, key="trajectory") from None

    key = pose_key(cfg.mocap.key_prefix, cfg.mocap.body)
    security = mocap_security(cfg.mocap, base, src)
    if cfg.backend.kind == "crazyflie":
        _check_crazyflie_config(cfg, assembly, src)
    # Every check of the input is done: only now is the log file made (bad input leaves nothing behind).
    stamp_name = time.strftime("flight-%Y%m%d-%H%M%S.mcap")
    log_file = Path(log_path) if log_path else (base / cfg.log_dir).resolve() / stamp_name
    try:
        log_file.parent.mkdir(parents=True, exist_ok=True)
        log_file.touch()
    except OSError as exc:
        raise ConfigError(f"log directory cannot be written: {exc}", path=src, key="log_dir") from None
    activity = activity or LoopActivity()
    ended_cleanly = [False]
    offset = time.time() - time.monotonic()

    def to_log(mono: float) -> float:
        """Log time (s since the epoch) of a monotonic time: every record of the flight uses this one clock."""
        return mono + offset

    with ExitStack() as stack:
        m = cfg.mocap
        if cfg.backend.kind == "sim":
            # The simulator plays the mocap system: it listens, the ground station connects (as with a bridge).
            ours, theirs = ([m.endpoint], []) if m.listen else ([], [m.endpoint])
            world = stack.enter_context(_SimulatedWorld(assembly, cfg, key, theirs, faults, activity, security))
            backend = world.backend
            param_issues = []
        else:
            ours = [m.endpoint] if m.listen else []
            theirs = [] if m.listen else [m.endpoint]
            world = None
            # Before the flight's own links open (a cflib connection and the raw link cannot share a module).
            backend = _hardware_backend(cfg, assembly)
            param_issues = _firmware_param_issues(cfg, base, src, log_file.parent)
            backend.connect()
            stack.callback(backend.close)
            # Runs first on the way out: a flight that landed (or never armed) is disarmed already; anything else
            # (an exception, Ctrl-C in preflight) gets the emergency stop.
            stack.callback(lambda: None if ended_cleanly[0] else backend.emergency_stop())
        gs_session = open_session(listen=ours, connect=theirs, security=security)
        stack.callback(gs_session.close)
        sub = PoseSubscriber(gs_session, key, SubscriberSettings(max_speed=m.max_speed))
        stack.callback(sub.close)

        log = FlightLog(log_file, {"config": json.dumps(asdict(cfg)), "config_path": src,
                                   "code_version": code_version(),
                                   "assembly": json.dumps(assembly_record(assembly))}, activity=activity,
                        live_port=live_port)
        stack.callback(log.close)
        pose = _LoggedPose(sub, log, f"/mocap/{m.body}", faults, to_log)

        # Preflight: let the mocap stream start (and the simulator settle on the ground).
        watch_start = time.monotonic()
        deadline = watch_start + PREFLIGHT_TIMEOUT_S
        while ((sub.latest() is None or sub.received < 10 or time.monotonic() - watch_start < PREFLIGHT_WATCH_S)
               and time.monotonic() < deadline):
            if world is not None:
                world.settle(0.02)
            time.sleep(0.005)
        s = pose.state()
        report = backend.preflight()
        issues = list(report.issues) + param_issues
        if sub.fault():
            issues.append(f"mocap: {sub.fault()}")
        if s is None:
            issues.append(f"mocap does not see '{m.body}' on {key} via {m.endpoint}")
        else:
            if s.rotation[2, 2] < np.cos(np.radians(10)):
                issues.append("assembly is not level")
            if np.linalg.norm(s.velocity) > STILL_SPEED:
                issues.append(f"assembly is moving ({np.linalg.norm(s.velocity):.2f} m/s)")
        reference = np.array([plan(t_ref).position for t_ref in np.arange(0.0, plan.duration, 0.05)])
        log.scene(assembly, to_log(time.monotonic()), reference,
                  (tuple(policy.geofence_lower), tuple(policy.geofence_upper)))
        if issues:
            log.event("error", "preflight failed: " + "; ".join(issues), to_log(time.monotonic()))
            raise PreflightError("preflight failed: " + "; ".join(issues))
        # Take off from where mocap sees the assembly (hardware is never exactly at the nominal spot).
        plan = FlightPlan(tuple(float(v) for v in s.position), track, takeoff_s=t.takeoff_s, landing_s=t.landing_s)
        volume_check(plan, volume)
        log.event("info", "preflight passed", to_log(time.monotonic()))

        before = world.before_period(on_period) if world is not None else on_period
        flight = Flight(assembly, plan, backend, pose, gains=gains, allocation=cfg.allocation, policy=policy,
                        log=log, requests=requests, before_period=before, to_log_time=to_log,
                        truth=world.backend.true_state if world is not None else None, on_status=on_status,
                        activity=activity)
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
        ended_cleanly[0] = flight.phase in (Phase.DONE, Phase.ABORTED)
        metrics = flight_summary(flight, time.perf_counter() - wall0, plan.duration, stats)
        log.record("/flight/summary", {k: v for k, v in metrics.items() if k != "loop"} | {
            "phase": flight.phase, "reason": flight.reason}, to_log(time.monotonic()))
    return FlyResult(log_file, flight.phase, flight.reason, metrics, flight.events, log.error)


class _SimulatedWorld:
    """The in-process simulator (``backend.kind = "sim"``): PyBullet physics publishing its pose over Zenoh.

    The flight advances it to the wall time at the start of every period.
    """

    def __init__(self, assembly, cfg: FlightConfig, key: str, listen: list[str], faults: Faults,
                 activity: LoopActivity, security=None) -> None:
        from sim.pybullet_backend import PyBulletBackend, SimConfig
        from sim.virtual_mocap import VirtualMocap

        m = cfg.mocap
        self.faults = faults
        self._stack = ExitStack()
        connect = [] if listen else [m.endpoint]
        session = open_session(listen=listen, connect=connect, security=security)
        self._stack.callback(session.close)
        publisher = PosePublisher(session, key)
        self._stack.callback(publisher.close)
        vmocap = VirtualMocap(publisher, m.rate_hz, m.position_noise, np.radians(m.attitude_noise_deg), m.latency_s,
                              threaded=True, activity=activity)
        self._stack.callback(vmocap.close)

        def observe(t_sim, state):
            vmocap.paused = faults.mocap_paused
            vmocap.on_step(t_sim, state)

        self.backend = PyBulletBackend(assembly, SimConfig(physics_hz=cfg.backend.physics_hz,
                                                           motor_time_constant=cfg.backend.motor_time_constant),
                                       observers=[observe])
        self.backend.connect()
        self._stack.callback(self.backend.close)
        self._stack.callback(self.backend.emergency_stop)  # runs first on the way out: motors off

    def settle(self, dt: float) -> None:
        """Advance the simulation by ``dt`` before the flight (preflight)."""
        self.backend.advance_to(self.backend.time + dt)

    def before_period(self, on_period: Callable[[float], None] | None) -> Callable[[float], None]:
        t0 = self.backend.time

        def advance(t: float) -> None:
            self.backend.link_ok = not self.faults.link_lost
            if on_period is not None:
                on_period(t)
            self.backend.advance_to(t0 + t)

        return advance

    def __enter__(self) -> _SimulatedWorld:
        return self

    def __exit__(self, *exc) -> None:
        self._stack.close()


def _install_signals(requests: Requests):
    """First SIGINT/SIGTERM: land. Second: stop the motors. Returns a function restoring the old handlers."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(signum, frame):
        if requests.land.is_set():
            requests.stop.set()
        requests.land.set()

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}

    def restore():
        for s, h in old.items():
            signal.signal(s, h)

    return restore

