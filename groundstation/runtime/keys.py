"""Operator keys during a flight: ``k`` stops the motors at once, ``l`` lands.

Active only when stdin is a terminal (closed, absent or redirected stdin: the flight runs without keys); the
terminal is put in cbreak mode (keys arrive without Enter, Ctrl-C still raises SIGINT) and always restored. A
terminal that goes away (end of file, a read error) ends the reader, not the flight.
"""

from __future__ import annotations

import errno
import os
import select
import sys
import threading

from groundstation.runtime.flight import Requests
from groundstation.runtime.terminal import terminal_lost

KILL_KEYS = "kK"
LAND_KEYS = "lL"
BACKGROUND_RETRY_S = 0.2
"""How often a reader refused by a terminal it is in the background of tries again, s."""


class KeyReader:
    def __init__(self, requests: Requests, stream=None) -> None:
        self._requests = requests
        self._stream = stream or sys.stdin
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._saved = None

    def _interactive(self) -> bool:
        try:
            return self._stream is not None and self._stream.isatty()
        except (ValueError, OSError):  # a closed stream
            return False

    def __enter__(self) -> KeyReader:
        if not self._interactive():
            return self
        import termios
        import tty

        fd = self._stream.fileno()
        self._saved = termios.tcgetattr(fd)
        tty.setcbreak(fd)
        self._thread = threading.Thread(target=self._run, args=(fd,), name="operator-keys", daemon=True)
        self._thread.start()
        return self

    def _run(self, fd: int) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([fd], [], [], 0.1)
                if not ready:
                    continue
                data = os.read(fd, 1)
            except OSError as exc:
                if exc.errno != errno.EIO or terminal_lost(fd):
                    return  # the terminal went away
                # A live terminal answers EIO to a read from a background process group (SIGTTIN is ignored in
                # flight): Ctrl-Z stopped a wrapper script and its shell resumed it behind another job. Keys
                # work again after `fg`.
                self._stop.wait(BACKGROUND_RETRY_S)
                continue
            if not data:
                return  # end of file: no more keys (and no busy loop on a readable EOF)
            key = data.decode(errors="ignore")
            if key in KILL_KEYS:
                self._requests.stop.set()
            elif key in LAND_KEYS:
                self._requests.land.set()

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._saved is not None:
            import contextlib
            import termios

            with contextlib.suppress(OSError, ValueError, termios.error):  # the terminal may be gone (hang-up)
                termios.tcsetattr(self._stream.fileno(), termios.TCSADRAIN, self._saved)
