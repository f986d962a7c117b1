"""The modules' gyros checked against each other: one rigid body has one rate, so a module whose gyro disagrees
with the others' is a failed or loose IMU (or a module mounted where the assembly file does not say).

Each module's reading, rotated into the body frame, is compared with the mean of the others'. Readings differ by
noise and by their delays (a Crazyflie's state packet every 10 ms, links 12-20 ms apart), so the tolerance is a
floor, a share of the rate, and what the rate itself changed by over the last ``delay_spread`` (a reading that
late can be that far off; the smallest change among the modules, since a failing one jumps). What exceeds the
tolerance is integrated: the fault comes when the excess would have turned the attitude estimate by
``angle_budget``. A gyro stuck at full scale (2000 deg/s) is a fault in the period it first shows, before the
estimator integrates it; one stuck at its reading while the body turns at 60 deg/s, after ~0.1 s. The fault
latches, and the module is left out of the body rate from then on: with three modules or more the one farthest
from the others, with two the one farther from the rate the mocap poses show
(:meth:`RigidBodyFilter.pose_rate`; without poses, neither). Readings that are not numbers never enter the body
rate, nor stale ones while a fresh one is there (a module isolated after a fault sends none: its last reading ages).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GyroAgreementSettings:
    floor: float = 0.5
    """Disagreement always tolerated, rad/s (29 deg/s: noise and quantisation)."""
    relative: float = 0.25
    """...plus this share of the body rate's magnitude (scale errors)..."""
    delay_spread: float = 0.025
    """...plus the rate's change over this long, s: how far apart in time two modules' readings may be."""
    angle_budget: float = math.radians(1.5)
    """Disagreement beyond the tolerance, integrated over time, that is a fault, rad (the attitude error it would
    have caused; a disagreement back within the tolerance starts the count again)."""
    max_step: float = 0.01
    """Longest time one reading counts for, s (a stalled loop's gap is not a disagreement that lasted)."""


