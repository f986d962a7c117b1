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

import math
import socket
import struct
import time
from urllib.parse import urlparse

from cflib.crtp.crtpstack import CRTPPacket

SO_TIMESTAMPNS = 35
"""Linux's ``SO_TIMESTAMPNS`` (also the ``SCM_`` control-message type); Python's socket module does not export
it. Where the option is refused the arrival is the read time (an upper bound: it includes the wait for the
poll)."""
_TIMESPEC = struct.Struct("@ll")
OFFSET_READS, OFFSET_GAP_S = 5, 20e-6
"""Realtime-to-clock offset: up to this many read triples, until two clock reads lie this close (s)."""
MAX_PACKET = 32
"""Bytes of the longest CRTP packet (header and payload); a longer datagram is not one and is dropped."""


class StampedUdpLink:
    """One module's ``udp://host:port`` link, read without blocking from the poll that asks.

    ``receive()`` returns the next packet with its arrival time on ``clock`` (s), or None when none is waiting.
    ``send_packet`` and ``close`` are cflib's driver calls; errors (the peer's port closed) go to ``on_error``
    once per kind for the link's life, not per datagram. After ``close`` it receives nothing and sends nothing."""

    def __init__(self, uri: str, on_error, clock=time.monotonic) -> None:
        parsed = urlparse(uri)
        if parsed.scheme != "udp" or parsed.hostname is None or parsed.port is None:
            raise ValueError(f"not a udp://host:port URI: {uri!r}")
        self.uri = uri
        self._on_error = on_error
        self._clock = clock
        self._reported: set[str] = set()
        self._closed = False
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            try:
                self.socket.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                self.stamped = True
                """The kernel stamps arrivals (False: the read time stands in)."""
            except OSError:
                self.stamped = False
            self.socket.connect((parsed.hostname, parsed.port))  # a connected socket takes datagrams from it only
            self.socket.setblocking(False)
        except OSError:  # an unknown host, an address of another family: the socket is not left open
            self.socket.close()
            raise
        self._ancillary = socket.CMSG_SPACE(_TIMESPEC.size)

    def send_packet(self, pk: CRTPPacket) -> None:
        if self._closed:
            return
        try:
            self.socket.send(bytes([pk.header]) + bytes(pk.data))
        except OSError as exc:  # no route, the peer's port closed (ICMP), a full buffer: the packet is lost
            self._error(exc)

    def receive(self) -> tuple[CRTPPacket, float] | None:
        """The next waiting packet and when it arrived (s, on the link's clock); None if none waits."""
        while not self._closed:
            try:
                data, ancdata, flags, _ = self.socket.recvmsg(MAX_PACKET, self._ancillary)
            except (BlockingIOError, InterruptedError):
                return None
            except ConnectionRefusedError as exc:  # from an earlier send (ICMP): reported, and the socket reads on
                self._error(exc)
                continue
            except OSError as exc:  # anything else will not go away by reading again
                self._error(exc)
                return None
            if not data or flags & socket.MSG_TRUNC:  # empty, or longer than any CRTP packet
                continue
            return CRTPPacket(data[0], data[1:]), self._arrival(ancdata)
        return None

    def receive_packet(self, wait: float = 0) -> CRTPPacket | None:
        """cflib's driver call (never waits): the next packet, without its arrival."""
        got = self.receive()
        return got[0] if got is not None else None

    def close(self) -> None:
        self._closed = True
        self.socket.close()

    def _arrival(self, ancdata) -> float:
        now = self._clock()
        for level, kind, payload in ancdata:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(payload) >= _TIMESPEC.size:
                sec, nsec = _TIMESPEC.unpack_from(payload)
                # The stamp is on the realtime clock. A step of that clock between the stamp and now would move
                # it: never later than now (the read's own bound).
                return min(sec + nsec * 1e-9 - self._realtime_offset(), now)
        return now

    def _realtime_offset(self) -> float:
        """``time.time()`` minus ``clock``, s, from reads a few microseconds apart: a preemption between two reads
        (a host taking the CPU for 100 ms) would shift the arrival by its length (seen: a test failing 1 in 10)."""
        best_gap, offset = math.inf, 0.0
        for _ in range(OFFSET_READS):
            before = self._clock()
            real = time.time()
            after = self._clock()
            if after - before < best_gap:
                best_gap, offset = after - before, real - (before + after) / 2
            if best_gap < OFFSET_GAP_S:
                break
        return offset

    def _error(self, exc: OSError) -> None:
        kind = type(exc).__name__
        if kind not in self._reported:
            self._reported.add(kind)
            self._on_error(f"UDP link: {exc}")
