"""One flight per link on this host: an advisory lock per module link, held while a backend is connected.

A second ``fly`` (or ``params``) against links another process holds is refused before it sends anything: its
preflight would otherwise stream zero commands into modules that are flying for the first. The lock is an
``flock`` on a file per link in the user's runtime directory; the kernel releases it when the holder exits,
however it exits, so a crashed flight never leaves a stale lock. Ground stations on other hosts are kept off by
the module itself (the motor app's owner, contract 3).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import tempfile
from pathlib import Path

from groundstation.errors import LinkError


def lock_dir() -> Path:
    """``$XDG_RUNTIME_DIR/groundstation-links`` (per user, cleared at logout), else the temp dir."""
    base = os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return Path(base) / f"groundstation-links-{os.getuid()}"


class LinkLocks:
    """Locks for a set of link URIs, taken together (all or none)."""

    def __init__(self, uris) -> None:
        self.uris = tuple(uris)
        self._files: list = []

    @staticmethod
    def _path(uri: str) -> Path:
        return lock_dir() / (hashlib.sha256(uri.strip().lower().encode()).hexdigest()[:32] + ".lock")

    def acquire(self) -> None:
        """Take every link's lock; raises :class:`LinkError` naming the link and the holder's pid if one is held."""
        lock_dir().mkdir(mode=0o700, parents=True, exist_ok=True)
        try:
            for uri in dict.fromkeys(self.uris):  # a link listed twice is the preflight's business, not a lock's
                fh = open(self._path(uri), "a+")  # noqa: SIM115 - held open while the link is in use
                try:
                    fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    fh.seek(0)
                    holder = fh.read().strip() or "unknown"
                    fh.close()
                    raise LinkError(f"{uri.strip()} is in use by another flight on this host (pid {holder}); one "
                                    f"flight owns a module set") from None
                fh.seek(0)
                fh.truncate()
                fh.write(str(os.getpid()))
                fh.flush()
                self._files.append(fh)
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        for fh in self._files:
            with contextlib.suppress(OSError):
                fh.close()  # closing drops the flock
        self._files = []
