"""When the control loop is between periods: the one piece of loop timing that the log writer, the simulated
mocap and status displays share with the loop (a layer below all of them)."""

from __future__ import annotations

import threading
import time


class LoopActivity:
    """Tells background Python threads (log writer, simulated mocap, status line) when the loop is between periods.

    Python threads share one GIL. A thread that wakes while a period computes takes the GIL from the loop (after
    the switch interval) and, worse, must first be scheduled by the OS before the loop can get it back: a
    real-time loop thread then waits on an ordinary one. Measured at 500 Hz, such hand-overs were the largest
    source of late periods. So producers on the loop thread only append to deques (no wake-ups), the loop marks
    :meth:`begin` when a period starts and :meth:`end` with the idle time it has left, and background threads wait
    for :meth:`end` and start a piece of work only if it fits before the next period (:meth:`may_work`).
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self.busy = False
        """True while a period computes (a plain bool: reads and writes are atomic under the GIL)."""
        self._idle_until = float("inf")

    def begin(self) -> None:
        self.busy = True

    def end(self, idle_s: float = float("inf")) -> None:
        """The period is done; the next one starts in ``idle_s`` seconds (default: no loop is running)."""
        self._idle_until = time.monotonic() + idle_s
        self.busy = False
        with self._cond:
            self._cond.notify_all()

    def may_work(self, budget_s: float) -> bool:
        """True if a piece of work taking ``budget_s`` seconds fits before the next period starts."""
        return not self.busy and time.monotonic() + budget_s < self._idle_until

    def wait_end(self, timeout: float) -> None:
        """Block until the next :meth:`end` or ``timeout`` seconds (so work proceeds when no loop runs)."""
        with self._cond:
            self._cond.wait(timeout)
