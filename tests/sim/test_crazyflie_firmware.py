"""The simulated Crazyflie: the transitions and arithmetic of crazyflie-firmware 2026.08 the ground station meets
(the same scenarios run against the real firmware in tests/firmware_sitl when a checkout is given)."""

import numpy as np
import pytest

from groundstation.backends import crtp_wire as wire
from sim.crazyflie_firmware import FirmwareBuild, SimulatedCrazyflie, Supervisor

IDLE_RPM = np.full(4, 2000.0)
"""Inside the 2.1 Brushless arming window (1000-3500 RPM)."""


def booted(platform: str) -> Supervisor:
    sup = Supervisor(platform, now=0.0)
    sup.step(0.001, False, 0.0)  # pre-flight checks pass on the first update of a level module
    return sup


def test_arming_platforms_wait_for_the_request_and_time_out_after_30_s():
    sup = booted("bolt")
    assert sup.state == "passed" and not sup.armed and not sup.motors_allowed
    assert sup.request_arming(True) == (True, True)
    sup.step(0.01, over_idle=False, setpoint_age=0.0)
    assert sup.state == "arming" and sup.motors_allowed and not sup.can_fly  # the idle floor, no flight yet
    sup.step(0.011, over_idle=False, setpoint_age=0.0)
    assert sup.state == "ready" and sup.can_fly  # no RPM check without bidirectional DSHOT
    sup.step(30.0, over_idle=False, setpoint_age=0.0)
    assert sup.state == "ready"
    sup.step(30.02, over_idle=False, setpoint_age=0.0)  # armed 30 s without flying: the pre-flight timeout
    assert sup.state == "not_passed" and not sup.armed and sup.last_event == "pre-flight timeout"


def test_auto_arming_platform_arms_itself():
    sup = booted("cf2")
    sup.step(0.002, False, 0.0)
    sup.step(0.003, False, 0.0)
    assert sup.armed and sup.state == "ready"


def test_brushless_passes_arming_only_with_every_motor_in_the_rpm_window_for_200_ms():
    sup = booted("cf21bl")
    sup.request_arming(True)
    sup.step(0.01, False, 0.0, rpm=IDLE_RPM)
    assert sup.state == "arming"
    sup.step(0.1, False, 0.0, rpm=IDLE_RPM)
    sup.step(0.209, False, 0.0, rpm=IDLE_RPM)
    assert sup.state == "arming"
    sup.step(0.311, False, 0.0, rpm=IDLE_RPM)
    assert sup.state == "ready" and sup.can_fly


def test_brushless_disarms_when_thrust_during_arming_leaves_the_rpm_window():
    """What the real cf21bl build did before the app gated on supervisorCanFly: take-off thrust right after the
    arming request spins the motors past 3500 RPM, and the 2 s spin-up timeout disarms the module."""
    sup = booted("cf21bl")
    sup.request_arming(True)
    sup.step(0.01, False, 0.0, rpm=np.zeros(4))
    assert sup.state == "arming"
    t = 0.011
    while t < 2.2 and sup.state == "arming":
        sup.step(t, True, 0.0, rpm=np.full(4, 9000.0))
        t += 0.001
    assert sup.state == "not_passed" and not sup.armed
    assert 2.0 < t < 2.02 and "arming RPM" in sup.last_event


@pytest.mark.parametrize("tumble_check, armed", [(1, False), (0, True)])
def test_a_module_mounted_beyond_60_degrees_is_refused_unless_tumble_detection_is_off(tumble_check, armed):
    fw = SimulatedCrazyflie(FirmwareBuild("bolt"), now=0.0, preset=(("supervisor.tmblChckEn", tumble_check),))
    tilted = (np.sin(np.radians(65.0)), 0.0, np.cos(np.radians(65.0)))  # 0.42 g along its z axis at rest
    for k in range(1, 1500):
        fw.step(k * 1e-3, acc_g=tilted)
    reply = fw.handle(bytes([wire.SUPERVISOR_HEADER]) + wire.arm_request(True), 1.5)
    assert wire.arm_response(reply[0][1:]) == (armed, armed)


def test_flying_landing_and_disarm_return_to_preflight_without_a_lock():
    sup = booted("bolt")
    sup.request_arming(True)
    sup.step(0.01, False, 0.0)
    sup.step(0.011, False, 0.0)
    sup.step(0.02, True, 0.0)
    assert sup.state == "flying"
    sup.step(2.5, False, 0.0)  # no thrust over idle for 2 s: landed
    assert sup.state == "landed"
    assert sup.request_arming(False) == (True, False)
    sup.step(2.6, False, 0.0)
    sup.step(2.61, False, 0.0)
    assert sup.state == "passed" and not sup.locked  # can arm again


def test_commander_watchdog_in_flight_and_the_stop_lock_until_reboot():
    sup = booted("bolt")
    sup.request_arming(True)
    sup.step(0.01, False, 0.0)
    sup.step(0.011, False, 0.0)
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
    assert fw.app.latest is None and np.all(fw.ratios(0.0) == 0.0)


def test_states_answer_commands_and_report_the_motor_ratios():
    """No ground station: nothing is queued (a new connection reads no backlog). Each batch of commands is
    answered once, with the ratios the power distribution set (battery compensated, idle floor), not the forces."""
    fw = SimulatedCrazyflie(FirmwareBuild("cf2"), now=0.0, battery_v=3.9)
    for k in range(1, 3000):
        fw.step(k * 1e-3)
        assert not fw.state_due()
    ident = wire.Identity.unpack(fw.handle(bytes([wire.APP_HEADER]) + wire.Claim(77).pack(), 3.0)[0][1:])
    assert (ident.session, ident.token) == (77, 1) and not fw.state_due()  # a claim is answered by the identity
    for seq in (1, 2, 3):
        fw.handle(bytes([wire.APP_HEADER]) + wire.MotorCommand(seq, True, wire.to_counts([0.5] * 4), 1).pack(), 3.0)
    assert fw.state_due()
    st = wire.ModuleState.unpack(fw.state_packet(3.0, np.zeros(3))[1:])
    assert not fw.state_due()
    assert st.sequence == 3 and st.can_fly and st.received == 3
    assert abs(st.counts[0] - 36507) <= 1  # 0.5 at 3.9 V, as the real cf2 build sets it (32768 commanded)
