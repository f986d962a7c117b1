"""The Crazyflie backend through cflib's real UDP link driver, against simulated modules speaking CRTP."""

import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from cflib.crtp.crtpstack import CRTPPacket

from groundstation.assembly.assembly_file import load_assembly
from groundstation.backends import crtp_wire as wire
from groundstation.backends.crazyflie import CrazyflieBackend, CrazyflieLinkError, CrazyflieSettings
from sim.crazyflie_peer import PeerConfig, SimulatedModules

ROOT = Path(__file__).resolve().parents[2]
ASM, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
U_MAX = ASM.params.u_max


def start_peer(port: int, mocap_port: int, **kw) -> tuple[SimulatedModules, threading.Thread]:
    peer = SimulatedModules(ASM, PeerConfig(port=port, mocap_endpoint=f"tcp/127.0.0.1:{mocap_port}", **kw))
    peer.open()
    th = threading.Thread(target=peer.run, daemon=True)
    th.start()
    return peer, th


def stop_peer(peer, th) -> None:
    peer.stop_event.set()
    th.join(5)
    peer.close()


def uris(port: int) -> list[str]:
    return [f"udp://127.0.0.1:{port + i}" for i in range(ASM.n)]


def hold(be: CrazyflieBackend, u: np.ndarray, seconds: float) -> None:
    """Keep sending ``u`` at 200 Hz (the modules' watchdog stops the motors when commands stop)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        be.send(u)
        be.telemetry()
        time.sleep(0.005)


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
            assert be.preflight().ok
            be.send(np.full(8, 0.5 * U_MAX))
            hold(be, np.full(8, 0.5 * U_MAX), 0.3)
            assert be.telemetry().motors.max() == 0.0  # not armed: the modules ignore it
            be.arm()
            cmd = np.array([-1.0, 2 * U_MAX, np.nan, np.inf, 0.25 * U_MAX, 0.5 * U_MAX, 0.75 * U_MAX, U_MAX])
            hold(be, cmd, 0.4)
            tel = be.telemetry()
            assert tel.link_ok and tel.battery_v.tolist() == pytest.approx([4.0, 4.0])
            np.testing.assert_allclose(tel.motors, [0, U_MAX, 0, 0, 0.25 * U_MAX, 0.5 * U_MAX, 0.75 * U_MAX, U_MAX],
                                       atol=2e-3 * U_MAX)
            # The body rate reassembled from the modules' IMUs (each in its own tilted frame) is the body's. The
            # lopsided command spins the assembly up, and the state is up to one 100 Hz reply old: 5% slack.
            omega = peer.sim.true_state().omega
            assert np.linalg.norm(omega) > 0.5
            np.testing.assert_allclose(tel.gyro, omega, rtol=0.05, atol=0.05)
            with pytest.raises(ValueError):
                be.send(np.zeros(5))
            be.emergency_stop()
            assert be.telemetry().motors.max() == 0.0  # at once, not after a round trip
            hold(be, np.full(8, 0.5 * U_MAX), 0.3)
            assert be.telemetry().motors.max() == 0.0  # disarmed, and the modules latched the stop
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
            hold(be, np.full(8, 0.5 * U_MAX), 0.1)
            assert be.telemetry().link_ok
            stop_peer(peer, th)  # the modules vanish
            t0 = time.monotonic()
            while be.telemetry().link_ok and time.monotonic() - t0 < 1.0:
                be.send(np.full(8, 0.5 * U_MAX))
                time.sleep(0.005)
            assert not be.telemetry().link_ok and time.monotonic() - t0 < 0.1 + 0.05
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
