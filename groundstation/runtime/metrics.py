"""Running figures of a flight: the same code computes them in flight and when a log is replayed.

Memory stays bounded whatever the flight's length (a 30-minute flight at 500 Hz has 900,000 periods): sums and
extremes, and fixed-bin histograms for the percentiles. :class:`FlightMetrics` takes one period at a time, from
:class:`~groundstation.runtime.flight.Flight` or from a log's ``/control`` records (``groundstation replay``),
so a replayed log reports what the flight reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from groundstation.control.phase import Phase
from groundstation.rotations import rotation_angle
from groundstation.runtime.loop import LoopSummary

MEASURED = (Phase.SETTLE, Phase.TRACK, Phase.HOLD)
"""Phases over which attitude errors and saturation count (take-off and landing ramps excluded)."""
SATURATED = 0.999
"""A rotor at this fraction of u_max or more, or at the complement or less, is saturated (at a bound)."""


@dataclass(frozen=True)
class FlightFigures:
    """Tracking, attitude, motor and loop figures of one flight; NaN where a phase was never reached. Position
    errors over the tracking phase, attitude errors and saturation over the airborne phases (:data:`MEASURED`)."""

    pos_rmse_m: float
    """RMS of the position error's norm, m."""
    max_pos_error_m: float
    """Largest position error norm, m."""
    pos_rmse_xyz_m: tuple[float, float, float]
    """RMS per world axis, m."""
    max_pos_error_xyz_m: tuple[float, float, float]
    """Largest |error| per world axis, m."""
    max_orientation_error_deg: float
    """Largest angle between the attitude and its target, deg."""
    orientation_error_p50_deg: float
    orientation_error_p95_deg: float
    max_roll_error_deg: float
    """Largest |roll - roll target| (ZYX angles), deg."""
    max_yaw_error_deg: float
    max_motor_fraction: float
    """Largest rotor command, fraction of u_max."""
    saturation_fraction: tuple[float, ...]
    """Per module: share of airborne periods in which one of its rotors was at a bound."""
    motor_change_rms: float
    """RMS, over the rotors and the tracking periods, of a rotor command's change since the period before,
    fraction of u_max: the chatter that sensor noise puts on the motors (NaN: no tracking)."""
    motor_change_max: float
    """The largest such change, fraction of u_max."""
    mocap_age_p99_ms: float
    """99th percentile of the age of the pose a period used, ms."""
    loop_period_error_p50_ms: float
    """Median |actual - scheduled| start of a period, ms."""
    loop_period_error_p99_ms: float
    compute_p99_ms: float
    """99th percentile of the compute time of the period before each commanded one, ms (the log's figure)."""
    periods: int
    simulated_s: float
    """Flight time covered by the periods, from the first one's start to the last one's end, s (a replayed window:
    its own)."""


@dataclass(frozen=True)
class FlightSummary(FlightFigures):
    """A flown flight's figures with its wall time, plan and end, and the loop's timing (``fly --json``)."""

    realtime_factor: float
    """Flight time per wall-clock second (1 for a real-time flight; above 1 in lockstep simulation)."""
    planned_s: float
    """Duration of the flight plan, take-off to landing, s."""
    crashed: bool
    """The flight ended in an emergency stop."""
    stalls: int
    """Loop stalls the flight logged."""
    loop: LoopSummary | None = None

    @classmethod
    def of(cls, figures: FlightFigures, **rest) -> FlightSummary:
        return cls(**figures_of(figures), **rest)


def figures_of(figures: FlightFigures) -> dict:
    """The :class:`FlightFigures` fields of ``figures`` (or of a subclass instance) by name, unconverted."""
    return {f.name: getattr(figures, f.name) for f in fields(FlightFigures)}


class Histogram:
    """Percentiles of a stream of non-negative values, to ``resolution`` up to ``limit`` (beyond: the exact
    maximum); memory ``limit / resolution`` counters."""

    def __init__(self, limit: float, resolution: float) -> None:
        self.resolution = resolution
        self._counts = np.zeros(int(math.ceil(limit / resolution)) + 1, dtype=np.int64)
        self.count = 0
        self.max = 0.0

    def add(self, x: float) -> None:
        x = abs(float(x))
        k = min(int(x / self.resolution), self._counts.size - 1)
        self._counts[k] += 1
        self.count += 1
        if x > self.max:
            self.max = x

    def percentile(self, q: float) -> float:
        """The q-th percentile (0..100): the upper edge of the bin holding it (the maximum in the last bin);
        NaN when empty."""
        if self.count == 0:
            return float("nan")
        rank = q / 100.0 * self.count
        k = int(np.searchsorted(np.cumsum(self._counts), max(rank, 1e-9)))
        if k >= self._counts.size - 1:
            return self.max
        return min((k + 1) * self.resolution, self.max)


class _Extent:
    """Sum of squares, maximum and count of a vector's components (per axis) and of its norm."""

    def __init__(self, dims: int) -> None:
        self.sq = np.zeros(dims)
        self.max = np.zeros(dims)
        self.norm_sq = 0.0
        self.norm_max = 0.0
        self.n = 0

    def add(self, e: np.ndarray) -> None:
        a = np.abs(e)
        self.sq += a * a
        np.maximum(self.max, a, out=self.max)
        nsq = float(a @ a)
        self.norm_sq += nsq
        self.norm_max = max(self.norm_max, math.sqrt(nsq))
        self.n += 1

    def rms(self) -> float:
        return math.sqrt(self.norm_sq / self.n) if self.n else float("nan")


