"""Ctrl-C for design work that runs in compiled code: inside Ipopt, and in the enumeration's numba kernels.

CasADi checks for signals during a solve and swallows SIGINT: a sweep ran on to its end after Ctrl-C. Inside
:func:`interruptible`, SIGINT only sets a flag; solvers poll it every iteration (an Ipopt iteration callback) and
between solves, and the context raises ``KeyboardInterrupt`` when the work stops. It takes effect only in the main
thread and only where SIGINT has Python's default handler: worker processes of a sweep ignore SIGINT (their
parent stops them) and Dask worker threads cannot install handlers.

numba's compiled code does not look at signals at all: Python runs the SIGINT handler only once a kernel returns
(a level of ``enumerate 13`` runs 20 s), and the ``KeyboardInterrupt`` it raises then surfaces inside numba's
dispatcher as a ``SystemError`` traceback. :func:`run_interruptible` runs such a kernel on a worker thread.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

T = TypeVar("T")


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


def run_interruptible(fn: Callable[..., T], *args) -> T:
    """``fn(*args)`` run on a daemon worker thread while the calling thread waits; for numba kernels compiled with
    ``nogil=True`` (and numba's compilation, which releases the GIL between bytecodes), which never return to
    the interpreter on their own.

    The wait is a lock acquisition, which a signal interrupts: Ctrl-C raises ``KeyboardInterrupt`` in the main
    thread at once, not after the kernel. The kernel cannot be stopped from outside: it runs on to its end on the
    abandoned thread, which a process exiting does not wait for (a library caller that goes on pays its CPU time
    until it ends)."""
    result: list = []
    error: list[BaseException] = []
    done = threading.Event()

    def work() -> None:
        try:
            result.append(fn(*args))
        except BaseException as exc:  # handed to the waiting thread
            error.append(exc)
        finally:
            done.set()

    threading.Thread(target=work, name=f"kernel-{getattr(fn, '__name__', 'call')}", daemon=True).start()
    done.wait()
    if error:
        raise error[0]
    return result[0]
