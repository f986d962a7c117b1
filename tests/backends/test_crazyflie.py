"""The Crazyflie backend through cflib's real UDP link driver, against simulated modules speaking CRTP."""

import struct
import time

import numpy as np
import pytest
from cflib.crtp.crtpstack import CRTPPacket

from groundstation.backends import crtp_wire as wire
from groundstation.backends.crazyflie import CrazyflieBackend, CrazyflieLinkError, CrazyflieSettings
from sim.crazyflie_peer import SimulatedCrazyflies
from tests import peers
from tests.peers import ASM, U_MAX, hold, stop_peer


def start_peer(port: int, mocap_port: int, **kw):
    return peers.start_peer(SimulatedCrazyflies, port, mocap_port, **kw)


def uris(port: int) -> list[str]:
    return [f"udp://127.0.0.1:{port + i}" for i in range(ASM.n)]


def test_wire_format_matches_cflib_and_round_trips():
    pk = CRTPPacket()
    pk.set_header(wire.PORT_PLATFORM, wire.APP_CHANNEL)
    assert pk.header == wire.APP_HEADER
    pk.set_header(wire.PORT_SUPERVISOR, wire.SUPERVISOR_COMMAND_CHANNEL)
    assert pk.header == wire.STOP_HEADER
    assert wire.port_channel(wire.APP_HEADER) == (13, 2)
    cmd = wire.MotorCommand(300, True, (0, 1, 32768, 65535))
    raw = cmd.pack()
    assert len(raw) <= wire.MAX_DATA and raw == struct.pack("<BB4H", 300 % 256, 1, 0, 1, 32768, 65535)
    back = wire.MotorCommand.unpack(raw)
    assert (back.sequence, back.armed, back.counts) == (44, True, (0, 1, 32768, 65535))
    st = wire.ModuleState(7, False, True, (1, 2, 3, 4), 3.9, (0.5, -0.25, 1.0))
    raw = st.pack()
    assert len(raw) <= wire.MAX_DATA
    back = wire.ModuleState.unpack(raw)
    assert (back.sequence, back.armed, back.stopped, back.counts) == (7, False, True, (1, 2, 3, 4))
    assert back.battery_v == pytest.approx(3.9, rel=1e-6) and back.gyro == (0.5, -0.25, 1.0)
    with pytest.raises(ValueError):
        wire.MotorCommand.unpack(raw)
    np.testing.assert_allclose(wire.from_counts(wire.to_counts([0, U_MAX / 3, U_MAX, 2 * U_MAX], U_MAX), U_MAX),
                               [0, U_MAX / 3, U_MAX, U_MAX], atol=U_MAX / 65535)


def test_commands_reach_the_modules_and_the_state_comes_back():
    peer, th = start_peer(19860, 7471)
    try:
        with CrazyflieBackend(uris(19860), U_MAX, ASM.module_rotations) as be:
            peers.check_commands_and_state(be, peer)
            assert be.preflight().issues == ("module 0 is emergency-stopped (restart it)",
                                             "module 1 is emergency-stopped (restart it)")
    finally:
        stop_peer(peer, th)


def test_module_watchdog_and_link_loss():
    peer, th = start_peer(19864, 7472)
    try:
        with CrazyflieBackend(uris(19864), U_MAX, ASM.module_rotations, CrazyflieSettings(link_timeout=0.1)) as be:
            be.arm()
            hold(be, np.full(8, 0.5 * U_MAX), 0.3)
            assert be.telemetry().motors.min() > 0.4 * U_MAX
            time.sleep(0.3)  # the ground station goes silent: each module stops its motors by itself
            assert np.all(peer.sim.telemetry().motors < 0.05 * U_MAX)
            peers.check_link_loss(be, peer, th, 0.1)
    finally:
        stop_peer(peer, th)


def test_preflight_names_silent_and_weak_modules():
    with CrazyflieBackend(uris(19868), U_MAX, ASM.module_rotations, CrazyflieSettings(preflight_timeout=0.3)) as be:
        assert be.preflight().issues == ("module 0 (udp://127.0.0.1:19868) does not answer",
                                         "module 1 (udp://127.0.0.1:19869) does not answer")
    peer, th = start_peer(19870, 7473, battery_v=3.3)
    try:
        with CrazyflieBackend(uris(19870), U_MAX, ASM.module_rotations) as be:
            assert be.preflight().issues == ("module 0 battery 3.30 V < 3.5 V", "module 1 battery 3.30 V < 3.5 V")
    finally:
        stop_peer(peer, th)


def test_unopenable_link():
    with pytest.raises(CrazyflieLinkError, match="cannot open radio://0/80/2M/E7E7E7E701"):
        CrazyflieBackend(["radio://0/80/2M/E7E7E7E701"], U_MAX, ASM.module_rotations[:1]).connect()
    with pytest.raises(ValueError, match="2 links for 1 modules"):
        CrazyflieBackend(["udp://127.0.0.1:1", "udp://127.0.0.1:2"], U_MAX, ASM.module_rotations[:1])