def _roll_yaw(rotation: np.ndarray) -> tuple[float, float]:
    """ZYX roll and yaw of a rotation matrix, rad."""
    return math.atan2(rotation[2, 1], rotation[2, 2]), math.atan2(rotation[1, 0], rotation[0, 0])


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


class FlightMetrics:
    """Tracking, attitude, motor and loop figures of one flight, one control period at a time."""

    def __init__(self, n_modules: int) -> None:
        self.position = _Extent(3)
        """Position error over the tracking phase."""
        self.orientation = Histogram(limit=180.0, resolution=0.01)
        """Angle between the attitude and its target, airborne, deg."""
        self.max_roll_error = 0.0
        self.max_yaw_error = 0.0
        self.max_motor = 0.0
        """Largest rotor command, fraction of u_max."""
        self.saturated = np.zeros(n_modules, dtype=np.int64)
        """Airborne periods in which a rotor of the module was saturated."""
        self.airborne = 0
        self._last_tracked: np.ndarray | None = None
        """The rotor commands of the previous period, if it was a tracking one."""
        self.motor_change_sq = 0.0
        self.motor_change_n = 0
        self.motor_change_max = 0.0
        self.start_error = Histogram(limit=0.05, resolution=1e-5)
        """|Actual - scheduled| start of each period, s."""
        self.compute = Histogram(limit=0.05, resolution=1e-5)
        self.mocap_age = Histogram(limit=1.0, resolution=1e-4)
        """Age of the pose each period used, s."""
        self.periods = 0
        self.t_first = math.nan
        self.t_last = math.nan
        self.dt = math.nan

    def add(self, t: float, phase: str, position, position_ref, rotation, rotation_target, roll_target: float,
            yaw_target: float, motors: np.ndarray, mocap_age: float | None = None) -> None:
        """One period: the position and attitude flown (truth in simulation), the reference, the attitude target
        the controller aimed at (``rotation_target``), the roll and yaw targets (rad), the rotor commands as
        fractions of u_max (``(n, 4)``) and the age of the pose used (s)."""
        if self.periods == 1:
            self.dt = t - self.t_first
        if self.periods == 0:
            self.t_first = t
        self.periods += 1
        self.t_last = t
        if phase == Phase.TRACK:
            self.position.add(np.asarray(position, float) - np.asarray(position_ref, float))
        m = np.asarray(motors, float)
        self.max_motor = max(self.max_motor, float(m.max()) if m.size else 0.0)
        if phase == Phase.TRACK:
            if self._last_tracked is not None and self._last_tracked.shape == m.shape and m.size:
                change = m - self._last_tracked
                self.motor_change_sq += float(np.sum(change * change))
                self.motor_change_n += change.size
                self.motor_change_max = max(self.motor_change_max, float(np.abs(change).max()))
            self._last_tracked = m
        else:
            self._last_tracked = None
        if mocap_age is not None and math.isfinite(mocap_age):
            self.mocap_age.add(mocap_age)
        if phase in MEASURED:
            self.airborne += 1
            r = np.asarray(rotation, float)
            self.orientation.add(math.degrees(float(rotation_angle(r, np.asarray(rotation_target, float)))))
            roll, yaw = _roll_yaw(r)
            self.max_roll_error = max(self.max_roll_error, abs(math.degrees(_wrap(roll - roll_target))))
            self.max_yaw_error = max(self.max_yaw_error, abs(math.degrees(_wrap(yaw - yaw_target))))
            self.saturated += ((m >= SATURATED) | (m <= 1.0 - SATURATED)).any(axis=1)

    def add_timing(self, start_error: float, compute: float) -> None:
        self.start_error.add(start_error)
        self.compute.add(compute)

    def result(self) -> FlightFigures:
        """The figures so far."""
        p = self.position
        tracked = p.n > 0
        airborne = self.airborne > 0
        nan3 = (math.nan,) * 3
        return FlightFigures(
            pos_rmse_m=p.rms(),
            max_pos_error_m=p.norm_max if tracked else math.nan,
            pos_rmse_xyz_m=tuple(np.sqrt(p.sq / p.n).tolist()) if tracked else nan3,
            max_pos_error_xyz_m=tuple(p.max.tolist()) if tracked else nan3,
            max_orientation_error_deg=self.orientation.max if airborne else math.nan,
            orientation_error_p50_deg=self.orientation.percentile(50),
            orientation_error_p95_deg=self.orientation.percentile(95),
            max_roll_error_deg=self.max_roll_error if airborne else math.nan,
            max_yaw_error_deg=self.max_yaw_error if airborne else math.nan,
            max_motor_fraction=self.max_motor,
            saturation_fraction=tuple((self.saturated / self.airborne).tolist()) if airborne
            else (0.0,) * self.saturated.size,
            motor_change_rms=math.sqrt(self.motor_change_sq / self.motor_change_n) if self.motor_change_n
            else math.nan,
            motor_change_max=self.motor_change_max if self.motor_change_n else math.nan,
            mocap_age_p99_ms=self.mocap_age.percentile(99) * 1e3,
            loop_period_error_p50_ms=self.start_error.percentile(50) * 1e3,
            loop_period_error_p99_ms=self.start_error.percentile(99) * 1e3,
            compute_p99_ms=self.compute.percentile(99) * 1e3,
            periods=self.periods,
            simulated_s=self.t_last - self.t_first + self.dt if self.periods > 1 else 0.0,
        )
