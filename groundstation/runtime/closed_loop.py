"""Closed-loop flight of an assembly against a simulated backend, in lockstep (paper §VI).

Pre-flight checks (hover feasibility from the allocation, the reference inside the flight volume), then the same
:class:`~groundstation.runtime.flight.Flight` that ``fly`` runs, on the simulator's clock. The result is a
:class:`FlightRecord` for metrics and plots.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.module import GRAVITY
from groundstation.backends.base import SimulatedBackend
from groundstation.control.allocation import allocate_bounded
from groundstation.control.geometric import Gains, adapt_attitude
from groundstation.control.model import ControlModel
from groundstation.control.phase import Phase
from groundstation.control.trajectory import FlightPlan, euler_zyx
from groundstation.errors import PreflightError
from groundstation.estimation.filter import EstimatorSettings, RigidBodyFilter
from groundstation.runtime.flight import FailsafePolicy, Flight, PhysicsPoseSource
from groundstation.runtime.loop import LoopStats, SimClock
from groundstation.runtime.metrics import FlightSummary

AllocationMode = Literal["clip", "bounded"]
MOCAP_WAIT_S = 0.05
"""Simulated time the assembly rests before the flight, s: the simulated mocap's first poses (a sample interval
and its latency) reach the estimator."""


@dataclass(frozen=True)
class FlightVolume:
    """Box the reference trajectory must stay in, world frame, m."""

    lower: tuple[float, float, float] = (-3.0, -3.0, 0.0)
    upper: tuple[float, float, float] = (3.0, 3.0, 3.0)


@dataclass(frozen=True, eq=False)
class FlightRecord:
    """Time series of one flight (one row per control period)."""

    t: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    position_ref: np.ndarray
    rotation_desired: np.ndarray
    roll_target: np.ndarray
    motors: np.ndarray
    phase: np.ndarray
    wall_s: float
    crashed: bool
    crash_reason: str
    metrics: FlightSummary


def hover_problem(model: ControlModel, attitude: np.ndarray) -> str | None:
    """Why the assembly cannot produce its hover wrench within motor bounds held at ``attitude`` (the rotation
    matrix of a roll target: the controller's :func:`adapt_attitude` of it), or None if it can."""
    weight = model.mass * GRAVITY * np.array([0.0, 0.0, 1.0])
    rd = adapt_attitude(attitude, weight, model)
    wrench = np.concatenate([rd.T @ weight, np.zeros(3)])
    u = allocate_bounded(wrench, model)
    err = np.abs(model.allocation @ u - wrench)
    if err[:3].max() > 1e-3 * np.linalg.norm(weight) or err[3:].max() > 1e-3 * np.linalg.norm(weight) * 0.1:
        return (f"the assembly cannot hover: best hover wrench misses by {err.max():.3g} (max thrust "
                f"{model.allocation[2].sum() * model.u_max:.2f} N, weight {np.linalg.norm(weight):.2f} N)")
    return None


def hover_check(model: ControlModel, plan: FlightPlan) -> None:
    """Raise :class:`PreflightError` unless the assembly can produce its hover wrench within motor bounds (held at
    the plan's roll target: one it cannot hover at is named, with those it can)."""
    att = plan.track.attitude
    if att.pitch == 0.0 and att.yaw == 0.0:
        issue = roll_hover_issue(model, float(np.degrees(att.roll)))
        if issue is not None:
            raise PreflightError(issue[1] if issue[0] == "assembly" else f"roll target {issue[1]}")
    elif (problem := hover_problem(model, att.matrix)) is not None:
        raise PreflightError(problem)


def roll_hover_issue(model: ControlModel, roll_deg: float) -> tuple[str, str] | None:
    """``(key, problem)`` if the assembly cannot hover held at the roll target ``roll_deg`` (deg), else None: the
    key is ``trajectory.roll_deg`` and the problem names the roll targets it hovers at if it hovers level, else
    ``assembly``."""
    problem = hover_problem(model, euler_zyx(np.radians(roll_deg), 0.0, 0.0))
    if problem is None:
        return None
    if roll_deg == 0.0 or hover_problem(model, np.eye(3)) is not None:
        return "assembly", problem
    lo, hi = (np.floor(hover_roll_limit(model, sign) * 10.0) / 10.0 for sign in (-1.0, 1.0))
    return ("trajectory.roll_deg", f"{roll_deg:g} deg: the assembly cannot hover held at it "
                                   f"({problem.removeprefix('the assembly cannot hover: ')}); it hovers at roll "
                                   f"targets from {-lo:.1f} to {hi:.1f} deg")


def hover_roll_limit(model: ControlModel, sign: float, tolerance_deg: float = 0.1) -> float:
    """The largest roll target, deg, of sign ``sign``, at which the assembly hovers (0 if it does not level):
    bisection, from level, to within ``tolerance_deg`` (the toy V: +-9.3 deg)."""
    def hovers(deg: float) -> bool:
        return hover_problem(model, euler_zyx(np.radians(sign * deg), 0.0, 0.0)) is None

    if not hovers(0.0):
        return 0.0
    lo, hi = 0.0, 90.0
    if hovers(hi):
        return hi
    while hi - lo > tolerance_deg:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if hovers(mid) else (lo, mid)
    return lo


THRUST_SHARE = 0.8
"""Of the assembly's collective thrust, the share the reference may ask for (the rest stays for attitude)."""
TILT_SHARE = 0.75
"""Of the controller's lean limit (``gains.max_tilt_deg``), the share the reference's accelerations may ask of an
assembly that tilts to accelerate sideways; the rest is for the feedback (a figure-8 asking 29 deg of a 30 deg
limit left its reference 0.5 m behind)."""
SPEED_SHARE = 0.8
"""Of the mocap's outlier speed (``mocap.max_speed``), the share the reference may fly at: faster genuine poses
would be rejected as jumps."""


def volume_check(plan: FlightPlan, volume: FlightVolume) -> None:
    """The whole plan stays in ``volume``: from its analytic bounds (no sampling, so any duration is cheap)."""
    b = plan.bounds()
    lo, hi = np.array(volume.lower), np.array(volume.upper)
    outside = (np.array(b.lower) < lo - 1e-9) | (np.array(b.upper) > hi + 1e-9)
    if outside.any():
        axes = ", ".join("xyz"[k] for k in np.flatnonzero(outside))
        raise PreflightError(f"the trajectory leaves the flight volume along {axes}: it spans "
                             f"{np.round(b.lower, 3).tolist()}..{np.round(b.upper, 3).tolist()}, the volume is "
                             f"{np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()} (the geofence less 0.2 m)")


def dynamics_check(model: ControlModel, plan: FlightPlan, max_speed: float, max_tilt_deg: float) -> None:
    """The plan's speed and acceleration, from its analytic bounds, within what the mocap gate and the assembly
    allow: speed below ``SPEED_SHARE`` of ``max_speed``; collective thrust for gravity plus the largest
    acceleration below ``THRUST_SHARE`` of the assembly's; the tilt the track's acceleration asks below
    ``TILT_SHARE`` of the controller's ``max_tilt_deg``."""
    b = plan.bounds()
    issues = []
    if b.speed > SPEED_SHARE * max_speed:
        issues.append(f"it needs {b.speed:.3g} m/s, above {SPEED_SHARE:g} x mocap.max_speed = "
                      f"{SPEED_SHARE * max_speed:g} m/s (faster poses are rejected as jumps)")
    thrust = float(model.allocation[:3].sum(axis=1) @ np.array([0.0, 0.0, 1.0])) * model.u_max
    need = model.mass * (GRAVITY + b.accel)
    if need > THRUST_SHARE * thrust:
        issues.append(f"it accelerates up to {b.accel:.3g} m/s^2: {need:.3g} N of thrust, above "
                      f"{THRUST_SHARE:g} x the assembly's {thrust:.3g} N")
    # The take-off's and landing's vertical ramps ask for thrust, not tilt; the track's time warp asks for both (its
    # v * s'' left out, an 8 s figure-8 cut to 0.4 s passed and flew to a 47 deg attitude error).
    sideways = plan.tracked_bounds().accel
    tilt = np.degrees(np.arctan2(sideways, GRAVITY))
    if tilt > TILT_SHARE * max_tilt_deg:
        issues.append(f"its {sideways:.3g} m/s^2 asks for {tilt:.0f} deg of tilt, above {TILT_SHARE:g} x "
                      f"gains.max_tilt_deg = {TILT_SHARE * max_tilt_deg:g} deg")
    if issues:
        raise PreflightError("the trajectory is beyond the assembly: " + "; ".join(issues))


def fly_simulated(assembly: Assembly, plan: FlightPlan, backend: SimulatedBackend, gains: Gains | None = None,
                  control_hz: float = 250.0, allocation: AllocationMode = "clip",
                  volume: FlightVolume | None = None, policy: FailsafePolicy | None = None,
                  log=None, estimator: EstimatorSettings | None = None, on_status=None) -> FlightRecord:
    """Fly ``plan`` in lockstep on a connected simulated ``backend``: the flight loop of ``fly`` with the
    simulator's clock, its mocap samples as the pose source, and the same estimator (``estimator``: its settings,
    matching the simulated mocap's); ``on_status`` is given each period's
    :class:`~groundstation.runtime.flight.Status`."""
    model = ControlModel.from_assembly(assembly)
    hover_check(model, plan)
    volume_check(plan, volume or FlightVolume())
    dynamics_check(model, plan, max_speed=np.inf, max_tilt_deg=(gains or Gains()).max_tilt_deg)
    report = backend.preflight()
    if not report.ok:
        raise PreflightError("backend preflight failed: " + "; ".join(report.issues))
    flight = Flight(assembly, plan, backend, PhysicsPoseSource(backend), gains=gains, allocation=allocation,
                    policy=policy, log=log, truth=backend.true_state, record=True, on_status=on_status,
                    estimator=RigidBodyFilter(estimator or EstimatorSettings(), model.mass))
    backend.advance_to(backend.time + MOCAP_WAIT_S)  # as fly's preflight, the first poses before anything spins
    wall0 = time.perf_counter()
    stats = flight.run(SimClock(backend), control_hz)
    return record_of(flight, time.perf_counter() - wall0, plan.duration, stats)


def flight_summary(flight: Flight, wall_s: float, planned_s: float, stats: LoopStats | None = None) -> FlightSummary:
    """The flight's figures with its wall time, plan and end, and the loop's timing."""
    figures = flight.metrics.result()
    return FlightSummary.of(figures, realtime_factor=figures.simulated_s / wall_s if wall_s > 0 else float("inf"),
                            planned_s=planned_s, crashed=flight.phase == Phase.EMERGENCY, stalls=flight.stalls,
                            loop=stats.summary() if stats is not None else None)


def record_of(flight: Flight, wall_s: float, planned_s: float, stats: LoopStats | None = None) -> FlightRecord:
    """Arrays of a finished flight flown with ``record=True``, with its metrics."""
    r = flight.recording
    n_rot = 4 * flight.assembly.n
    return FlightRecord(np.array(r.t), np.array(r.position).reshape(-1, 3), np.array(r.rotation).reshape(-1, 3, 3),
                        np.array(r.position_ref).reshape(-1, 3), np.array(r.rotation_desired).reshape(-1, 3, 3),
                        np.array(r.roll_target), np.array(r.motors).reshape(-1, n_rot), np.array(r.phase), wall_s,
                        flight.phase == Phase.EMERGENCY, flight.reason if flight.phase == Phase.EMERGENCY else "",
                        flight_summary(flight, wall_s, planned_s, stats))
