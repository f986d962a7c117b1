import gc
import os
import subprocess
import sys
import threading
import time

import pytest

from groundstation.loop_activity import LoopActivity
from groundstation.runtime.loop import (
    HELPER_NICE,
    collect_young,
    collector_paused,
    realtime_priority,
    run_fixed_rate,
)


class FakeClock:
    """Time moves only when the step says so (``cost``) or when the loop sleeps."""

    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t

    def sleep_until(self, t: float) -> None:
        self.t = max(self.t, t)


def test_deadlines_overruns_and_between():
    clock = FakeClock()
    starts, left = [], []
    costs = {3: 0.025, 6: 0.005}  # period 3 overruns by 1.5 periods; period 6 fits

    def step(k, t):
        starts.append((k, round(t, 9)))
        clock.t += costs.get(k, 0.001)
        return k < 8

    stats = run_fixed_rate(step, 100.0, clock, between=lambda s: left.append(round(s, 9)))
    # period 3 ends at 0.055 s: deadlines 0.04 and 0.05 are skipped, the loop resumes at 0.06 (k = 6)
    assert [k for k, _ in starts] == [0, 1, 2, 3, 6, 7, 8]
    assert [t for _, t in starts] == [0.0, 0.01, 0.02, 0.03, 0.06, 0.07, 0.08]
    assert stats.overruns == 1 and len(stats.compute) == 7
    assert stats.overrun_starts == [pytest.approx(100.03)]  # clock time, not loop time
    assert stats.compute[3] == pytest.approx(0.025)
    assert left[:3] == [0.009, 0.009, 0.009] and left[3] == pytest.approx(0.005)  # to 0.06 from 0.055
    s = stats.summary()
    assert s.periods == 7 and s.overruns == 1 and s.realtime is False


def test_background_thread_waits_for_the_end_of_a_period():
    activity = LoopActivity()
    woke = []

    def background():
        activity.wait_end(5.0)
        woke.append((time.monotonic(), activity.busy))

    activity.begin()
    th = threading.Thread(target=background)
    th.start()
    time.sleep(0.05)
    assert not woke  # still computing
    t_end = time.monotonic()
    activity.end()
    th.join(2.0)
    assert woke and woke[0][0] >= t_end and woke[0][1] is False
    t0 = time.monotonic()
    activity.wait_end(0.02)  # nobody ends a period: returns after the timeout
    assert time.monotonic() - t0 >= 0.019
    assert activity.may_work(10.0)  # no loop running: any work fits
    activity.begin()
    assert not activity.may_work(0.0)
    activity.end(0.05)  # the next period starts in 50 ms
    assert activity.may_work(0.01) and not activity.may_work(0.1)


def test_collector_paused_restores_the_collector():
    assert gc.isenabled()
    with collector_paused():
        assert not gc.isenabled() and gc.get_freeze_count() > 0
        assert not collect_young(0.5e-3)  # not enough time left before the next period
        assert collect_young(5e-3)
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_realtime_priority_is_restored():
    before = os.sched_getscheduler(0)
    wake = threading.Event()
    helper = threading.Thread(target=wake.wait, daemon=True)  # a link receiver, say
    helper.start()
    writer = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])  # the log writer, say
    try:
        helper_nice = os.getpriority(os.PRIO_PROCESS, helper.native_id)
        writer_nice = os.getpriority(os.PRIO_PROCESS, writer.pid)
        with realtime_priority(10, (writer.pid,)) as rt:
            policy = os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK
            assert (policy == os.SCHED_FIFO) == rt
            # the other threads and the helper processes outrank ordinary processes meanwhile (where permitted)
            assert os.getpriority(os.PRIO_PROCESS, helper.native_id) == (min(HELPER_NICE, helper_nice) if rt else
                                                                         helper_nice)
            assert os.getpriority(os.PRIO_PROCESS, writer.pid) == (min(HELPER_NICE, writer_nice) if rt else
                                                                   writer_nice)
            started = []  # a thread started from the real-time one (a hook's) does not inherit the policy
            child = threading.Thread(target=lambda: started.append(os.sched_getscheduler(0)))
            child.start()
            child.join()
            assert started == [os.SCHED_OTHER]
        assert os.sched_getscheduler(0) == before
        assert os.getpriority(os.PRIO_PROCESS, helper.native_id) == helper_nice
        assert os.getpriority(os.PRIO_PROCESS, writer.pid) == writer_nice
    finally:
        wake.set()
        helper.join()
        writer.kill()
        writer.wait()
    with realtime_priority(0) as rt:
        assert rt is False and os.sched_getscheduler(0) == before
