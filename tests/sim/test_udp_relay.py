"""The fault relay on loopback sockets: what it forwards, and the TIMESYNC answers it forges in a module's name."""

import socket
import threading
import time

from pymavlink import mavutil

from sim.udp_relay import Faults, UdpRelay


def _socket(port: int = 0) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    s.settimeout(2.0)
    return s


def _messages(data: bytes):
    parser = mavutil.mavlink.MAVLink(None)
    return parser.parse_buffer(data) or []


def test_a_forging_relay_answers_probes_on_the_modules_clock_and_keeps_them_from_it():
    module = _socket()
    target = module.getsockname()[1]
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    listen = probe.getsockname()[1]
    probe.close()  # a free port for the relay's front
    relay = UdpRelay(listen, target, 1, Faults(answer_timesync=True))
    th = threading.Thread(target=relay.run, daemon=True)
    th.start()
    gs = _socket()
    as_gs = mavutil.mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    as_module = mavutil.mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
    try:
        heartbeat = as_gs.heartbeat_encode(6, 8, 0, 0, 4).pack(as_gs)
        gs.sendto(heartbeat, ("127.0.0.1", listen))
        data, back = module.recvfrom(512)
        assert data == heartbeat  # relayed, and now the relay knows where the ground station is
        gs.sendto(as_gs.timesync_encode(0, 111).pack(as_gs), ("127.0.0.1", listen))
        assert module.recvfrom(512)[0]  # the module's clock unknown yet: the probe goes through
        module.sendto(as_module.attitude_encode(5000, 0, 0, 0, 0, 0, 0).pack(as_module), back)
        assert _messages(gs.recvfrom(512)[0])[0].get_type() == "ATTITUDE"
        time.sleep(0.1)
        gs.sendto(as_gs.timesync_encode(0, 222).pack(as_gs), ("127.0.0.1", listen))
        (answer,) = _messages(gs.recvfrom(512)[0])
        # In the module's name, on its clock (5 s at the ATTITUDE, 0.1 s on: ms, as ns), the probe named
        assert (answer.get_type(), answer.get_srcSystem(), answer.get_srcComponent(), answer.ts1) == ("TIMESYNC", 7, 1,
                                                                                                   222)
        assert 5.1e9 <= answer.tc1 < 5.6e9, answer.tc1
        module.settimeout(0.2)
        try:
            got = module.recvfrom(512)[0]
        except TimeoutError:
            got = None
        assert got is None and relay.counts.answered == 1  # kept from the module
    finally:
        relay.stop()
        th.join(2)
        for s in (module, gs):
            s.close()
