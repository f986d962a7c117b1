"""Run Python in a network namespace of its own: ``python tests/own_network.py ARGS...`` is ``python ARGS...``
with a private loopback interface.

The parallel test workers (``pytest -n 2``, see ``conftest.py``) start through it. The tests bind fixed loopback
ports (a mocap router at 7448, simulated modules at 19850, ...) and take the host lock of each module link they
fly, as operators' flights do; two workers sharing one loopback would take each other's ports and links. In a
namespace each worker has 127.0.0.1 to itself, and nothing of one worker's traffic can reach the other's (its link
locks are its own too: ``conftest.py``).

Needs root, or unprivileged user namespaces (the default on Debian and Fedora); ``available()`` says whether this
machine allows it, and the tests then run in one worker.
"""

from __future__ import annotations

import ctypes
import fcntl
import os
import socket
import struct
import subprocess
import sys

CLONE_NEWUSER = 0x10000000
CLONE_NEWNET = 0x40000000
SIOCSIFFLAGS = 0x8914
IFF_UP, IFF_LOOPBACK, IFF_RUNNING = 0x1, 0x8, 0x40


def _enter() -> None:
    """Unshare the network namespace (and, without root, a user namespace that maps us to ourselves: no
    privilege beyond our own once Python is exec'd again), then bring its loopback up."""
    libc = ctypes.CDLL(None, use_errno=True)
    uid, gid = os.getuid(), os.getgid()
    flags = CLONE_NEWNET if os.geteuid() == 0 else CLONE_NEWNET | CLONE_NEWUSER
    if libc.unshare(flags) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"unshare: {os.strerror(err)}")
    if flags & CLONE_NEWUSER:
        for name, text in (("setgroups", "deny"), ("uid_map", f"{uid} {uid} 1"), ("gid_map", f"{gid} {gid} 1")):
            with open(f"/proc/self/{name}", "w") as fh:
                fh.write(text)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        fcntl.ioctl(s, SIOCSIFFLAGS, struct.pack("16sH14x", b"lo", IFF_UP | IFF_LOOPBACK | IFF_RUNNING))


def available() -> bool:
    """Whether this machine lets us run Python in a namespace of its own (tried in a child process)."""
    probe = [sys.executable, __file__, "-c", "import socket; socket.create_server(('127.0.0.1', 0)).close()"]
    return subprocess.run(probe, capture_output=True, timeout=60).returncode == 0


def main() -> None:
    _enter()
    os.execv(sys.executable, [sys.executable, *sys.argv[1:]])


if __name__ == "__main__":
    main()
