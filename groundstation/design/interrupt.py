"""Ctrl-C for design work that runs inside Ipopt.

CasADi checks for signals during a solve and swallows SIGINT: a sweep ran on to its end after Ctrl-C. Inside
:func:`interruptible`, SIGINT only sets a flag; solvers poll it every iteration (an Ipopt iteration callback) and
between solves, and the context raises ``KeyboardInterrupt`` when the work stops. It takes effect only in the main
thread and only where SIGINT has Python's default handler: worker processes of a sweep ignore SIGINT (their
parent stops them) and Dask worker threads cannot install handlers.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


class Interrupted(KeyboardInterrupt):
    """Raised out of a solve that stopped because Ctrl-C was pressed."""


class StopFlag:
    """Set by SIGINT; polled by the solvers."""

    def __init__(self) -> None:
        self._set = threading.Event()

    def set(self) -> None:
        self._set.set()

    def __call__(self) -> bool:
        return self._set.is_set()

    def check(self) -> None:
        """Raise :class:`Interrupted` when set."""
        if self._set.is_set():
            raise Interrupted()


@contextmanager
def interruptible() -> Iterator[StopFlag]:
    """A :class:`StopFlag` that SIGINT sets for the duration of the block (see the module docstring)."""
    flag = StopFlag()
    usable = threading.current_thread() is threading.main_thread() and \
        signal.getsignal(signal.SIGINT) is signal.default_int_handler
    if not usable:
        yield flag
        return
    previous = signal.signal(signal.SIGINT, lambda *_: flag.set())
    try:
        yield flag
    finally:
        signal.signal(signal.SIGINT, previous)
    flag.check()
