"""A Crazyflie link over UDP (cflib's ``udp://`` wire: one CRTP packet per datagram) that keeps the kernel's
arrival time of every packet.

cflib's own UDP driver reads the socket on a thread of its own and queues the packets. On a busy host that thread
waits for a core and for the GIL, so a state that reached the machine in 1 ms can reach the control loop's poll
10 ms later, and the round trip measured at the poll blamed the link for the host (FITL beside a CPU hog: round
trips 17-22 ms through a firmware that answered in ~1 ms). This link has no thread: the backend's poll reads the
socket directly, and ``SO_TIMESTAMPNS`` gives each datagram's arrival as the kernel saw it. The round trip a
flight checks is then the link's and the module's, and a late host shows as late control periods instead.
"""

from __future__ import annotations

import socket
import struct
import time
from urllib.parse import urlparse

from cflib.crtp.crtpstack import CRTPPacket

SO_TIMESTAMPNS = 35
"""Linux's ``SO_TIMESTAMPNS`` (also the ``SCM_`` control-message type); Python's socket module does not export
it. Where the option is refused the arrival is the read time (as with cflib's driver)."""
_TIMESPEC = struct.Struct("@ll")
MAX_DATAGRAM = 64
"""A CRTP packet is at most 32 bytes; anything longer is not one."""


class StampedUdpLink:
    """One module's ``udp://host:port`` link, read without blocking from the poll that asks.

    ``receive()`` returns the next packet with its arrival time on ``clock`` (s), or None when none is waiting.
    ``send_packet`` and ``close`` are cflib's driver calls; errors (the peer's port closed) go to ``on_error``
    once per kind, not per datagram."""

    def __init__(self, uri: str, on_error, clock=time.monotonic) -> None:
        parsed = urlparse(uri)
        if parsed.scheme != "udp" or parsed.hostname is None or parsed.port is None:
            raise ValueError(f"not a udp://host:port URI: {uri!r}")
        self.uri = uri
        self._on_error = on_error
        self._clock = clock
        self._reported: set[str] = set()
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.socket.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
            self.stamped = True
            """The kernel stamps arrivals (False: the read time stands in)."""
        except OSError:
            self.stamped = False
        self.socket.connect((parsed.hostname, parsed.port))
        self.socket.setblocking(False)
        self._ancillary = socket.CMSG_SPACE(_TIMESPEC.size)

    def send_packet(self, pk: CRTPPacket) -> None:
        try:
            self.socket.send(bytes([pk.header]) + bytes(pk.data))
        except OSError as exc:  # no route, the peer's port closed (ICMP), a full buffer: the packet is lost
            self._error(exc)

    def receive(self) -> tuple[CRTPPacket, float] | None:
        """The next waiting packet and when it arrived (s, on the link's clock); None if none waits."""
        while True:
            try:
                data, ancdata, _, _ = self.socket.recvmsg(MAX_DATAGRAM, self._ancillary)
            except (BlockingIOError, InterruptedError):
                return None
            except OSError as exc:  # ECONNREFUSED from an earlier send: reported, and the socket reads on
                self._error(exc)
                continue
            if not data:
                continue
            arrival = self._arrival(ancdata)
            return CRTPPacket(data[0], data[1:]), arrival

    def receive_packet(self, wait: float = 0) -> CRTPPacket | None:
        """cflib's driver call (never waits): the next packet, without its arrival."""
        got = self.receive()
        return got[0] if got is not None else None

    def close(self) -> None:
        self.socket.close()

    def _arrival(self, ancdata) -> float:
        for level, kind, payload in ancdata:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(payload) >= _TIMESPEC.size:
                sec, nsec = _TIMESPEC.unpack_from(payload)
                # The stamp is on the realtime clock; the offset to ``clock`` is taken now (microseconds apart).
                return sec + nsec * 1e-9 - (time.time() - self._clock())
        return self._clock()

    def _error(self, exc: OSError) -> None:
        kind = type(exc).__name__
        if kind not in self._reported:
            self._reported.add(kind)
            self._on_error(f"UDP link: {exc}")
