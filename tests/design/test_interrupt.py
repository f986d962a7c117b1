"""Ctrl-C reaches the main thread while compiled code that never checks for signals runs on a worker thread."""

import os
import signal
import threading

import pytest
from numba import njit

from groundstation.design.interrupt import run_interruptible


@njit(nogil=True)
def spin(n: int, started) -> int:
    """A numba kernel that runs ``n`` steps of a generator LLVM cannot shortcut, looking at no signal."""
    started[0] = 1
    x = 1
    for _ in range(n):
        x = (x * 6364136223846793005 + 1442695040888963407) & 0x7FFFFFFFFFFFFFFF
    return x


def test_returns_the_result_and_raises_the_error():
    assert run_interruptible(divmod, 7, 2) == (3, 1)
    with pytest.raises(ZeroDivisionError):
        run_interruptible(divmod, 1, 0)


@pytest.fixture
def python_sigint():
    """Python's own SIGINT handler, as a command starts with (an earlier test in this process may have left
    another, e.g. a flight's), restored afterwards."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_sigint_raises_in_the_caller_while_the_kernel_runs(python_sigint):
    import numpy as np

    started = np.zeros(1, np.int64)
    spin(10, started)  # compiled before the clock matters
    started[0] = 0

    def interrupt():
        while not started[0]:
            threading.Event().wait(0.01)
        os.kill(os.getpid(), signal.SIGINT)

    sender = threading.Thread(target=interrupt)
    sender.start()
    with pytest.raises(KeyboardInterrupt):
        run_interruptible(spin, 3_000_000_000, started)  # seconds of work
    running = [t for t in threading.enumerate() if t.name == "kernel-spin"]
    sender.join()
    assert running and running[0].is_alive()  # the interrupt came while the kernel ran, not after it
