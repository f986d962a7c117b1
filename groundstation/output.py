"""Writing a command's output files: a write that fails (a full disk, a read-only or vanished directory) is one line
naming the file, not a traceback.

``writable_output`` checks a path before any work is done; a disk can still fill up while the file is written, and
the ``OSError`` raised then (``ENOSPC``, often from a buffered flush or ``close`` that does not name the file) would
reach the operator as a traceback. These wrap the writes of the commands' writers.
"""

from __future__ import annotations

import errno
import os
import sys
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


class StdoutError(OSError):
    """What a command prints did not reach stdout: closed (``>&-``), a full device, a pipe whose reader went."""


class GuardedStdout:
    """``sys.stdout`` of a command's process: a write or flush that fails raises :class:`StdoutError`, so the command
    line tells that failure (one line on stderr, exit 1: ``simulate > /dev/full`` ended in a traceback) from any other
    ``OSError``, which is a fault to see whole. Everything else is the stream's. Descriptor 1 closed, every write
    fails (Python leaves ``sys.stdout`` None then, and click and rich drop what is printed to None without a word:
    ``simulate``, ``enumerate``, ``--help`` printed nothing and exited 0)."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self._failed = None if stream is not None else StdoutError(errno.EBADF, "stdout is closed")
        """The failure, kept: every later write fails with it (click's probe of the stream swallows the first)."""

    def write(self, text: str) -> int:
        self._check()
        try:
            return self._stream.write(text)
        except OSError as exc:
            self._give_up(exc)
            raise self._failed from None

    def flush(self) -> None:
        if self._stream is None:  # closed: nothing was written (every write failed)
            return
        self._check()
        try:
            self._stream.flush()
        except OSError as exc:
            self._give_up(exc)
            raise self._failed from None

    def _check(self) -> None:
        if self._failed is not None:
            raise self._failed

    def isatty(self) -> bool:
        return self._stream is not None and self._stream.isatty()

    def __getattr__(self, name: str):
        return getattr(self._stream, name)

    def _give_up(self, exc: OSError) -> None:
        """Keep the failure, and put descriptor 1 on /dev/null: what is left in the buffer would fail again in
        Python's flush at exit (a traceback of its own)."""
        self._failed = StdoutError(exc.errno, exc.strerror or str(exc))
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 1)
        os.close(null)


class QuietStderr:
    """``sys.stderr`` of a command's process: a write or flush that fails (a full device, a pipe gone) is dropped,
    and so is everything after it. Stderr carries the diagnostics; losing them must not change what the command
    does or its exit status (on a full stderr, bad input exited 1 with an unseen traceback instead of 2, and
    ``replay`` printed nothing on stdout: hostile campaign 30)."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self._lost = False

    def write(self, text: str) -> int:
        if not self._lost:
            try:
                return self._stream.write(text)
            except OSError:
                self._give_up()
        return len(text)

    def flush(self) -> None:
        if not self._lost:
            try:
                self._stream.flush()
            except OSError:
                self._give_up()

    def isatty(self) -> bool:
        return not self._lost and self._stream.isatty()

    def __getattr__(self, name: str):
        return getattr(self._stream, name)

    def _give_up(self) -> None:
        """Descriptor 2 onto /dev/null: the buffer's rest would fail again at exit, and so would a C library."""
        self._lost = True
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)


def stdout_lost() -> None:
    """Stdout failed and the command said so on stderr: from here what is printed goes to /dev/null (Python's own
    flush at exit would fail once more, with a traceback and status 120). Only the command line's own stdout
    (:func:`hold_standard_descriptors`): an in-process caller's is its own."""
    if isinstance(sys.stdout, GuardedStdout):
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (the process's, to its end)


def hold_standard_descriptors() -> None:
    """Put /dev/null on each of descriptors 0-2 that is closed (``>&-``, ``2>&-``, ``0<&-``), for the process's life:
    the next file opened would otherwise be given it, and what is written to stdout or stderr (a C library's
    messages, the summary) would land in it (a flight's log); and guard stdout (:class:`GuardedStdout`).
    ``sys.stderr`` closed stays None (nobody is told anything)."""
    for fd in (0, 1, 2):
        if not descriptor_open(fd):
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
    sys.stdout = GuardedStdout(sys.stdout)
    if sys.stderr is not None:
        sys.stderr = QuietStderr(sys.stderr)


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
