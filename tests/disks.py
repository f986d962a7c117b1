"""Disks that are full, for the tests of every writer: a path that is ``/dev/full`` (every write fails with
ENOSPC) and a tiny tmpfs (a real file system that fills up part way through a file; mounting needs root)."""

from __future__ import annotations

import contextlib
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest


def full(path: Path) -> Path:
    """``path`` made a link to ``/dev/full``. Only for files a command writes and never reads: reading
    ``/dev/full`` never ends."""
    path.symlink_to("/dev/full")
    return path


@contextlib.contextmanager
def tiny_disk(where: Path, size: str = "64k") -> Iterator[Path]:
    """A tmpfs of ``size`` mounted at ``where`` (the test is skipped where mounting is not allowed)."""
    where.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                                           capture_output=True).returncode != 0:
        pytest.skip("mounting a tmpfs needs root (and a container that allows it)")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], capture_output=True)
