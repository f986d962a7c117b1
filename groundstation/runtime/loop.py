"""The fixed-rate loop: deadline scheduling on an injected clock, with per-period timing.

One loop serves both uses: ``simulate`` injects a :class:`SimClock` (lockstep: "sleeping" advances physics)
and ``fly`` a :class:`WallClock` (monotonic time, hybrid sleep: ``time.sleep`` until shortly before the
deadline, then a short spin, which keeps the start error well under a millisecond on a loaded machine).
A period that overruns its deadline is counted and the loop resumes at the next future deadline instead of
bursting to catch up.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

SPIN_S = 0.0015
"""Last part of each wait spent spinning instead of sleeping, s."""


class Clock(Protocol):
    def now(self) -> float: ...
    def sleep_until(self, t: float) -> None: ...


class WallClock:
    """Monotonic wall time."""

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        remaining = t - time.monotonic()
        if remaining > SPIN_S:
            time.sleep(remaining - SPIN_S)
        while time.monotonic() < t:
            pass


class SimClock:
    """Simulated time of a backend with ``time`` and ``advance_to`` (lockstep)."""

    def __init__(self, backend) -> None:
        self._backend = backend

    def now(self) -> float:
        return self._backend.time

    def sleep_until(self, t: float) -> None:
        self._backend.advance_to(t)


@dataclass
class LoopStats:
    """Per-period timing of a run, seconds."""

    period: float
    start_error: list[float] = field(default_factory=list)
    """Actual minus scheduled start of each period."""
    compute: list[float] = field(default_factory=list)
    """Time spent in the step function."""
    overruns: int = 0
    """Periods whose step ended after the next deadline."""

    def summary(self) -> dict:
        e = np.abs(np.array(self.start_error)) * 1e3 if self.start_error else np.zeros(1)
        c = np.array(self.compute) * 1e3 if self.compute else np.zeros(1)
        return {"periods": len(self.start_error), "rate_hz": 1.0 / self.period, "overruns": self.overruns,
                "start_error_ms_p50": float(np.percentile(e, 50)), "start_error_ms_p99": float(np.percentile(e, 99)),
                "start_error_ms_max": float(e.max()), "compute_ms_p50": float(np.percentile(c, 50)),
                "compute_ms_p99": float(np.percentile(c, 99))}


def run_fixed_rate(step: Callable[[int, float], bool], rate_hz: float, clock: Clock,
                   max_periods: int | None = None, stats: LoopStats | None = None) -> LoopStats:
    """Call ``step(k, t)`` at ``rate_hz`` (``t`` seconds since the start, on ``clock``) until it returns False.

    The step for period k is scheduled at ``t0 + k / rate_hz``. Pass ``stats`` to let the step read the timing
    of the periods before it (e.g. to log it).
    """
    period = 1.0 / rate_hz
    stats = stats if stats is not None else LoopStats(period)
    t0 = clock.now()
    k = 0
    while max_periods is None or k < max_periods:
        deadline = t0 + k * period
        clock.sleep_until(deadline)
        start = clock.now()
        stats.start_error.append(start - deadline)
        keep_going = step(k, start - t0)
        done = clock.now()
        stats.compute.append(done - start)
        if not keep_going:
            break
        k += 1
        if done > t0 + k * period:  # overran: skip to the next deadline still ahead
            stats.overruns += 1
            k = int(np.floor((done - t0) / period)) + 1
    return stats
