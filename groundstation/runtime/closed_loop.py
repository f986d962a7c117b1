"""Closed-loop flight of an assembly against a simulated backend, in lockstep (paper §VI).

Pre-flight checks (hover feasibility from the allocation, the reference inside the flight volume), then the same
:class:`~groundstation.runtime.flight.Flight` that ``fly`` runs, on the simulator's clock. The result is a
:class:`FlightRecord` for metrics and plots.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from groundstation.assembly.assembly import Assembly
from groundstation.control.allocation import allocate_bounded
from groundstation.control.geometric import Gains, adapt_attitude
from groundstation.control.model import ControlModel
from groundstation.control.trajectory import FlightPlan
from groundstation.design.task import GRAVITY
from groundstation.errors import GroundstationError
from groundstation.runtime.flight import FailsafePolicy, Flight, PhysicsPoseSource
from groundstation.runtime.loop import LoopStats, SimClock

AllocationMode = Literal["clip", "bounded"]


class PreflightError(GroundstationError):
    """The flight must not start (the assembly cannot hover, the plan leaves the flight volume, ...)."""


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
    crash_reason: str = ""
    metrics: dict = field(default_factory=dict)


def hover_check(model: ControlModel, plan: FlightPlan) -> None:
    """Raise :class:`PreflightError` unless the assembly can produce its hover wrench within motor bounds."""
    weight = model.mass * GRAVITY * np.array([0.0, 0.0, 1.0])
    rd = adapt_attitude(plan.track.attitude.matrix, weight, model)
    wrench = np.concatenate([rd.T @ weight, np.zeros(3)])
    u = allocate_bounded(wrench, model)
    err = np.abs(model.allocation @ u - wrench)
    if err[:3].max() > 1e-3 * np.linalg.norm(weight) or err[3:].max() > 1e-3 * np.linalg.norm(weight) * 0.1:
        raise PreflightError(f"the assembly cannot hover: best hover wrench misses by {err.max():.3g} "
                             f"(max thrust {model.allocation[2].sum() * model.u_max:.2f} N, weight "
                             f"{np.linalg.norm(weight):.2f} N)")


def volume_check(plan: FlightPlan, volume: FlightVolume) -> None:
    ts = np.arange(0.0, plan.duration, 0.01)
    pts = np.array([plan(t).position for t in ts])
    lo, hi = np.array(volume.lower), np.array(volume.upper)
    bad = np.any((pts < lo - 1e-9) | (pts > hi + 1e-9), axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise PreflightError(f"the trajectory leaves the flight volume at t = {ts[k]:.2f} s: "
                             f"{np.round(pts[k], 3).tolist()} outside {list(volume.lower)}..{list(volume.upper)}")


def fly_simulated(assembly: Assembly, plan: FlightPlan, backend, gains: Gains | None = None,
                  control_hz: float = 250.0, allocation: AllocationMode = "clip",
                  volume: FlightVolume | None = None, policy: FailsafePolicy | None = None,
                  log=None) -> FlightRecord:
    """Fly ``plan`` in lockstep on a connected simulated ``backend``: the flight loop of ``fly`` with the
    simulator's clock and its physics state as the pose source."""
    model = ControlModel.from_assembly(assembly)
    hover_check(model, plan)
    volume_check(plan, volume or FlightVolume())
    report = backend.preflight()
    if not report.ok:
        raise PreflightError("backend preflight failed: " + "; ".join(report.issues))
    flight = Flight(assembly, plan, backend, PhysicsPoseSource(backend), gains=gains, allocation=allocation,
                    policy=policy, log=log, truth=backend.true_state, record=True)
    wall0 = time.perf_counter()
    stats = flight.run(SimClock(backend), control_hz)
    return record_of(flight, time.perf_counter() - wall0, plan.duration, stats)


def flight_summary(flight: Flight, wall_s: float, planned_s: float, stats: LoopStats | None = None) -> dict:
    """The flight's figures (:class:`~groundstation.runtime.metrics.FlightMetrics`) with its wall time, plan and
    end, and the loop's timing."""
    metrics = flight.metrics.result()
    sim_s = metrics["simulated_s"]
    metrics |= {"realtime_factor": sim_s / wall_s if wall_s > 0 else float("inf"), "planned_s": planned_s,
                "crashed": flight.phase == "emergency"}
    if stats is not None:
        metrics["loop"] = stats.summary()
    return metrics


def record_of(flight: Flight, wall_s: float, planned_s: float, stats: LoopStats | None = None) -> FlightRecord:
    """Arrays of a finished flight flown with ``record=True``, with its metrics."""
    r = flight.recording
    n_rot = 4 * flight.assembly.n
    return FlightRecord(np.array(r.t), np.array(r.position).reshape(-1, 3), np.array(r.rotation).reshape(-1, 3, 3),
                        np.array(r.position_ref).reshape(-1, 3), np.array(r.rotation_desired).reshape(-1, 3, 3),
                        np.array(r.roll_target), np.array(r.motors).reshape(-1, n_rot), np.array(r.phase), wall_s,
                        flight.phase == "emergency", flight.reason if flight.phase == "emergency" else "",
                        flight_summary(flight, wall_s, planned_s, stats))
