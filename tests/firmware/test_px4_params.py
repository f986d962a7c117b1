"""PX4 parameters over MAVLink (pymavlink on both ends) against simulated PX4 modules that apply them."""

import time

import numpy as np

from groundstation.backends.mavlink import MavlinkBackend
from groundstation.firmware.params import issues
from groundstation.firmware.px4_params import check_px4
from sim.mavlink_peer import SimulatedPx4
from tests.peers import ASM, U_MAX, hold, start_peer, stop_peer


def test_check_apply_and_the_module_uses_the_new_value():
    peer, th = start_peer(SimulatedPx4, 14640, 7604)
    links = ["udpout:127.0.0.1:14640", "udpout:127.0.0.1:14641"]
    try:
        wanted = {"COM_OF_LOSS_T": 0.1, "PWM_MAIN_MIN": 1000, "PWM_MAIN_MAX": 2000, "NOPE": 1}
        assert issues(check_px4(links[0], 0, wanted)) == [
            "module 0 (udpout:127.0.0.1:14640): COM_OF_LOSS_T is 1, must be 0.1",
            "module 0 (udpout:127.0.0.1:14640): NOPE is no such parameter, or no answer, must be 1"]
        del wanted["NOPE"]
        with MavlinkBackend(links, U_MAX, ASM.module_rotations) as be:  # stock COM_OF_LOSS_T: 1 s
            be.arm()
            hold(be, np.full(8, 0.5 * U_MAX), 0.1)
            time.sleep(0.4)
            assert all(m.armed for m in peer.modules)  # still flying 0.4 s after the ground station went silent
        for i, link in enumerate(links):
            checks = check_px4(link, i, wanted, apply=True)
            assert issues(checks) == [] and [c.written for c in checks] == [True, False, False]
        assert [peer.param(i, "COM_OF_LOSS_T") for i in range(2)] == [np.float32(0.1)] * 2
    finally:
        stop_peer(peer, th)
    peer, th = start_peer(SimulatedPx4, 14644, 7605, params=(("COM_OF_LOSS_T", 0.1),))
    try:
        with MavlinkBackend(["udpout:127.0.0.1:14644", "udpout:127.0.0.1:14645"], U_MAX, ASM.module_rotations) as be:
            be.arm()
            hold(be, np.full(8, 0.5 * U_MAX), 0.1)
            time.sleep(0.25)
            assert not any(m.armed for m in peer.modules)  # with 0.1 s, the modules stopped by themselves
    finally:
        stop_peer(peer, th)


def test_silent_module_is_named():
    checks = check_px4("udpout:127.0.0.1:14649", 3, {"COM_OF_LOSS_T": 0.1}, heartbeat_timeout=0.3)
    assert checks[0].unreachable
    assert issues(checks) == ["module 3 (udpout:127.0.0.1:14649) does not answer: no heartbeat within 0.3 s"]
