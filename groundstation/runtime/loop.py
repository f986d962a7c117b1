"""The fixed-rate loop: deadline scheduling on an injected clock, with per-period timing.

One loop serves both uses: ``simulate`` injects a :class:`SimClock` (lockstep: "sleeping" advances physics)
and ``fly`` a :class:`WallClock` (monotonic time, hybrid sleep: ``time.sleep`` until shortly before the
deadline, then a short spin, which keeps the start error well under a millisecond on a loaded machine).
A period that overruns its deadline is counted and the loop resumes at the next future deadline instead of
bursting to catch up.
"""

from __future__ import annotations

import gc
import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from groundstation.backends.base import SimulatedBackend

SPIN_S = 0.0015
"""Last part of each wait spent spinning instead of sleeping, s (normal scheduling: wake-up can be late)."""
SPIN_RT_S = 0.0002
"""The same under real-time scheduling, where a sleeping thread wakes within tens of microseconds, s."""


class Clock(Protocol):
    def now(self) -> float: ...
    def sleep_until(self, t: float) -> None: ...


class WallClock:
    """Monotonic wall time."""

    def __init__(self, spin_s: float = SPIN_S) -> None:
        self.spin_s = spin_s

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        remaining = t - time.monotonic()
        if remaining > self.spin_s:
            time.sleep(remaining - self.spin_s)
        while time.monotonic() < t:
            pass


class SimClock:
    """Simulated time of a backend with ``time`` and ``advance_to`` (lockstep)."""

    def __init__(self, backend: SimulatedBackend) -> None:
        self._backend = backend

    def now(self) -> float:
        return self._backend.time

    def sleep_until(self, t: float) -> None:
        self._backend.advance_to(t)


@contextmanager
def collector_paused() -> Iterator[None]:
    """Run the block with Python's cyclic garbage collector off, everything allocated before it frozen.

    An automatic collection runs in whichever thread happens to allocate, holding the GIL: measured during a
    500 Hz dry run, 4 young-generation passes per second took 0.5-1.5 ms each and an oldest-generation pass 20 ms,
    the largest single cause of late periods. Inside the block the loop collects the young generations itself,
    between periods (:func:`collect_young`); the oldest generation waits for the end of the block. Reference
    counting still frees everything that is not in a cycle, which is nearly everything the loop allocates.
    """
    was_enabled = gc.isenabled()
    gc.freeze()
    gc.disable()
    try:
        yield
    finally:
        gc.unfreeze()
        if was_enabled:
            gc.enable()


def collect_young(time_left: float, min_time: float = 1.2e-3) -> bool:
    """Collect generations 0 and 1 if at least ``min_time`` seconds remain before the next period; True if done.

    Measured in a 500 Hz dry run with one collection a second: 0.64 ms median, 0.75 ms worst."""
    if time_left < min_time:
        return False
    gc.collect(1)
    return True


HELPER_NICE = -10
"""Nice value of the flight process's other threads while the loop runs real-time (link receivers, Zenoh, the
log feeder): they take the GIL between periods, and one that an ordinary process preempts while holding it holds
the loop up too. At nice 0 beside two busy processes on 2 cores, a SCHED_FIFO loop still stalled 20-40 ms (compute
p50 1.8 ms against 0.5 idle) on a Crazyflie flight."""


