"""Silence C-level writes to stdout (file descriptor 1) for the duration of a block."""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager


@contextmanager
def quiet_stdout():
    sys.stdout.flush()
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # no real stdout (e.g. captured by a test runner)
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
