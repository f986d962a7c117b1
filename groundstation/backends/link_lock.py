"""One flight per link on this host: an advisory lock per module link, held while a backend is connected.

A second ``fly`` (or ``params``) against links another process holds is refused before it sends anything: its
preflight would otherwise stream zero commands into modules that are flying for the first. The lock is an
``flock`` on a file per link in ``/tmp/groundstation-links-<uid>`` (:func:`lock_dir`); the kernel releases it when
the holder exits, however it exits, so a crashed flight never leaves a stale lock. Ground stations on other hosts
are kept off by the module itself (the motor app's owner, contract 3).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import ipaddress
import os
import re
import socket
import stat
from pathlib import Path

from groundstation.errors import LinkError

_NETWORK = re.compile(r"^(?:udp|udpin|udpout|udpbcast|tcp|tcpin)(?::|://)(?:\[(?P<v6>[^\]]*)\]|(?P<host>[^:/]*)):"
                      r"(?P<port>\d+)")
_RADIO = re.compile(r"^radio://[^/]*/(?P<channel>\d+)(?:/[^/]*(?:/(?P<address>[0-9a-f]+))?)?")


def link_key(uri: str) -> str:
    """What a link reaches, however it is spelled: ``udp://localhost:19850/1`` and ``UDP://127.0.0.1:19850`` are one
    module (a second flight spelling its links another way passed the lock: hostile campaign 30); a radio link is
    its channel and address, whichever dongle carries it; a serial device its real path."""
    raw = uri.strip()
    u = raw.lower()
    if m := _RADIO.match(u):
        return f"radio:{int(m['channel'])}:{(m['address'] or 'e7e7e7e7e7').lstrip('0') or '0'}"
    if m := _NETWORK.match(u):
        return f"ip:{_address(m['v6'] if m['v6'] is not None else m['host'])}:{int(m['port'])}"
    device = raw.split(",")[0].split(":")[0]
    if device.startswith("/") or os.path.exists(device):
        return f"serial:{os.path.realpath(device)}"
    return u


def _address(host: str) -> str:
    """The address a link's host name or number reaches, as the link resolves it (``vm`` from /etc/hosts, ``127.1``,
    ``0x7f000001``, ``2130706433`` are all 127.0.0.1: spelled so, they passed the lock, hostile campaign 31); every
    loopback and the unspecified address (which reaches this host) are one: a module served here may listen on
    any of them, and so is an address of one of this host's own interfaces (a module served here on 0.0.0.0 answers
    on it too: spelled so, it passed the lock, hostile campaign 33)."""
    try:
        found = {info[4][0] for info in socket.getaddrinfo(host.rstrip(".") or "localhost", None,
                                                          proto=socket.IPPROTO_UDP)}
    except (OSError, UnicodeError):
        return host  # not a name this host resolves: the link does not open either
    addresses = set()
    for a in found:
        ip = ipaddress.ip_address(a.split("%")[0])
        ip = ip.ipv4_mapped or ip if isinstance(ip, ipaddress.IPv6Address) else ip
        addresses.add("this host" if ip.is_loopback or ip.is_unspecified or _assigned_here(ip) else str(ip))
    return min(addresses)  # a name with several addresses: the link takes the first; any one names it alike


def _assigned_here(ip: ipaddress.IPv4Address | ipaddress.IPv6Address) -> bool:
    """``ip`` is one of this host's own addresses: a socket binds to it only then (no interface list to parse)."""
    family = socket.AF_INET6 if ip.version == 6 else socket.AF_INET
    try:
        with socket.socket(family, socket.SOCK_DGRAM) as s:
            s.bind((str(ip), 0))
    except OSError:
        return False
    return True


LOCK_BASE = Path("/tmp")
"""Where the lock directory lives: fixed, not ``TMPDIR`` or ``XDG_RUNTIME_DIR`` (set otherwise in a second shell,
they put its locks elsewhere, and a second PX4 flight armed the first's modules: hostile campaign 33)."""
OTHER_HOST_ENV = "GROUNDSTATION_OTHER_HOST_LOCKS"
"""A directory named here stands for another host's locks (the tests' second ground station "elsewhere", on this
machine): only this variable, named for what it does, moves them."""


def lock_dir() -> Path:
    """``/tmp/groundstation-links-<uid>``: per user (mode 700)."""
    base = Path(os.environ[OTHER_HOST_ENV]) if os.environ.get(OTHER_HOST_ENV) else LOCK_BASE
    return base / f"groundstation-links-{os.getuid()}"


def _own_lock_dir() -> Path:
    """:func:`lock_dir`, made if missing; refused unless it is a directory (not a link) of this user's that no one
    else may write: its name is known to every account, which could make it first and hold or swap the locks."""
    path = lock_dir()
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = os.lstat(path)
    except OSError as exc:
        raise LinkError(f"cannot make the link lock directory {path}: {exc}") from None
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        raise LinkError(f"the link lock directory {path} is not this user's alone (owner uid {st.st_uid}, mode "
                        f"{stat.S_IMODE(st.st_mode):o}{', a link' if stat.S_ISLNK(st.st_mode) else ''}): remove it")
    return path


class LinkLocks:
    """Locks for a set of link URIs, taken together (all or none)."""

    def __init__(self, uris) -> None:
        self.uris = tuple(uris)
        self._files: list = []

    @staticmethod
    def _path(uri: str) -> Path:
        return lock_dir() / (hashlib.sha256(link_key(uri).encode()).hexdigest()[:32] + ".lock")

    def acquire(self) -> None:
        """Take every link's lock; raises :class:`LinkError` naming the link and the holder's pid if one is held."""
        directory = _own_lock_dir()
        try:
            first: dict[str, str] = {}  # a link listed twice (however spelled) is the preflight's business
            for uri in self.uris:
                first.setdefault(link_key(uri), uri)
            for uri in first.values():
                try:  # never through a link planted in the directory
                    fd = os.open(directory / self._path(uri).name, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW |
                                 os.O_CLOEXEC, 0o600)
                except OSError as exc:
                    raise LinkError(f"cannot lock {uri.strip()}: {exc}") from None
                fh = os.fdopen(fd, "r+")
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
