"""Crazyflie parameters through cflib's real ``Crazyflie`` class (TOC, param service) against simulated modules."""

import time

from cflib.utils.power_switch import PowerSwitch

from groundstation.firmware.crazyflie_params import check_crazyflie
from groundstation.firmware.params import issues, load_param_file
from sim.crazyflie_peer import SimulatedCrazyflies
from tests.peers import ROOT, start_peer, stop_peer

WANTED = load_param_file(ROOT / "firmware_params/crazyflie.toml")


def reboot(peer, i: int, uri: str) -> None:
    """Reboot module i as an operator would after an emergency stop: cflib's PowerSwitch over its link."""
    boots = peer.firmware(i).boots
    switch = PowerSwitch(uri)
    switch.reboot_to_fw()
    switch.close()
    deadline = time.monotonic() + 2.0
    while peer.firmware(i).boots == boots and time.monotonic() < deadline:
        time.sleep(0.01)
    assert peer.firmware(i).boots == boots + 1


def test_check_apply_store_and_survive_a_reboot(tmp_path):
    peer, th = start_peer(SimulatedCrazyflies, 19720, 7603)
    try:
        uri = "udp://127.0.0.1:19721"
        checks = check_crazyflie(uri, 1, WANTED | {"nope.x": 1}, toc_cache=tmp_path / "toc")
        # A motor-app build: version and controller are right from boot; tumble detection is on (stock).
        assert issues(checks) == ["module 1 (udp://127.0.0.1:19721): supervisor.tmblChckEn is 1, must be 0",
                                  "module 1 (udp://127.0.0.1:19721): nope.x is not in the module's parameters, "
                                  "must be 1"]
        assert peer.firmware(1).services.value("supervisor.tmblChckEn") == 1  # a check writes nothing
        checks = check_crazyflie(uri, 1, WANTED, apply=True, toc_cache=tmp_path / "toc")
        assert issues(checks) == []
        assert [(c.name, c.written, c.stored) for c in checks if c.written] == [("supervisor.tmblChckEn", True, True)]
        # The module itself holds it, in EEPROM too, and module 0 was not touched.
        assert peer.firmware(1).services.value("supervisor.tmblChckEn") == 0
        assert peer.firmware(1).services.stored == {"supervisor.tmblChckEn": 0}
        assert peer.firmware(0).services.value("supervisor.tmblChckEn") == 1
        assert list((tmp_path / "toc").iterdir())  # the TOC was cached for the next connection
        # An emergency stop needs a reboot; the stored value survives it.
        peer.firmware(1).supervisor.estop = True
        reboot(peer, 1, uri)
        assert not peer.locked(1)
        assert issues(check_crazyflie(uri, 1, WANTED, toc_cache=tmp_path / "toc")) == []
    finally:
        stop_peer(peer, th)


def test_read_only_parameters_are_never_written():
    peer, th = start_peer(SimulatedCrazyflies, 19724, 7604)
    try:
        uri = "udp://127.0.0.1:19724"
        checks = check_crazyflie(uri, 0, {"motorApp.version": 4}, apply=True)
        assert issues(checks) == ["module 0 (udp://127.0.0.1:19724): motorApp.version is 3, must be 4 (read-only: "
                                  "flash the firmware that has it right)"]
        assert not checks[0].written and peer.firmware(0).services.value("motorApp.version") == 3
    finally:
        stop_peer(peer, th)


def test_stock_firmware_is_named():
    peer, th = start_peer(SimulatedCrazyflies, 19726, 7605, motor_app=False)
    try:
        checks = check_crazyflie("udp://127.0.0.1:19726", 0, WANTED)
        assert issues(checks) == [
            "module 0 (udp://127.0.0.1:19726): motorApp.version is not in the module's parameters, must be 3",
            "module 0 (udp://127.0.0.1:19726): supervisor.tmblChckEn is 1, must be 0",
            "module 0 (udp://127.0.0.1:19726): stabilizer.controller is 1, must be 6"]
    finally:
        stop_peer(peer, th)


def test_silent_module_is_named_once():
    checks = check_crazyflie("udp://127.0.0.1:19729", 0, WANTED, timeout=0.3)
    assert all(c.actual is None and c.unreachable for c in checks)
    assert issues(checks) == ["module 0 (udp://127.0.0.1:19729) does not answer: Error communicating with the "
                              "Crazyflie (5 attempts)"]


def test_a_right_value_only_in_ram_is_named_and_stored_by_apply():
    """tmblChckEn = 0 set by hand but never stored reads right, and the reboot an emergency stop requires brings
    tumble detection back: the check names it (from the module's stored state), --apply stores it."""
    peer, th = start_peer(SimulatedCrazyflies, 19728, 7619)
    try:
        uri = "udp://127.0.0.1:19728"
        peer.firmware(0).services.set("supervisor.tmblChckEn", 0)  # RAM only
        assert issues(check_crazyflie(uri, 0, WANTED)) == [
            "module 0 (udp://127.0.0.1:19728): supervisor.tmblChckEn is right in RAM but not stored: a reboot "
            "brings the stock value back, must be 0"]
        checks = check_crazyflie(uri, 0, WANTED, apply=True)
        assert issues(checks) == []
        assert [(c.name, c.written, c.stored) for c in checks if c.stored] == [("supervisor.tmblChckEn", False, True)]
        assert peer.firmware(0).services.stored == {"supervisor.tmblChckEn": 0}
        reboot(peer, 0, uri)
        assert peer.firmware(0).services.value("supervisor.tmblChckEn") == 0
        assert issues(check_crazyflie(uri, 0, WANTED)) == []
    finally:
        stop_peer(peer, th)
