"""The same scenarios against the real firmware (``cf_sitl`` processes) and against our model of it
(``sim/crazyflie_firmware.py``), driven by the ground station's own Crazyflie backend through cflib over UDP: the
model must give the outcomes the firmware gives. The firmware half needs ``CRAZYFLIE_FIRMWARE`` (see conftest)."""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time

import numpy as np
import pytest

from groundstation.assembly.assembly_file import load_assembly
from groundstation.backends import crtp_wire as wire
from groundstation.backends.crazyflie import CrazyflieBackend, CrazyflieSettings
from groundstation.errors import ArmingError
from groundstation.firmware.crazyflie_params import check_crazyflie
from groundstation.firmware.params import issues, load_param_file
from groundstation.runtime.placement import placement_issues, predicted_up
from sim.crazyflie_peer import SimulatedCrazyflies
from sim.firmware_peer import FIRMWARE_PHYSICS_HZ, FirmwareCrazyflies
from sim.module_peer import PeerConfig
from tests.firmware_sitl.conftest import ROOT, sitl_binary
from tests.peers import UNTIMED_LINK, hold

KINDS = ["model", "firmware"]
WANTED = load_param_file(ROOT / "firmware_params/crazyflie.toml")
TOY = {"bolt": "toy_v2.json", "cf2": "toy_v2_cf2.json", "cf21bl": "toy_v2_cf21bl.json"}


def toy(platform: str):
    return load_assembly(ROOT / "configs/assemblies" / TOY[platform])[0]


class Modules:
    """Modules of ``kind`` for ``assembly`` in a thread of the test, on ``port``, ``port + 1``, ..."""

    def __init__(self, kind: str, platform: str, assembly, port: int, mocap_port: int, tmp_path) -> None:
        self.kind, self.assembly, self.port = kind, assembly, port
        config = PeerConfig(port=port, mocap_endpoint=f"tcp/127.0.0.1:{mocap_port}", platform=platform,
                            physics_hz=FIRMWARE_PHYSICS_HZ if kind == "firmware" else PeerConfig.physics_hz)
        if kind == "firmware":
            self.peer = FirmwareCrazyflies(assembly, config, binary=sitl_binary(platform), state_dir=tmp_path)
        else:
            self.peer = SimulatedCrazyflies(assembly, config)
        self.peer.open()
        self._start()

    def _start(self) -> None:
        self.peer.stop_event.clear()
        self._thread = threading.Thread(target=self.peer.run, daemon=True)
        self._thread.start()

    def _stop(self) -> None:
        self.peer.stop_event.set()
        self._thread.join(5)

    @property
    def uris(self) -> list[str]:
        return [f"udp://127.0.0.1:{self.port + i}" for i in range(self.assembly.n)]

    def backend(self, **settings) -> CrazyflieBackend:
        return CrazyflieBackend(self.uris, self.assembly.params, self.assembly.module_rotations,
                                CrazyflieSettings(**(UNTIMED_LINK | settings)))

    def restart(self) -> None:
        """Power-cycle every module: only stored parameters survive."""
        self._stop()
        if self.kind == "firmware":
            self.peer.restart()
        else:
            for i in range(self.assembly.n):
                self.peer.firmware(i).handle(bytes([wire.NULL_HEADER, 0xFE, 0xF0]), time.monotonic())
        self._start()

    def kill(self, i: int) -> None:
        """Module i stops dead (its firmware process killed, or the model powered off)."""
        if self.kind == "firmware":
            self.peer.kill(i)
        else:
            self.peer.firmware(i).handle(bytes([wire.NULL_HEADER, 0xFE, 0x02]), time.monotonic())

    def close(self) -> None:
        self._stop()
        self.peer.close()


@contextlib.contextmanager
def modules(kind, platform, assembly, port, mocap_port, tmp_path):
    m = Modules(kind, platform, assembly, port, mocap_port, tmp_path)
    try:
        yield m
    finally:
        m.close()


def armed(be: CrazyflieBackend) -> CrazyflieBackend:
    """``be`` through preflight and armed."""
    report = be.preflight()
    assert report.ok, report.issues
    be.arm()
    return be


