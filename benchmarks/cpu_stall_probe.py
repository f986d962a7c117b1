"""Detects stalls of one CPU that no process on it can cause: a top-priority thread that wakes every millisecond.

    python -m benchmarks.cpu_stall_probe --cpu 0 --duration 60 [--threshold-ms 0.5]

Pinned to ``--cpu`` at ``SCHED_FIFO`` 99 (falls back to normal scheduling if refused, which it reports), the
probe preempts every ordinary and real-time thread of the guest, so when it wakes late the CPU itself was not
running: a hypervisor taking the virtual CPU away (steal), or kernel work with interrupts off. It prints one JSON
object: ``{"cpu", "realtime", "wakeups", "stalls": [[monotonic start s, length s], ...]}``. CLOCK_MONOTONIC is
system-wide, so the stalls line up with another process's timestamps (``benchmarks.loop`` uses this to tell
overruns the machine caused from overruns the ground station caused). It costs ~2% of one CPU. SIGTERM ends
it early (it still prints).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import time

PERIOD_S = 1e-3


class _Stop(Exception):
    pass


def _stop(*_) -> None:
    raise _Stop


def probe(duration: float, threshold: float) -> tuple[int, list[tuple[float, float]]]:
    """Wake every ``PERIOD_S`` for ``duration`` s (or until SIGTERM); returns the wake-ups and each
    (due time, lateness) over ``threshold``."""
    stalls = []
    wakeups = 0
    end = time.monotonic() + duration
    due = time.monotonic()
    signal.signal(signal.SIGTERM, _stop)
    try:
        while due < end:
            due += PERIOD_S
            time.sleep(max(0.0, due - time.monotonic()))
            late = time.monotonic() - due
            wakeups += 1
            if late > threshold:
                stalls.append((due, late))
                due = time.monotonic()  # resynchronise rather than burst
    except _Stop:
        pass
    return wakeups, stalls


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cpu", type=int, required=True)
    ap.add_argument("--duration", type=float, required=True, help="s")
    ap.add_argument("--threshold-ms", type=float, default=0.5)
    args = ap.parse_args(argv)
    os.sched_setaffinity(0, {args.cpu})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(99))
        realtime = True
    except (PermissionError, OSError):
        realtime = False
    wakeups, stalls = probe(args.duration, args.threshold_ms * 1e-3)
    print(json.dumps({"cpu": args.cpu, "realtime": realtime, "wakeups": wakeups, "stalls": stalls}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
