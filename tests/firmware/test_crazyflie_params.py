"""Crazyflie parameters through cflib's real ``Crazyflie`` class (TOC, param service) against simulated modules."""

from groundstation.firmware.crazyflie_params import check_crazyflie
from groundstation.firmware.params import issues
from sim.crazyflie_peer import SimulatedCrazyflies
from tests.peers import start_peer, stop_peer

WANTED = {"supervisor.tmblChckEn": 0, "stabilizer.controller": 6, "motorPowerSet.enable": 0}


def test_check_apply_and_read_back(tmp_path):
    peer, th = start_peer(SimulatedCrazyflies, 19720, 7603)
    try:
        uri = "udp://127.0.0.1:19721"
        checks = check_crazyflie(uri, 1, WANTED | {"nope.x": 1}, toc_cache=tmp_path / "toc")
        assert issues(checks) == ["module 1 (udp://127.0.0.1:19721): supervisor.tmblChckEn is 1, must be 0",
                                  "module 1 (udp://127.0.0.1:19721): stabilizer.controller is 0, must be 6",
                                  "module 1 (udp://127.0.0.1:19721): nope.x is not in the module's parameters, "
                                  "must be 1"]
        assert peer.firmware(1).value("supervisor.tmblChckEn") == 1  # a check writes nothing
        checks = check_crazyflie(uri, 1, WANTED, apply=True, toc_cache=tmp_path / "toc")
        assert issues(checks) == [] and [c.written for c in checks] == [True, True, False]
        # The module itself now holds them (not just cflib's copy), and module 0 was not touched.
        assert [peer.firmware(1).value(n) for n in WANTED] == [0, 6, 0]
        assert peer.firmware(0).value("stabilizer.controller") == 0
        assert list((tmp_path / "toc").iterdir())  # the TOC was cached for the next connection
        assert issues(check_crazyflie(uri, 1, WANTED)) == []
    finally:
        stop_peer(peer, th)


def test_silent_module_is_named():
    checks = check_crazyflie("udp://127.0.0.1:19729", 0, WANTED, timeout=0.5)
    assert all(c.actual is None and c.note for c in checks)
    assert issues(checks)[0].startswith("module 0 (udp://127.0.0.1:19729): supervisor.tmblChckEn is ")
