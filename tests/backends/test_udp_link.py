"""The stamped UDP link against plain loopback sockets: cflib's wire, the kernel's arrival time, errors once."""

import socket
import time

import pytest
from cflib.crtp.crtpstack import CRTPPacket
from cflib.crtp.udpdriver import UdpDriver

from groundstation.backends.udp_link import StampedUdpLink


def _server() -> tuple[socket.socket, str]:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(2.0)
    return s, f"udp://127.0.0.1:{s.getsockname()[1]}"


def test_datagrams_are_cflibs_wire():
    server, uri = _server()
    ours, theirs = StampedUdpLink(uri, print), UdpDriver()
    theirs.connect(uri, None, print)
    try:
        pk = CRTPPacket(0x3E, bytes(range(30)))
        got = []
        for link in (ours, theirs):
            link.send_packet(pk)
            got.append(server.recvfrom(64))
        assert got[0][0] == got[1][0] == bytes([0x3E]) + bytes(range(30))
        server.sendto(b"", got[0][1])  # empty, and longer than any CRTP packet: not packets, dropped
        server.sendto(bytes(33), got[0][1])
        server.sendto(b"\x2c\x01\x02", got[0][1])  # an answer to our link
        deadline = time.monotonic() + 2.0
        while (answer := ours.receive()) is None and time.monotonic() < deadline:
            time.sleep(0.001)
        assert answer is not None
        assert (answer[0].header, bytes(answer[0].data)) == (0x2C, b"\x01\x02")
        assert ours.receive() is None  # nothing else waits; the read never blocks
    finally:
        ours.close()
        theirs.close()
        server.close()


def test_the_arrival_is_the_kernels_not_the_read():
    """A state that waited in the socket while the loop was busy keeps its arrival time: a slow reader is not a
    slow link."""
    server, uri = _server()
    link = StampedUdpLink(uri, print)
    try:
        assert link.stamped
        link.send_packet(CRTPPacket(0xFF, b""))
        _, addr = server.recvfrom(64)
        _until_the_kernel_stamps(link, server, addr)
        sent = time.monotonic()
        server.sendto(b"\x2c\x07", addr)
        time.sleep(0.2)  # the reader is busy; the datagram waits in the kernel
        read = time.monotonic()
        got = link.receive()
        assert got is not None and bytes(got[0].data) == b"\x07", got
        arrival = got[1]
        # The stamp lies between the send and the read, and the 0.2 s the datagram waited are not in it. (One-sided
        # bounds: a loaded machine only lengthens the sleep.) 1 ms allows for the realtime-to-monotonic offset.
        assert sent - 1e-3 <= arrival <= read - 0.19, (sent, arrival, read)
    finally:
        link.close()
        server.close()


def _until_the_kernel_stamps(link: StampedUdpLink, server: socket.socket, addr) -> None:
    """Linux turns arrival stamping on for the first socket that asks from a work queue, a moment later; a
    datagram arriving before that is stamped when it is read (CI: the arrival was the read, 0.2 s late). A link
    opens seconds before a flight reads it; this test waits for the same."""
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        server.sendto(b"\x2c\x00", addr)
        time.sleep(0.05)
        read = time.monotonic()
        got = link.receive()
        if got is not None and got[1] <= read - 0.04:
            return
    raise AssertionError("the kernel never stamped an arrival in 5 s")


def test_a_closed_port_is_reported_once_and_reading_goes_on():
    server, uri = _server()
    server.close()  # nobody listens: each send draws an ICMP port unreachable
    errors = []
    link = StampedUdpLink(uri, errors.append)
    try:
        for _ in range(20):
            link.send_packet(CRTPPacket(0x3E, b"\x00"))
            time.sleep(0.005)
            assert link.receive() is None
        assert errors == ["UDP link: [Errno 111] Connection refused"]
    finally:
        link.close()


def test_not_a_udp_uri():
    with pytest.raises(ValueError, match="not a udp://host:port URI: 'radio://0/80/2M'"):
        StampedUdpLink("radio://0/80/2M", print)
    with pytest.raises(ValueError, match="not a udp://host:port URI"):
        StampedUdpLink("udp://127.0.0.1", print)


def test_a_closed_link_neither_reads_nor_sends():
    server, uri = _server()
    errors = []
    link = StampedUdpLink(uri, errors.append)
    link.close()
    try:
        assert link.receive() is None and link.receive_packet(0) is None  # returns (it once spun on EBADF)
        link.send_packet(CRTPPacket(0x3E, b"\x00"))
        assert errors == []
    finally:
        server.close()


def test_a_preemption_between_the_clock_reads_does_not_move_the_arrival(monkeypatch):
    """The realtime-to-monotonic offset is read again when the thread lost its CPU between two clock reads (the
    first realtime read here comes 50 ms late, as when a host takes the CPU away)."""
    server, uri = _server()
    link = StampedUdpLink(uri, print)
    try:
        link.send_packet(CRTPPacket(0xFF, b""))
        _, addr = server.recvfrom(64)
        sent = time.monotonic()
        server.sendto(b"\x2c\x07", addr)
        time.sleep(0.01)
        real_time, late = time.time, [True]

        def preempted() -> float:
            if late.pop() if late else False:
                time.sleep(0.05)
            return real_time()

        monkeypatch.setattr(time, "time", preempted)
        got = link.receive()
        monkeypatch.undo()
        assert got is not None and got[1] >= sent - 1e-3, (sent, got)  # 50 ms early had the late read counted
    finally:
        link.close()
        server.close()
