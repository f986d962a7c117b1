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

A reading that is not a number, or one repeated to the last bit for ``frozen_s`` while its module's packets keep
arriving (a gyro's noise changes every reading: a repeat is a stuck sensor or a stuck buffer), is *unusable*: it
is a fault at once, and the module is left out. When no module has a usable reading (every gyro failed alike, or
the only one), the fault says so and :meth:`GyroAgreement.rate` returns no rate, NaN, with the age of the last
usable one: the estimator then takes the attitude from the poses. Agreeing with each other, such readings had
been flown on: stuck at 0 or at 1 rad/s, the estimate held or turned while the poses were rejected as "off the
gyros' prediction", and the V landed blind on that attitude and came to rest upside down.
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
    frozen_s: float = 0.04
    """A module's reading the same to the last bit for this long, while fresh, is frozen, s: four readings at
    the 100 Hz of a Crazyflie's state packets (a real gyro's noise, 0.1 deg/s, changes every float32 reading);
    short of the estimator's ``inconsistent_s`` after the poses it turns away start being rejected."""


class GyroAgreement:
    """Feed :meth:`rate` every period with the modules' body-frame gyros; :attr:`fault` names a latched
    disagreement or an unusable reading ("" while there is none)."""

    def __init__(self, settings: GyroAgreementSettings | None = None) -> None:
        self.settings = settings or GyroAgreementSettings()
        self.fault = ""
        self.excluded: int | None = None
        """The module left out of the body rate after a fault."""
        self.worst = 0.0
        """The largest disagreement seen, rad/s."""
        self.lost_since: float | None = None
        """Since when no module has had a usable reading, s (None while one has)."""
        self._t: float | None = None
        self._since: float | None = None
        self._excess = 0.0
        self._recent: deque[tuple[float, list[list[float]]]] = deque()
        """(t, readings) of the last ``delay_spread``."""
        self._judged: list[int] | None = None
        """The modules judged last (None: all): :attr:`_recent` compares readings of the same modules only."""
        self._previous: tuple[float, list[list[float]]] | None = None
        """(t, readings) of the previous call: what a frozen reading repeats."""
        self._same_since: list[float | None] = []
        """Per module: since when its reading has been the same to the last bit, s (None: it changed)."""
        self._used_t = -math.inf
        """When the newest reading flown on arrived, s."""
        self._condemned_since: float | None = None
        """Since when every reading is wrong, as another witness found (:meth:`condemn`), s."""

    def rate(self, t: float, module_gyros: np.ndarray, mean: np.ndarray,
             referee: Callable[[], np.ndarray | None] | None = None, ages: np.ndarray | None = None,
             age: float = 0.0, stale_s: float = math.inf, touching: bool = False) -> tuple[np.ndarray, float]:
        """The body rate to fly on at ``t`` (s) and how old it is (s): ``mean`` (the backend's, of all modules,
        ``age`` old) unless a module was left out, a reading is unusable or is stale; judges ``module_gyros``
        ((n, 3), rad/s, body frame) on the way. ``ages``: each module's reading's age, s (None or empty: all
        ``age`` old; NaN: stale); a reading older than ``stale_s`` is left out of the rate while fresher ones exist,
        and only the fresh readings are judged, against each other (two at least): a packet late by tens of ms
        during a turn is old news, not a loose IMU, and a module taken out of the flight (its age infinite) leaves
        the others judged. ``referee``: the body rate from the mocap poses (rad/s; None: none), which picks the
        wrong one of two; asked only then (not on the control loop's every period). ``touching``: the assembly may
        be touching the ground, whose contacts kick the body rate for a reading or two, which modules sampling a few
        ms apart read differently (measured at a touchdown: 248 deg/s apart for one reading): their disagreement is
        not judged then, unusable readings still are. With no usable reading: NaN, and the time since the last one
        flown on (:attr:`lost_since`)."""
        n = len(module_gyros)
        if n == 0:
            return mean, age
        if self._condemned_since is not None:
            self.lost_since = self._condemned_since
            return np.full(3, math.nan), t - self._condemned_since
        # In Python floats: on a few modules' readings numpy's overhead per call costs more than the arithmetic
        # (``python -m benchmarks.estimator``, 2026-12-02: 68 us a period in numpy for two modules, 10 us in floats; 82
        # and 67 us for 60).
        rates = module_gyros.tolist()
        fresh = None
        if ages is not None and len(ages) == n:
            fresh = ages <= stale_s  # NaN compares False: stale
            fresh = None if fresh.all() else fresh
        elif not age <= stale_s:  # no ages of their own: all as old as ``age`` (a gap is not a frozen reading)
            fresh = np.zeros(n, dtype=bool)
        # A sum that is a number says that every reading is one (the common case, on every control period).
        finite = None if math.isfinite(sum(map(sum, rates))) else np.isfinite(module_gyros).all(axis=1)
        frozen = self._frozen(t, rates, fresh)
        usable = finite if frozen is None else (~frozen if finite is None else finite & ~frozen)
        if not self.fault:
            bad = None if usable is None else ~usable if fresh is None else ~usable & fresh
            if bad is not None and bad.any():
                self._name_unusable(t, rates, bad, usable if fresh is None else usable & fresh, finite)
            elif touching:
                self._since, self._excess = None, 0.0
            elif n < 2:
                pass
            elif fresh is None:
                self._judge(t, module_gyros, rates, referee, None)
            elif fresh.sum() >= 2:
                index = np.flatnonzero(fresh).tolist()
                self._judge(t, module_gyros[index], [rates[i] for i in index], referee, index)
        if self.excluded is None and usable is None and fresh is None:
            self._used_t, self.lost_since = t - age, None
            return mean, age
        keep = np.ones(n, dtype=bool) if usable is None else usable.copy()
        if self.excluded is not None:
            keep[self.excluded] = False
        if fresh is not None and (keep & fresh).any():
            keep &= fresh
        if not keep.any():
            # Frozen readings were flown on until they were seen to be: the rate is unknown since they froze.
            lost = min([self._used_t] + [since for i, since in enumerate(self._same_since)
                                         if since is not None and i != self.excluded])
            self.lost_since = lost
            return np.full(3, math.nan), t - lost
        used_age = age if ages is None or len(ages) != n else float(ages[keep].max())
        self._used_t, self.lost_since = t - used_age, None
        return (mean if keep.all() else module_gyros[keep].mean(axis=0)), used_age

    def condemn(self, since: float, why: str) -> None:
        """Every module's reading is wrong alike since ``since`` (s), as a witness other than the modules found
        (:class:`~groundstation.estimation.gyro_torque.TorqueAgreement`): from now on :meth:`rate` gives no rate,
        and :attr:`fault` says ``why`` (unless a fault was named before: it stays, the rate goes all the same)."""
        self._condemned_since = since
        self.fault = self.fault or why

    def _frozen(self, t: float, rates: list[list[float]], fresh: np.ndarray | None) -> np.ndarray | None:
        """Which modules' readings have been the same to the last bit, while fresh, for ``frozen_s`` (None: none)."""
        previous, self._previous = self._previous, (t, rates)
        if previous is None or len(previous[1]) != len(rates):
            self._same_since = [None] * len(rates)
            return None
        t_before, before = previous
        same, limit, out = self._same_since, self.settings.frozen_s, None
        for i, (now, then) in enumerate(zip(rates, before, strict=True)):
            if now != then:  # NaN differs from NaN: not "frozen"
                same[i] = None
                continue
            if fresh is not None and not fresh[i]:
                # A stale reading pauses the count, never ends it: a stuck gyro whose packets pause for 50 ms comes
                # back as stuck (counted afresh, it was flown on for another 40 ms: an 11 deg phantom turn).
                continue
            if same[i] is None:
                same[i] = t_before
            if t - same[i] >= limit:
                if out is None:
                    out = np.zeros(len(rates), dtype=bool)
                out[i] = True
        return out

    def _name_unusable(self, t: float, rates: list[list[float]], bad: np.ndarray, good: np.ndarray,
                       finite: np.ndarray | None) -> None:
        """Latch the fault of the unusable readings ``bad`` (``good``: the usable ones judged)."""
        def what(i: int) -> str:
            if finite is not None and not finite[i]:
                return "is not a number"
            reading = ", ".join(f"{math.degrees(x):.1f}" for x in rates[i])
            return f"has read ({reading}) deg/s to the last bit for {(t - self._same_since[i]) * 1e3:.0f} ms: frozen"

        first = int(np.flatnonzero(bad)[0])
        if not good.any():
            whose = "the gyro" if len(rates) == 1 else "every module's gyro" if bad.all() else \
                "every fresh module's gyro"
            self.fault = f"{whose} {what(first)}: no body rate, the attitude from the poses alone"
            return
        self.excluded = first
        self.fault = f"module {first}'s gyro {what(first)}: a failed IMU, left out of the body rate"

    def _judge(self, t: float, module_gyros: np.ndarray, rates: list[list[float]],
               referee: Callable[[], np.ndarray | None] | None, index: list[int] | None) -> None:
        """``rates``: ``module_gyros`` (every one a number) as lists; ``index``: the modules these are (None: all,
        in order)."""
        s = self.settings
        if index != self._judged:  # other modules than last time: their history does not compare
            self._judged = index
            self._recent.clear()
        dt = 0.0 if self._t is None else min(max(t - self._t, 0.0), s.max_step)
        self._t = t
        n = len(module_gyros)
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
        if off_i > tolerance:  # what the rate changed by is wanted only when the rest is not enough
            tolerance += self._change()
        self.worst = max(self.worst, off_i)
        if off_i <= tolerance:
            self._since, self._excess = None, 0.0
            return
        if self._since is None:
            self._since = t
        self._excess += (off_i - tolerance) * dt
        if self._excess < s.angle_budget:
            return
        i = off.index(max(off))
        size = f"{math.degrees(off_i):.0f} deg/s"
        lasted = f"{(t - self._since) * 1e3:.0f} ms"
        poses = referee() if n == 2 and referee is not None else None
        if poses is not None:
            i = int(np.argmax(np.sqrt(((module_gyros - poses) ** 2).sum(axis=1))))
        elif n == 2:
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