class GyroAgreement:
    """Feed :meth:`rate` every period with the modules' body-frame gyros; :attr:`fault` names a latched
    disagreement ("" while there is none)."""

    def __init__(self, settings: GyroAgreementSettings | None = None) -> None:
        self.settings = settings or GyroAgreementSettings()
        self.fault = ""
        self.excluded: int | None = None
        """The module left out of the body rate after a fault."""
        self.worst = 0.0
        """The largest disagreement seen, rad/s."""
        self._t: float | None = None
        self._since: float | None = None
        self._excess = 0.0
        self._recent: deque[tuple[float, list[list[float]]]] = deque()
        """(t, readings) of the last ``delay_spread``."""
        self._judged: list[int] | None = None
        """The modules judged last (None: all): :attr:`_recent` compares readings of the same modules only."""

    def rate(self, t: float, module_gyros: np.ndarray, mean: np.ndarray,
             referee: Callable[[], np.ndarray | None] | None = None, ages: np.ndarray | None = None,
             age: float = 0.0, stale_s: float = math.inf) -> tuple[np.ndarray, float]:
        """The body rate to fly on at ``t`` (s) and how old it is (s): ``mean`` (the backend's, of all modules,
        ``age`` old) unless a module was left out, a reading is not a number or is stale; judges ``module_gyros``
        ((n, 3), rad/s, body frame) on the way. ``ages``: each module's reading's age, s (None or empty: all
        ``age`` old; NaN: stale); a reading older than ``stale_s`` is left out of the rate while fresher ones exist,
        and only the fresh readings are judged, against each other (two at least): a packet late by tens of ms
        during a turn is old news, not a loose IMU, and a module taken out of the flight (its age infinite) leaves
        the others judged. ``referee``: the body rate from the mocap poses (rad/s; None: none), which picks the
        wrong one of two; asked only then (not on the control loop's every period)."""
        n = len(module_gyros)
        if n < 2:
            return mean, age
        # In Python floats: on a few modules' readings numpy's overhead per call costs more than the arithmetic
        # (``python -m benchmarks.estimator``, 2026-12-02: 68 us a period in numpy for two modules, 10 us in floats; 82
        # and 67 us for 60).
        rates = module_gyros.tolist()
        # A sum that is a number says that every reading is one (the common case, on every control period).
        finite = None if math.isfinite(sum(map(sum, rates))) else np.isfinite(module_gyros).all(axis=1)
        fresh = None
        if ages is not None and len(ages) == n:
            fresh = ages <= stale_s  # NaN compares False: stale
            fresh = None if fresh.all() else fresh
        if not self.fault:
            if fresh is None:
                self._judge(t, module_gyros, rates, finite, referee, None)
            elif fresh.sum() >= 2:
                index = np.flatnonzero(fresh).tolist()
                self._judge(t, module_gyros[index], [rates[i] for i in index],
                            None if finite is None else finite[index], referee, index)
        if self.excluded is None and (finite is None or finite.all()) and fresh is None:
            return mean, age
        keep = np.isfinite(module_gyros).all(axis=1)
        if self.excluded is not None:
            keep[self.excluded] = False
        if fresh is not None and (keep & fresh).any():
            keep &= fresh
        if not keep.any():
            return mean, age
        used_age = age if ages is None or len(ages) != n else float(ages[keep].max())
        return (mean if keep.all() else module_gyros[keep].mean(axis=0)), used_age

    def _judge(self, t: float, module_gyros: np.ndarray, rates: list[list[float]], finite: np.ndarray | None,
               referee: Callable[[], np.ndarray | None] | None, index: list[int] | None) -> None:
        """``rates``: ``module_gyros`` as lists; ``finite``: which are numbers (None: all are); ``index``: the
        modules these are (None: all, in order)."""
        s = self.settings
        if index != self._judged:  # other modules than last time: their history does not compare
            self._judged = index
            self._recent.clear()
        dt = 0.0 if self._t is None else min(max(t - self._t, 0.0), s.max_step)
        self._t = t
        n = len(module_gyros)
        broken = finite is not None and not finite.all()
        if broken:  # a reading that is not a number agrees with nothing
            off = [0.0 if ok else math.inf for ok in finite.tolist()]
            bx, by, bz = module_gyros[finite].mean(axis=0).tolist() if finite.any() else (0.0, 0.0, 0.0)
        else:
            self._remember(t, rates)
            tx, ty, tz = map(sum, zip(*rates, strict=True))
            k = n - 1
            off = []  # squared: only the largest needs its root
            for x, y, z in rates:  # each module against its counterpart, the mean of the others
                dx, dy, dz = x - (tx - x) / k, y - (ty - y) / k, z - (tz - z) / k
                off.append(dx * dx + dy * dy + dz * dz)
            bx, by, bz = tx / n, ty / n, tz / n
        off_i = math.sqrt(max(off))
        tolerance = s.floor + s.relative * math.sqrt(bx * bx + by * by + bz * bz)
        if off_i > tolerance and not broken:  # what the rate changed by is wanted only when the rest is not enough
            tolerance += self._change()
        self.worst = max(self.worst, off_i)
        if off_i <= tolerance:
            self._since, self._excess = None, 0.0
            return
        if self._since is None:
            self._since = t
        self._excess += (off_i - tolerance) * dt if math.isfinite(off_i) else math.inf
        if self._excess < s.angle_budget:
            return
        i = off.index(max(off))
        size = "not a number" if not math.isfinite(off_i) else f"{math.degrees(off_i):.0f} deg/s"
        lasted = f"{(t - self._since) * 1e3:.0f} ms"
        poses = referee() if n == 2 and referee is not None and not broken else None
        if poses is not None:
            i = int(np.argmax(np.sqrt(((module_gyros - poses) ** 2).sum(axis=1))))
        elif n == 2 and not broken:
            a, b = index or (0, 1)
            self.fault = (f"the gyros of modules {a} and {b} disagree by {size} for {lasted} (tolerated "
                          f"{math.degrees(tolerance):.0f}): a failed or loose IMU; no poses to tell which")
            return
        i = i if index is None else index[i]
        self.excluded = i
        whose = "other's" if n == 2 else "others'"
        self.fault = (f"module {i}'s gyro disagrees with the {whose} by {size} for {lasted} (tolerated "
                      f"{math.degrees(tolerance):.0f}): a failed or loose IMU, left out of the body rate")

    def _remember(self, t: float, rates: list[list[float]]) -> None:
        recent = self._recent
        recent.append((t, rates))
        while len(recent) > 1 and recent[1][0] <= t - self.settings.delay_spread:
            recent.popleft()

    def _change(self) -> float:
        """The smallest change of a module's reading over the last ``delay_spread`` (to the newest), rad/s."""
        recent = self._recent
        oldest, newest = recent[0][1], recent[-1][1]
        if len(oldest) != len(newest):
            return 0.0
        return min(math.sqrt((x - u) ** 2 + (y - v) ** 2 + (z - w) ** 2)
                   for (x, y, z), (u, v, w) in zip(newest, oldest, strict=True))
