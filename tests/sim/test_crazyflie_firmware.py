"""The simulated Crazyflie's supervisor: the transitions of crazyflie-firmware 2026.08 the ground station meets."""

import numpy as np

from groundstation.backends import crtp_wire as wire
from sim.crazyflie_firmware import FirmwareBuild, SimulatedCrazyflie, Supervisor


def test_arming_platforms_wait_for_the_request_and_time_out_after_30_s():
    sup = Supervisor("bolt", now=0.0)
    assert sup.state == "passed" and not sup.armed and not sup.motors_allowed
    assert sup.request_arming(True) == (True, True)
    sup.step(0.01, over_idle=False, setpoint_age=0.0)
    assert sup.state == "ready" and sup.motors_allowed
    sup.step(30.0, over_idle=False, setpoint_age=0.0)
    assert sup.state == "ready"
    sup.step(30.02, over_idle=False, setpoint_age=0.0)  # armed 30 s without flying: the pre-flight timeout
    assert sup.state == "passed" and not sup.armed


def test_auto_arming_platform_arms_itself():
    sup = Supervisor("cf2", now=0.0)
    assert sup.armed and sup.state == "ready"


def test_flying_landing_and_disarm_return_to_preflight_without_a_lock():
    sup = Supervisor("bolt", now=0.0)
    sup.request_arming(True)
    sup.step(0.01, False, 0.0)
    sup.step(0.02, True, 0.0)
    assert sup.state == "flying"
    sup.step(2.5, False, 0.0)  # no thrust over idle for 2 s: landed
    assert sup.state == "landed"
    assert sup.request_arming(False) == (True, False)
    sup.step(2.6, False, 0.0)
    assert sup.state == "passed" and not sup.locked  # can arm again


def test_commander_watchdog_in_flight_and_the_stop_lock_until_reboot():
    sup = Supervisor("bolt", now=0.0)
    sup.request_arming(True)
    sup.step(0.01, False, 0.0)
    sup.step(0.02, True, 0.0)
    sup.step(1.0, True, setpoint_age=2.01)  # 2 s without a setpoint while flying
    assert sup.locked and not sup.motors_allowed
    assert sup.request_arming(True) == (False, False)
    fw = SimulatedCrazyflie(FirmwareBuild("bolt"), now=0.0)
    fw.handle(bytes([wire.SUPERVISOR_HEADER, wire.CMD_EMERGENCY_STOP]), 0.1)
    fw.step(0.1)
    assert fw.supervisor.locked
    fw.handle(bytes([wire.NULL_HEADER, 0xFE, 0xF0, 0x01]), 0.2)  # cflib's PowerSwitch.reboot_to_fw over UDP
    assert not fw.supervisor.locked and fw.boots == 2


def test_the_null_packet_is_not_routed_to_the_app():
    fw = SimulatedCrazyflie(FirmwareBuild("cf2"), now=0.0)
    assert fw.handle(bytes([wire.NULL_HEADER]), 0.0) == []
    assert fw.app.latest is None and np.all(fw.forces(0.0) == 0.0)
