"""Closed-loop flight of an assembly against a simulated backend, in lockstep (paper §VI).

Each control period: read the measured state, sample the flight plan, run the geometric controller and the
allocation, send the rotor inputs, advance physics to the next period. Everything that happened is recorded in a
:class:`FlightRecord` for metrics and plots.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from groundstation.assembly.assembly import Assembly
from groundstation.control.allocation import allocate, allocate_bounded
from groundstation.control.geometric import Gains, adapt_attitude, control
from groundstation.control.model import ControlModel
from groundstation.control.trajectory import FlightPlan, roll_pitch_yaw
from groundstation.design.task import GRAVITY
from groundstation.errors import GroundstationError

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
                  volume: FlightVolume | None = None) -> FlightRecord:
    """Fly ``plan`` on a connected simulated ``backend`` (with ``advance_to`` and ``measured_state``)."""
    gains = gains or Gains()
    model = ControlModel.from_assembly(assembly)
    hover_check(model, plan)
    volume_check(plan, volume or FlightVolume())
    report = backend.preflight()
    if not report.ok:
        raise PreflightError("backend preflight failed: " + "; ".join(report.issues))
    alloc = allocate if allocation == "clip" else allocate_bounded
    dt = 1.0 / control_hz
    steps = int(np.ceil(plan.duration / dt))
    n_rot = 4 * assembly.n
    rec = {k: [] for k in ("t", "p", "r", "pref", "rd", "roll", "u", "phase")}
    crashed, reason = False, ""
    backend.arm()
    wall0 = time.perf_counter()
    for k in range(steps):
        t = k * dt
        state = backend.measured_state()
        sp = plan(t)
        out = control(state, sp, model, gains)
        u = alloc(out.wrench, model)
        if not np.all(np.isfinite(u)):
            backend.emergency_stop()
            crashed, reason = True, f"non-finite command at t = {t:.3f} s"
            break
        backend.send(u)
        truth = backend.true_state()
        phase = plan.phase_at(t)
        rec["t"].append(t)
        rec["p"].append(truth.position)
        rec["r"].append(truth.rotation)
        rec["pref"].append(sp.position)
        rec["rd"].append(out.rotation_desired)
        rec["roll"].append(roll_pitch_yaw(sp.rotation)[0])
        rec["u"].append(u)
        rec["phase"].append(phase)
        if np.linalg.norm(truth.position - sp.position) > 1.0 or truth.rotation[2, 2] < np.cos(np.radians(80)):
            backend.emergency_stop()
            crashed, reason = True, f"lost control at t = {t:.2f} s ({phase})"
            break
        backend.advance_to(t + dt)
    wall = time.perf_counter() - wall0
    backend.emergency_stop()
    arr = {k: np.array(v) if v else np.zeros((0,)) for k, v in rec.items()}
    record = FlightRecord(arr["t"], arr["p"].reshape(-1, 3), arr["r"].reshape(-1, 3, 3), arr["pref"].reshape(-1, 3),
                          arr["rd"].reshape(-1, 3, 3), arr["roll"], arr["u"].reshape(-1, n_rot), arr["phase"], wall,
                          crashed, reason)
    object.__setattr__(record, "metrics", flight_metrics(record, plan.duration, assembly.params.u_max))
    return record


def rotation_angle(ra: np.ndarray, rb: np.ndarray) -> np.ndarray:
    """Angle between rotations (batched), rad."""
    tr = np.einsum("...ij,...ij->...", ra, rb)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def flight_metrics(rec: FlightRecord, planned_s: float, u_max: float) -> dict:
    """Tracking figures: position over the tracking phase, attitude from the end of take-off on."""
    track = rec.phase == "track"
    airborne = np.isin(rec.phase, ("settle", "track", "hold"))
    e = np.linalg.norm(rec.position - rec.position_ref, axis=1)
    ang = np.degrees(rotation_angle(rec.rotation, rec.rotation_desired))
    roll = np.degrees(np.arctan2(rec.rotation[:, 2, 1], rec.rotation[:, 2, 2])) if len(rec.t) else np.zeros(0)
    roll_err = roll - np.degrees(rec.roll_target)
    sim_s = float(rec.t[-1] + (rec.t[1] - rec.t[0])) if len(rec.t) > 1 else 0.0
    return {
        "pos_rmse_m": float(np.sqrt(np.mean(e[track] ** 2))) if track.any() else float("nan"),
        "max_pos_error_m": float(e[track].max()) if track.any() else float("nan"),
        "max_orientation_error_deg": float(ang[airborne].max()) if airborne.any() else float("nan"),
        "max_roll_error_deg": float(np.abs(roll_err[airborne]).max()) if airborne.any() else float("nan"),
        "max_motor_fraction": float(rec.motors.max() / u_max) if rec.motors.size else 0.0,
        "realtime_factor": sim_s / rec.wall_s if rec.wall_s > 0 else float("inf"),
        "simulated_s": sim_s,
        "planned_s": planned_s,
        "crashed": rec.crashed,
    }