def wait_for(condition, timeout: float = 2.0, step=None) -> bool:
    """Poll ``condition`` (calling ``step`` between polls) until true or ``timeout`` s passed."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        if step is not None:
            step()
        time.sleep(0.005)
    return condition()


@pytest.mark.parametrize("kind", KINDS)
def test_brushless_arms_through_the_rpm_check_and_take_off_does_not_disarm(kind, tmp_path):
    asm = toy("cf21bl")
    with modules(kind, "cf21bl", asm, 19600, 7620, tmp_path) as m, m.backend() as be:
        armed(be)
        assert all(s.can_fly and s.supervisor_armed for s in be.module_states())
        hold(be, np.full(8, 0.3 * asm.params.u_max), 2.5)  # thrust over idle, past the 2 s spin-up timeout
        tel = be.telemetry()
        assert tel.module_faults == ("", "")
        assert np.all(tel.motors > 0.25 * asm.params.u_max) and all(m.peer.armed(i) for i in range(asm.n))
        be.disarm()


@pytest.mark.parametrize("kind", KINDS)
def test_emergency_stop_locks_every_module_and_zeroes_its_motors(kind, tmp_path):
    asm = toy("bolt")
    with modules(kind, "bolt", asm, 19610, 7621, tmp_path) as m, m.backend() as be:
        armed(be)
        hold(be, np.full(8, 0.3 * asm.params.u_max), 0.3)
        assert all(m.peer.ratios(i).min() > 0.2 for i in range(asm.n))
        be.emergency_stop()
        assert wait_for(lambda: all(m.peer.locked(i) and not m.peer.ratios(i).any() for i in range(asm.n)))
        hold(be, np.full(8, 0.3 * asm.params.u_max), 0.3)  # disarmed, and the modules latched the stop
        assert all(m.peer.locked(i) and not m.peer.ratios(i).any() for i in range(asm.n))
        assert all(s.locked for s in be.module_states())


@pytest.mark.parametrize("kind", KINDS)
def test_a_module_mounted_beyond_60_degrees_flies_only_once_tumble_detection_is_off_and_stored(kind, tmp_path):
    steep = dataclasses.replace(toy("bolt"), alpha=np.radians([65.0, 0.0, -130.0]))  # each module tilted 65 deg
    with modules(kind, "bolt", steep, 19620, 7622, tmp_path) as m:
        time.sleep(1.5)  # the tumble check needs 1 s below 0.5 g along the module's z axis
        with m.backend() as be, pytest.raises(ArmingError) as refused:
            armed(be)
        assert "module 0 (udp://127.0.0.1:19620): its supervisor refused to arm" in str(refused.value)
        assert "module 1 (udp://127.0.0.1:19621): its supervisor refused to arm" in str(refused.value)
        for i, uri in enumerate(m.uris):
            assert issues(check_crazyflie(uri, i, WANTED, apply=True)) == []
        m.restart()  # the reboot an emergency stop requires: the stored value is still 0
        for i, uri in enumerate(m.uris):
            checks = check_crazyflie(uri, i, WANTED)
            assert issues(checks) == [] and [c.actual for c in checks if c.name == "supervisor.tmblChckEn"] == [0]
        time.sleep(1.5)
        with m.backend() as be:
            armed(be)
            be.disarm()


@pytest.mark.parametrize("kind", KINDS)
def test_one_ground_station_owns_the_modules_and_each_names_itself(kind, tmp_path, monkeypatch):
    """Motor app contract 3: the claim's answer names each module (distinct unique ids, gravity where its mount
    puts it); a second ground station (another host: its own link locks) is refused while the first flies, and
    its commands never reach the motors; two links to one module are refused."""
    asm = toy("bolt")
    u = np.full(8, 0.3 * asm.params.u_max)  # below hover: on the ground
    with modules(kind, "bolt", asm, 19620, 7622, tmp_path) as m, m.backend() as first:
        armed(first)
        ids = first.module_ids()
        assert None not in ids and len(set(ids)) == 2
        up = predicted_up(asm.module_rotations, m.peer.sim.true_state().rotation)
        assert not placement_issues(first.module_gravity(), asm.module_rotations,
                                    m.peer.sim.true_state().rotation, ["m0", "m1"])
        assert max(np.degrees(np.arccos(np.clip(np.sum(first.module_gravity() * up, axis=1), -1, 1)))) < 3.0
        flying = threading.Thread(target=hold, args=(first, u, 2.5), daemon=True)
        flying.start()
        # Flying means armed commands streaming: arm() ends on disarmed zeros, and with links that open at once the
        # second claim could reach the modules before the thread's first armed command (a free module is claimed).
        assert wait_for(lambda: all(s is not None and s.armed for s in first.module_states()))
        monkeypatch.setenv("GROUNDSTATION_OTHER_HOST_LOCKS", str(tmp_path / "other-host"))
        with m.backend() as second:
            issues = second.preflight().issues
            assert issues == tuple(f"module {i} (udp://127.0.0.1:{19620 + i}) flies for another ground station "
                                   f"(session {first.session:08x}): one flight owns a module set" for i in range(2))
            second.send(np.zeros(8))  # never claimed: nothing goes out
        flying.join()
        tel = first.telemetry()
        assert tel.module_faults == ("", "") and np.allclose(tel.motors, u, rtol=1e-3)
        first.disarm()
    with modules(kind, "bolt", asm, 19624, 7624, tmp_path / "b") as m:
        twice = CrazyflieBackend(["udp://127.0.0.1:19624"] * 2, asm.params, asm.module_rotations,
                                 CrazyflieSettings(**UNTIMED_LINK))
        with twice:
            issues = twice.preflight().issues
        assert any(i.startswith("module 0 (udp://127.0.0.1:19624) and module 1 (udp://127.0.0.1:19624) are one "
                                "module (unique id ") for i in issues), issues


@pytest.mark.parametrize("kind", KINDS)
def test_a_module_that_dies_in_hover_is_named(kind, tmp_path):
    asm = toy("bolt")
    with modules(kind, "bolt", asm, 19630, 7623, tmp_path) as m, m.backend() as be:
        armed(be)
        hold(be, np.full(8, 0.3 * asm.params.u_max), 0.3)
        m.kill(1)
        hold(be, np.full(8, 0.3 * asm.params.u_max), 0.3)
        tel = be.telemetry()
        assert not tel.link_ok and tel.module_faults[0] == ""
        assert tel.module_faults[1].startswith("sends no state (for ")
        be.emergency_stop()


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("platform", ["cf2", "bolt", "cf21bl"])
def test_the_motor_ratios_are_the_thrust_maps(kind, platform, tmp_path):
    """What the power distribution sets (battery compensation and its dead zone, the idle floor), as the modules
    report it, against the ground station's map of the platform (``motor_map.MotorCommandMap.motor_ratios``)."""
    asm = toy(platform)
    motor_map, u_max = asm.params.motor_command, asm.params.u_max
    port = {"cf2": 19670, "bolt": 19680, "cf21bl": 19690}[platform]
    with modules(kind, platform, asm, port, 7627, tmp_path) as m, m.backend() as be:
        armed(be)
        u = np.tile([0.004, 0.1, 0.2, 0.35], 2) * u_max  # below hover: the assembly stays on the ground
        hold(be, u, 1.0)  # the firmware's battery filter settles (b = 0.01 per 1 ms step)
        battery = np.array([s.battery_v for s in be.module_states()])
        sent = motor_map.fractions((asm.params.c_f * u).reshape(-1, 4), battery)
        expected = motor_map.motor_ratios(np.rint(sent * 65535) / 65535, battery) * 65535
        reported = np.array([s.counts for s in be.module_states()], float)
        np.testing.assert_allclose(reported, expected, rtol=5e-3, atol=2)
        assert np.all(reported[:, 0] == np.rint(motor_map.idle * 65535))  # dead zone or nothing: the idle floor
        be.disarm()


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("platform", ["cf2", "bolt"])
def test_a_normal_end_leaves_the_modules_ready_to_fly_again(kind, platform, tmp_path):
    """After thrust, a disarm and the ground station gone, no module locks (an auto-arming cf2 arms itself again and,
    its flying hysteresis still on, is flying: without the zeros the backend streams until it has run out, its
    commander watchdog locked it 2 s later), and a second flight arms without a reboot."""
    asm = toy(platform)
    port = {"cf2": 19710, "bolt": 19720}[platform]
    with modules(kind, platform, asm, port, 7628, tmp_path) as m:
        with m.backend() as be:
            armed(be)
            hold(be, np.full(8, 0.3 * asm.params.u_max), 1.0)
            hold(be, np.zeros(8), 0.2)
            be.disarm()
        time.sleep(3.0)  # past the commander watchdog
        assert not any(m.peer.locked(i) for i in range(asm.n))
        with m.backend() as be:
            armed(be)
            be.disarm()