@contextmanager
def realtime_priority(priority: int, helpers: tuple[int, ...] = ()) -> Iterator[bool]:
    """Run the calling thread under ``SCHED_FIFO`` at ``priority`` (1..99) for the block, and the process's other
    threads, and those of the processes ``helpers`` (pids: the log writer), at :data:`HELPER_NICE`; yields whether
    it did.

    A real-time thread is not preempted by the process's other threads or by ordinary processes, which is what
    keeps a 4 ms period on a busy 2-core machine; the others outrank ordinary processes so that what holds the GIL
    gives it back soon. It needs CAP_SYS_NICE or an ``rtprio`` limit (``/etc/security/limits.conf``); without
    them, or with ``priority`` 0, the block runs at normal priority and this yields False. Linux applies both per
    thread; the old ones are restored after.
    """
    if priority <= 0 or not hasattr(os, "sched_setscheduler"):
        yield False
        return
    old_policy, old_param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        # RESET_ON_FORK: threads and processes started from this one (a hook's thread, a restarted firmware
        # process) do not inherit the real-time policy.
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
    except (PermissionError, OSError):
        yield False
        return
    reniced: list[tuple[str, int, int]] = []
    try:
        # The log writer too: at nice 0 beside two flights' loops and helpers (the test suite's two workers), it
        # took none of its input for 2 s, and the flight called it hung.
        for pid in ("self", *map(str, helpers)):
            reniced += _renice_threads(pid, HELPER_NICE)
        yield True
    finally:
        for pid, tid, nice in reniced:
            with suppress(OSError):  # the thread has ended meanwhile
                if os.path.exists(f"/proc/{pid}/task/{tid}"):  # not an id the kernel has given to another
                    os.setpriority(os.PRIO_PROCESS, tid, nice)
        os.sched_setscheduler(0, old_policy, old_param)


def _renice_threads(pid: str, nice: int) -> list[tuple[str, int, int]]:
    """Set every thread of process ``pid`` ("self": this one, but for the calling thread) to ``nice`` (those whose
    nice is higher); returns (pid, thread id, old nice) of each changed."""
    me, changed = threading.get_native_id(), []
    with suppress(OSError):  # the process has ended
        for entry in os.listdir(f"/proc/{pid}/task"):
            tid = int(entry)
            with suppress(OSError):  # ended meanwhile, or not permitted
                old = os.getpriority(os.PRIO_PROCESS, tid)
                if tid != me and old > nice:
                    os.setpriority(os.PRIO_PROCESS, tid, nice)
                    changed.append((pid, tid, old))
    return changed


@dataclass(frozen=True)
class LoopSummary:
    """Timing of a fixed-rate run (``/loop/timing`` in a flight log); times in ms, percentiles of |start error|."""

    periods: int
    rate_hz: float
    overruns: int
    """Periods whose step ended after the next deadline."""
    realtime: bool
    """The loop thread ran under real-time scheduling."""
    start_error_ms_p50: float
    start_error_ms_p99: float
    start_error_ms_max: float
    compute_ms_p50: float
    compute_ms_p99: float
    overrun_starts: tuple[float, ...]
    """Clock time at which each overrunning period started, s."""


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
    overrun_starts: list[float] = field(default_factory=list)
    """Clock time at which each overrunning period started (to line overruns up with other events)."""
    realtime: bool = False
    """The loop thread ran under real-time scheduling."""
    t0: float | None = None
    """Clock time period 0 was scheduled at (None before the loop starts)."""

    def summary(self) -> LoopSummary:
        e = np.abs(np.array(self.start_error)) * 1e3 if self.start_error else np.zeros(1)
        c = np.array(self.compute) * 1e3 if self.compute else np.zeros(1)
        return LoopSummary(len(self.start_error), 1.0 / self.period, self.overruns, self.realtime,
                           float(np.percentile(e, 50)), float(np.percentile(e, 99)), float(e.max()),
                           float(np.percentile(c, 50)), float(np.percentile(c, 99)), tuple(self.overrun_starts))


def run_fixed_rate(step: Callable[[int, float], bool], rate_hz: float, clock: Clock,
                   max_periods: int | None = None, stats: LoopStats | None = None,
                   between: Callable[[float], object] | None = None) -> LoopStats:
    """Call ``step(k, t)`` at ``rate_hz`` (``t`` seconds since the start, on ``clock``) until it returns False.

    The step for period k is scheduled at ``t0 + k / rate_hz``. Pass ``stats`` to let the step read the timing
    of the periods before it (e.g. to log it). ``between(time_left)`` runs after each step's timing is taken,
    with the seconds left before the next deadline (housekeeping; if it runs late, the next start error shows it).
    """
    period = 1.0 / rate_hz
    stats = stats if stats is not None else LoopStats(period)
    t0 = clock.now()
    stats.t0 = t0
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
            stats.overrun_starts.append(start)
            k = int(np.floor((done - t0) / period)) + 1
        if between is not None:
            between(t0 + k * period - clock.now())
    return stats
