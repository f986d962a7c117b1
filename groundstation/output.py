"""Writing a command's output files: a write that fails (a full disk, a read-only or vanished directory) is one line
naming the file, not a traceback.

``writable_output`` checks a path before any work is done; a disk can still fill up while the file is written, and
the ``OSError`` raised then (``ENOSPC``, often from a buffered flush or ``close`` that does not name the file) would
reach the operator as a traceback. These wrap the writes of the commands' writers.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from groundstation.errors import UsageError


def descriptor_open(fd: int) -> bool:
    """Whether file descriptor ``fd`` is open."""
    try:
        os.fstat(fd)
    except OSError:
        return False
    return True


def hold_standard_descriptors() -> None:
    """Put /dev/null on each of descriptors 0-2 that is closed (``>&-``, ``2>&-``, ``0<&-``), for the process's life:
    the next file opened would otherwise be given it, and what is written to stdout or stderr (a C library's
    messages, the summary) would land in it (a flight's log). Python's ``sys.stdout`` and ``sys.stderr`` stay
    None, so the commands still know there is nobody to tell."""
    for fd in (0, 1, 2):
        if not descriptor_open(fd):
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)


@contextmanager
def writing(path: str | Path) -> Iterator[None]:
    """Turn an ``OSError`` raised inside into a :class:`UsageError` naming ``path`` (one line, exit status 2, as for
    an output path that is not writable in the first place)."""
    try:
        yield
    except OSError as exc:
        raise UsageError(f"{path}: cannot write: {exc.strerror or exc}") from None


def save_figure(fig, path: str | Path, **savefig_kwargs) -> Path:
    """Save a matplotlib figure to ``path`` and close it, also when the write fails (see :func:`writing`)."""
    import matplotlib.pyplot as plt

    out = Path(path)
    try:
        with writing(out):
            fig.savefig(out, **savefig_kwargs)
    finally:
        plt.close(fig)
    return out
