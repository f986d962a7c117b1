"""One conformance suite for every backend: the rules the flight loop relies on."""

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from groundstation.assembly.assembly_file import load_assembly
from groundstation.backends.base import Backend, SimulatedBackend
from groundstation.backends.crazyflie import CrazyflieBackend, CrazyflieSettings
from groundstation.backends.fake import FakeBackend
from groundstation.backends.mavlink import MavlinkBackend
from sim.crazyflie_peer import SimulatedCrazyflies
from sim.mavlink_peer import SimulatedPx4
from sim.module_peer import PeerConfig
from sim.pybullet_backend import PyBulletBackend
from tests.peers import UNTIMED_LINK

ROOT = Path(__file__).resolve().parents[2]
ASM, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
U_MAX = ASM.params.u_max


def make_fake():
    return FakeBackend(ASM.n, U_MAX)


def make_sim():
    return PyBulletBackend(ASM)


def held(backend_class):
    """A hardware backend with a test helper: repeat the last command for a while (the modules' watchdogs stop
    the motors when commands stop)."""

    class Held(backend_class):
        last = np.zeros(8)

        def send(self, u):
            self.last = np.asarray(u, float)
            super().send(u)

        def settle(self) -> None:
            end = time.monotonic() + 0.3
            while time.monotonic() < end:
                super().send(self.last)
                time.sleep(0.005)

    return Held


def make_crazyflie():
    return held(CrazyflieBackend)([f"udp://127.0.0.1:{19874 + i}" for i in range(ASM.n)], ASM.params,
                                  ASM.module_rotations, CrazyflieSettings(**UNTIMED_LINK))


def make_mavlink():
    return held(MavlinkBackend)([f"udpout:127.0.0.1:{14574 + i}" for i in range(ASM.n)], U_MAX,
                                ASM.module_rotations)


PEERS = {make_crazyflie: (SimulatedCrazyflies, 19874), make_mavlink: (SimulatedPx4, 14574)}


@pytest.fixture(params=[make_fake, make_sim, make_crazyflie, make_mavlink],
                ids=["fake", "pybullet", "crazyflie-udp", "mavlink-udp"])
def backend(request):
    peer = None
    if request.param in PEERS:
        peer_class, port = PEERS[request.param]
        peer = peer_class(ASM, PeerConfig(port=port, mocap_endpoint="tcp/127.0.0.1:7474"))
        peer.open()
        th = threading.Thread(target=peer.run, daemon=True)
        th.start()
    be = request.param()
    try:
        with be:
            yield be
    finally:
        if peer is not None:
            peer.stop_event.set()
            th.join(5)
            peer.close()


def applied(be) -> np.ndarray:
    if hasattr(be, "advance_to"):
        be.advance_to(be.time + 0.5)  # let the motor lag settle
    if hasattr(be, "settle"):
        be.settle()
    return be.telemetry().motors


def test_protocol_and_preflight(backend):
    assert isinstance(backend, Backend)
    assert backend.preflight().ok and backend.telemetry().link_ok


def test_commands_ignored_until_armed(backend):
    backend.send(np.full(8, 0.5 * U_MAX))
    assert applied(backend).max() == 0.0


def test_commands_bounded_and_nan_stops_the_rotor(backend):
    backend.arm()
    cmd = np.array([-1.0, 2 * U_MAX, np.nan, np.inf, 0.25 * U_MAX, 0.5 * U_MAX, 0.75 * U_MAX, U_MAX])
    backend.send(cmd)
    u = applied(backend)
    assert u.min() >= 0.0 and u.max() <= U_MAX
    floor = backend.idle_inputs()  # a Crazyflie Bolt keeps its motors at the idle floor while armed
    floor = floor[[0, 2, 3]] if floor.size else 0.0
    assert np.all(floor < 0.02 * U_MAX)
    np.testing.assert_allclose(u[[0, 2, 3]], floor, atol=1e-6 * U_MAX)
    np.testing.assert_allclose(u[[1, 7]], U_MAX, rtol=1e-3)
    np.testing.assert_allclose(u[4:7], [0.25 * U_MAX, 0.5 * U_MAX, 0.75 * U_MAX], rtol=1e-3)


def test_emergency_stop_zeroes_at_once_and_disarms(backend):
    backend.arm()
    backend.send(np.full(8, 0.5 * U_MAX))
    applied(backend)
    backend.emergency_stop()
    assert backend.telemetry().motors.max() == 0.0  # immediately, not after a lag
    backend.send(np.full(8, 0.5 * U_MAX))
    assert applied(backend).max() == 0.0  # disarmed


def test_disarm_ends_normally_and_the_modules_fly_again(backend):
    backend.arm()
    backend.send(np.full(8, 0.5 * U_MAX))
    assert applied(backend).min() > 0.45 * U_MAX
    backend.disarm()
    backend.send(np.full(8, 0.5 * U_MAX))
    assert applied(backend).max() < 1e-4 * U_MAX  # disarmed (simulated rotors spin down through their lag)
    backend.arm()  # no reboot: a normal end does not latch like the emergency stop
    backend.send(np.full(8, 0.5 * U_MAX))
    np.testing.assert_allclose(applied(backend), 0.5 * U_MAX, rtol=1e-3)


def test_wrong_command_size_is_an_error(backend):
    backend.arm()
    with pytest.raises(ValueError):
        backend.send(np.zeros(5))


def test_leaving_the_block_on_an_error_stops_an_armed_backend(backend):
    backend.arm()
    backend.send(np.full(8, 0.5 * U_MAX))
    assert applied(backend).min() > 0.45 * U_MAX
    error = RuntimeError("operator code failed")
    backend.__exit__(RuntimeError, error, None)  # the fixture's ``with backend:`` block ending in this error
    assert not backend.armed  # the emergency stop ran before the links closed


def test_only_the_simulator_is_a_simulated_backend(backend):
    assert isinstance(backend, SimulatedBackend) == isinstance(backend, PyBulletBackend)
