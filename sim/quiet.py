"""Silence C-level writes to stderr for the duration of a block (pybullet's import banner; C's stderr is
unbuffered, so nothing is left to flush afterwards)."""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager

from groundstation.output import descriptor_open


@contextmanager
def quiet_stderr():
    """C-level stderr goes to /dev/null within the block. With no stderr at all (``2>&-``: Python's
    ``sys.stderr`` is None, file descriptor 2 closed) /dev/null is put on descriptor 2 for good: a file opened
    later (a flight's log) would otherwise be given descriptor 2, and a C library's messages written into it."""
    if sys.stderr is not None:
        sys.stderr.flush()
    if not descriptor_open(2):
        devnull = os.open(os.devnull, os.O_WRONLY)
        if devnull != 2:
            os.dup2(devnull, 2)
            os.close(devnull)
        yield
        return
    try:
        fd = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):  # no real stderr (e.g. captured by a test runner)
        yield
        return
    saved = os.dup(fd)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)
        os.close(devnull)
