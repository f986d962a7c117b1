"""The operator's terminal going away under a running flight.

After a hang-up (an SSH connection dropped, a terminal window closed) the kernel fails every write to the terminal
with EIO. The flight lands on its own and its summary is in the log, but the status line's last redraw and the
summary's printing would end the command in a traceback and exit 1 after a safe landing. Pointing the lost
terminal's descriptors at ``/dev/null`` keeps the exit status the flight's.
"""

from __future__ import annotations

import errno
import os

STANDARD_FDS = (0, 1, 2)


def terminal_lost(fd: int) -> bool:
    """True if ``fd`` is a terminal that has hung up: a write of no bytes fails with EIO only there (on a live
    terminal, a file or a pipe it writes nothing and succeeds; a closed descriptor fails with EBADF)."""
    try:
        os.write(fd, b"")
    except OSError as exc:
        return exc.errno == errno.EIO
    return False


def forget_lost_terminal(fds: tuple[int, ...] = STANDARD_FDS) -> tuple[int, ...]:
    """Point each of ``fds`` whose terminal hung up at ``/dev/null`` (reads see end of file, writes vanish); return
    the descriptors replaced. Safe to call from a signal handler of the main thread and more than once."""
    lost = tuple(fd for fd in fds if terminal_lost(fd))
    if lost:
        null = os.open(os.devnull, os.O_RDWR)
        try:
            for fd in lost:
                os.dup2(null, fd)
        finally:
            os.close(null)
    return lost
