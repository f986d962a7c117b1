"""Operator keys during a flight: ``k`` stops the motors at once, ``l`` lands.

Active only when stdin is a terminal; the terminal is put in cbreak mode (keys arrive without Enter, Ctrl-C still
raises SIGINT) and always restored.
"""

from __future__ import annotations

import os
import select
import sys
import threading

from groundstation.runtime.flight import Requests

KILL_KEYS = "kK"
LAND_KEYS = "lL"


class KeyReader:
    def __init__(self, requests: Requests, stream=None) -> None:
        self._requests = requests
        self._stream = stream or sys.stdin
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._saved = None

    def __enter__(self) -> KeyReader:
        if not self._stream.isatty():
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
            ready, _, _ = select.select([fd], [], [], 0.1)
            if not ready:
                continue
            key = os.read(fd, 1).decode(errors="ignore")
            if key in KILL_KEYS:
                self._requests.stop.set()
            elif key in LAND_KEYS:
                self._requests.land.set()

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._saved is not None:
            import termios

            termios.tcsetattr(self._stream.fileno(), termios.TCSADRAIN, self._saved)
