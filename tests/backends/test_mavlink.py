"""The MAVLink backend through pymavlink's UDP connections, against simulated PX4 modules speaking MAVLink."""

import contextlib
import itertools
import threading
import time

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from groundstation.backends import mavlink_wire as mw
from groundstation.backends.mavlink import ARM_GRACE_S, MavlinkBackend, MavlinkSettings
from groundstation.errors import ArmingError, LinkError
from sim.mavlink_peer import SimulatedPx4
from tests import peers
from tests.peers import ASM, U_MAX, hold, stop_peer

UNTIMED = MavlinkSettings(max_latency=0.5)
"""For tests that are not about the round-trip bound: the simulated modules are threads of this (loaded) process."""


def start_peer(port: int, mocap_port: int, **kw):
    return peers.start_peer(SimulatedPx4, port, mocap_port, **kw)


def links(port: int) -> list[str]:
    return [f"udpout:127.0.0.1:{port + i}" for i in range(ASM.n)]


def test_wire_conventions():
    u = np.array([0.0, U_MAX / 3, U_MAX, 2 * U_MAX])
    controls = mw.to_controls(u, U_MAX)
    assert len(controls) == 8 and controls[4:] == [0.0] * 4
    np.testing.assert_allclose(controls[:4], [0.0, 1 / 3, 1.0, 1.0])
    np.testing.assert_allclose(mw.from_controls(controls, U_MAX), [0.0, U_MAX / 3, U_MAX, U_MAX])
    pwm = mw.to_pwm(u, U_MAX, 1000, 2000)
    assert pwm == [1000, 1333, 2000, 2000]
    np.testing.assert_allclose(mw.from_pwm(pwm, U_MAX, 1000, 2000), [0, U_MAX / 3, U_MAX, U_MAX], atol=U_MAX / 1000)
    assert mw.from_pwm([900, 0, 1000, 2100], U_MAX, 1000, 2000).tolist() == [0.0, 0.0, 0.0, U_MAX]
    # PX4's custom mode for offboard: main mode 6 in bits 16-23 (px4_custom_mode.h)
    assert mw.PX4_OFFBOARD_CUSTOM_MODE == 0x00060000
    # FRD -> FLU is a proper rotation (pi about x), its own inverse
    assert np.linalg.det(mw.FRD_TO_FLU) == 1.0 and np.array_equal(mw.FRD_TO_FLU @ mw.FRD_TO_FLU, np.eye(3))


def test_actuator_message_survives_the_wire():
    """SET_ACTUATOR_CONTROL_TARGET as packed by pymavlink (MAVLink 2) decodes to the controls we sent."""
    enc = mavlink2.MAVLink(None, srcSystem=mw.GCS_SYSTEM_ID, srcComponent=mw.GCS_COMPONENT_ID)
    controls = mw.to_controls(np.array([0.1, 0.2, 0.3, 0.4]) * U_MAX, U_MAX)
    raw = enc.set_actuator_control_target_encode(123, mw.ACTUATOR_GROUP, 2, 1, controls).pack(enc)
    msg = mavlink2.MAVLink(None).parse_char(raw)
    assert msg.get_type() == "SET_ACTUATOR_CONTROL_TARGET" and msg.target_system == 2 and msg.group_mlx == 0
    np.testing.assert_allclose(msg.controls[:4], [0.1, 0.2, 0.3, 0.4], rtol=1e-6)


def test_commands_reach_the_modules_and_the_state_comes_back():
    peer, th = start_peer(14600, 7481)
    try:
        with MavlinkBackend(links(14600), U_MAX, ASM.module_rotations, UNTIMED) as be:
            peers.check_commands_and_state(be, peer)  # ATTITUDE rates arrive in PX4's FRD frame
            assert be.preflight().issues == ("module 0 is flight-terminated (reboot it)",
                                             "module 1 is flight-terminated (reboot it)")
            with pytest.raises(ArmingError, match="module 0 .* refused to switch to offboard"):
                be.arm()  # termination latches
    finally:
        stop_peer(peer, th)


def test_offboard_loss_disarms_the_modules_and_ends_the_flight():
    peer, th = start_peer(14604, 7482, params=(("COM_OF_LOSS_T", 0.1),))
    try:
        with MavlinkBackend(links(14604), U_MAX, ASM.module_rotations, MavlinkSettings(link_timeout=0.1)) as be:
            be.arm()
            hold(be, np.full(8, 0.5 * U_MAX), 0.3)
            assert be.telemetry().motors.min() > 0.4 * U_MAX and be.telemetry().link_ok
            time.sleep(0.3)  # the ground station goes silent: each module disarms by itself (offboard loss)
            assert np.all(peer.sim.telemetry().motors < 0.05 * U_MAX)
            assert not any(m.armed for m in peer.modules)
            # The next heartbeat (<= 1 s) says so, and the flight must not go on with disarmed modules.
            t0 = time.monotonic()
            while be.telemetry().link_ok and time.monotonic() - t0 < 1.5:
                be.send(np.full(8, 0.5 * U_MAX))
                time.sleep(0.005)
            assert not be.telemetry().link_ok
    finally:
        stop_peer(peer, th)


def test_link_loss():
    peer, th = start_peer(14606, 7485)
    try:
        with MavlinkBackend(links(14606), U_MAX, ASM.module_rotations, MavlinkSettings(link_timeout=0.1)) as be:
            be.arm()
            peers.check_link_loss(be, peer, th, 0.1)
    finally:
        stop_peer(peer, th)


def test_vehicle_refuses_offboard_without_a_setpoint_stream():
    """What PX4 does, and why arm() streams setpoints first: a bare mode switch is rejected."""
    peer, th = start_peer(14610, 7483)
    try:
        gcs = mavutil.mavlink_connection("udpout:127.0.0.1:14610", source_system=mw.GCS_SYSTEM_ID,
                                         source_component=mw.GCS_COMPONENT_ID)
        try:
            gcs.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            assert gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=2.0).get_srcSystem() == 1
            gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_DO_SET_MODE, 0, 1, mw.PX4_MAIN_MODE_OFFBOARD,
                                      0, 0, 0, 0, 0)
            ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=2.0)
            assert ack.command == mavutil.mavlink.MAV_CMD_DO_SET_MODE
            assert ack.result == mavutil.mavlink.MAV_RESULT_TEMPORARILY_REJECTED
            gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=2.0)
            assert ack.result == mavutil.mavlink.MAV_RESULT_DENIED and not peer.modules[0].armed
        finally:
            gcs.close()
    finally:
        stop_peer(peer, th)


def test_preflight_and_arm_name_silent_and_weak_modules():
    settings = MavlinkSettings(preflight_timeout=0.3, arm_timeout=0.3)
    with MavlinkBackend(links(14616), U_MAX, ASM.module_rotations, settings) as be:
        assert be.preflight().issues == ("module 0 (udpout:127.0.0.1:14616) does not answer",
                                         "module 1 (udpout:127.0.0.1:14617) does not answer")
        with pytest.raises(ArmingError, match=r"module 0 \(udpout:127.0.0.1:14616\): no heartbeat within 0.3 s"):
            be.arm()
    peer, th = start_peer(14618, 7484, battery_v=3.3)
    try:
        with MavlinkBackend(links(14618), U_MAX, ASM.module_rotations, UNTIMED) as be:
            assert be.preflight().issues == ("module 0 battery 3.30 V < 3.5 V", "module 1 battery 3.30 V < 3.5 V")
    finally:
        stop_peer(peer, th)


def test_unopenable_link():
    with pytest.raises(LinkError, match="cannot open /dev/ttyNOPE"):
        MavlinkBackend(["/dev/ttyNOPE,57600"], U_MAX, ASM.module_rotations[:1]).connect()
    with pytest.raises(ValueError, match="2 links for 1 modules"):
        MavlinkBackend(["udpout:127.0.0.1:1", "udpout:127.0.0.1:2"], U_MAX, ASM.module_rotations[:1])


def _px4_simple_mixers(text: str) -> list[tuple[tuple[float, ...], list[tuple[int, int, tuple[float, ...]]]]]:
    """Parse PX4 simple mixers (``M:``, ``O:``, ``S:`` lines; everything else is comment), scales / 10000."""
    mixers = []
    for line in text.splitlines():
        tag, _, rest = line.partition(":")
        fields = rest.split()
        if tag == "M":
            mixers.append([None, []])
        elif tag == "O":
            mixers[-1][0] = tuple(int(v) / 1e4 for v in fields)
        elif tag == "S":
            mixers[-1][1].append((int(fields[0]), int(fields[1]), tuple(int(v) / 1e4 for v in fields[2:])))
    return [(o, s) for o, s in mixers]


def _scale(scaler: tuple[float, ...], x: float) -> float:
    """PX4's mixer scaler: negative/positive scale, then offset, then clamp to [lower, upper]."""
    neg, pos, offset, lower, upper = scaler
    return min(max((neg if x < 0 else pos) * x + offset, lower), upper)


def test_passthrough_mixer_file_matches_the_wire_convention():
    mixers = _px4_simple_mixers((peers.ROOT / "firmware_params/px4/passthrough_quad.main.mix").read_text())
    assert len(mixers) == 4
    u = np.array([0.0, 0.25, 0.6, 1.0]) * U_MAX
    controls = mw.to_controls(u, U_MAX)
    for q, (out_scaler, inputs) in enumerate(mixers):
        assert [(g, i) for g, i, _ in inputs] == [(mw.ACTUATOR_GROUP, q)]  # output q takes control q alone
        out = _scale(out_scaler, sum(_scale(sc, controls[i]) for _, i, sc in inputs))
        pwm = 1000 + (out + 1) / 2 * (2000 - 1000)  # PX4's PWM driver: [-1, 1] -> [PWM_MAIN_MIN, PWM_MAIN_MAX]
        assert pwm == pytest.approx(mw.to_pwm(u, U_MAX, 1000, 2000)[q], abs=0.5)


@pytest.mark.parametrize("outputs, disarmed", [(900, True), (1300, False)])
def test_a_stale_disarmed_heartbeat_right_after_arming_is_not_a_disarm(outputs, disarmed):
    """A vehicle whose heartbeat, built before it armed, arrives after its arming ACK (PX4 sends them from
    different threads): the backend keeps flying; a disarmed heartbeat a second later ends the flight once the
    vehicle's outputs say so too (PWM_MAIN_DISARM, 900 us); outputs still in the armed range (1300 us) say the
    heartbeat was not the vehicle's state (one forged heartbeat stopped the motors 0.77 m up: hostile campaign
    34)."""
    vehicle = mavutil.mavlink_connection("udpin:127.0.0.1:14650", source_system=1, source_component=1)
    stop = threading.Event()
    disarmed_beat = threading.Event()

    def heartbeat(armed: bool) -> None:
        vehicle.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_QUADROTOR, mavutil.mavlink.MAV_AUTOPILOT_PX4,
                                   mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0, 0, 3)

    def serve() -> None:
        while not stop.is_set():
            msg = vehicle.recv_match(blocking=True, timeout=0.01)
            if msg is None:
                continue
            if msg.get_type() == "HEARTBEAT":
                heartbeat(False)
                vehicle.mav.sys_status_send(0, 0, 0, 0, 4000, -1, -1, 0, 0, 0, 0, 0, 0)
            elif msg.get_type() == "COMMAND_LONG":
                vehicle.mav.command_ack_send(msg.command, mavutil.mavlink.MAV_RESULT_ACCEPTED)
                if msg.command == mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM and msg.param1 == 1:
                    heartbeat(False)  # the stale one
            elif disarmed_beat.is_set():
                heartbeat(False)
                vehicle.mav.servo_output_raw_send(0, 0, *[outputs] * 4, 0, 0, 0, 0)
                disarmed_beat.clear()
            else:
                vehicle.mav.attitude_send(0, 0, 0, 0, 0, 0, 0)  # keeps the link fresh

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    try:
        with MavlinkBackend(["udpout:127.0.0.1:14650"], U_MAX, ASM.module_rotations[:1]) as be:
            be.arm()
            hold(be, np.zeros(4), 0.3)
            assert be.telemetry().link_ok  # the stale disarmed heartbeat was not taken as a disarm
            time.sleep(ARM_GRACE_S)
            disarmed_beat.set()
            hold(be, np.zeros(4), 0.2)
            assert be.telemetry().link_ok != disarmed  # a fresh one is, with the outputs of a disarmed vehicle
    finally:
        stop.set()
        th.join(2)
        vehicle.close()


def test_px4_attitude_round_trip_and_up_in_the_module_frame():
    """PX4 reports the FRD frame in NED; the up direction recovered from its roll and pitch is the ENU world's z
    in the module's FLU frame, for any attitude (checked against R^T e_z)."""
    from groundstation.control.trajectory import euler_zyx, roll_pitch_yaw

    rng = np.random.default_rng(3)
    for _ in range(50):
        rotation = euler_zyx(*rng.uniform(-1.2, 1.2, 2), rng.uniform(-3, 3))
        roll, pitch, _ = roll_pitch_yaw(mw.px4_attitude(rotation))
        np.testing.assert_allclose(mw.up_in_module(roll, pitch), rotation.T @ [0.0, 0.0, 1.0], atol=1e-12)


def test_module_gravity_and_two_links_to_one_vehicle():
    peer, th = start_peer(14590, 7491)
    try:
        with MavlinkBackend(links(14590), U_MAX, ASM.module_rotations, UNTIMED) as be:
            assert be.preflight().ok
            assert 0.0 <= be.link_latency().max() < 0.5  # the simulated PX4 answers TIMESYNC
            state = peer.sim.true_state()
            expected = np.array([(state.rotation @ r).T @ [0.0, 0.0, 1.0] for r in ASM.module_rotations])
            np.testing.assert_allclose(be.module_gravity(), expected, atol=2e-3)
    finally:
        stop_peer(peer, th)
    peer, th = start_peer(14594, 7492)
    try:
        with MavlinkBackend(["udpout:127.0.0.1:14594", "udpout:127.0.0.1:14594"], U_MAX, ASM.module_rotations,
                            MavlinkSettings(preflight_timeout=1.0)) as be:
            issues = be.preflight().issues
        # Both links reach the vehicle at 14594 (it answers whichever sent last): either both hear it and the
        # system ids name the duplicate, or one never hears it.
        assert ("module 0 (udpout:127.0.0.1:14594) and module 1 (udpout:127.0.0.1:14594) are one vehicle (system "
                "id 1): two links reach it") in issues or any(i.endswith("does not answer") for i in issues), issues
    finally:
        stop_peer(peer, th)


@contextlib.contextmanager
def _vehicle(port: int, answer_after: float | None, silent: threading.Event | None = None, answerer: int = 1,
             every: int = 1, attitude_lag: float | None = 0.0, answer_clock: float = 0.0):
    """A PX4-like vehicle on ``port``: heartbeats, battery and attitude; with ``answer_after`` it answers each
    TIMESYNC request that long after it came (and again, a repeat), and sends a forged answer at once (a ``ts1``
    never sent) and requests of its own (``tc1`` 0), none of which may count as a round trip; once ``silent`` is
    set it answers no more (its other streams go on); ``answerer``: the component id its answers come from (1, the
    autopilot; 191, a companion computer on the vehicle); ``every``: it answers one request in that many (a lossy
    link); ``attitude_lag``: its ATTITUDE that much older on its clock than its answers (what a relay answering
    for it and holding the rest back makes of the stream; None: it sends none); ``answer_clock``: its answers' clock
    that far off its own (something else answering). Runs while the block does."""
    vehicle = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    stop = threading.Event()
    due: list[tuple[float, int]] = []
    requests = itertools.count()

    def answer(tc1: int, ts1: int) -> None:
        tc1 += int(answer_clock * 1e9)
        vehicle.mav.srcComponent = answerer
        vehicle.mav.timesync_send(tc1, ts1)
        vehicle.mav.srcComponent = 1

    def serve() -> None:
        while not stop.is_set():
            msg = vehicle.recv_match(blocking=True, timeout=0.002)
            now = time.monotonic()
            for when, ts1 in [d for d in due if d[0] <= now]:
                due.remove((when, ts1))
                for _ in range(2):
                    answer(int(now * 1e9), ts1)
            if msg is None:
                continue
            kind = msg.get_type()
            if kind == "HEARTBEAT":
                vehicle.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_QUADROTOR, mavutil.mavlink.MAV_AUTOPILOT_PX4,
                                           0, 0, 3)
                vehicle.mav.sys_status_send(0, 0, 0, 0, 4000, -1, -1, 0, 0, 0, 0, 0, 0)
                if attitude_lag is not None:  # on the clock its answers carry
                    vehicle.mav.attitude_send(int((now - attitude_lag) * 1e3), 0, 0, 0, 0, 0, 0)
            elif kind == "TIMESYNC" and msg.tc1 == 0 and answer_after is not None and not (silent and silent.is_set()):
                if next(requests) % every:
                    continue
                due.append((now + answer_after, msg.ts1))
                answer(int(now * 1e9), msg.ts1 + 1)  # names no probe
                vehicle.mav.timesync_send(0, int(now * 1e9))  # the vehicle's own request

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    try:
        yield
    finally:
        stop.set()
        th.join(2)
        vehicle.close()


def test_the_round_trip_is_measured_by_timesync_and_bounded_in_preflight():
    """The answer to each probe measures the link; forged, repeated answers and the vehicle's own requests do not.
    Each round trip is a lower bound (to the last read that had not found the answer): a vehicle answering 30 ms
    late reads at least 30 ms less one read's wait (10 ms in preflight)."""
    with (_vehicle(14654, answer_after=0.03),
          MavlinkBackend(["udpout:127.0.0.1:14654"], U_MAX, ASM.module_rotations[:1]) as be):
        issues = be.preflight().issues
        latency = be.link_latency()[0]
        assert 0.019 <= latency < 0.2, latency  # upper: a loaded machine wakes the vehicle late, never early
        assert issues == (f"module 0 (udpout:127.0.0.1:14654) link round trip {latency * 1e3:.0f} ms > 14 ms",)
        assert be.telemetry().link_latency_s[0] >= 0.019  # what the flight is given (probes still answered)


def test_answers_that_stop_are_a_lost_link_not_the_last_round_trip():
    """A vehicle whose TIMESYNC answers stop while its other streams go on (PX4 drops what its full transmit buffer
    cannot take): the link loses everything (a degraded link: the flight lands), not a link as fast as its last
    answers; nor is the silence a round trip (random loss has silences too, and a round trip beyond the stop bound
    stops the motors in the air)."""
    silent = threading.Event()
    with (_vehicle(14658, answer_after=0.0, silent=silent),
          MavlinkBackend(["udpout:127.0.0.1:14658"], U_MAX, ASM.module_rotations[:1],
                         MavlinkSettings(link_timeout=0.1, max_latency=0.5)) as be):
        assert be.preflight().ok and be.link_latency()[0] < 0.1
        silent.set()
        t0 = time.monotonic()
        while time.monotonic() - t0 < 0.8:  # the loss window (0.5 s, ending a link timeout ago) all silent
            be.send(np.zeros(4))
            be.telemetry()
            time.sleep(0.004)
        assert be.telemetry().link_loss[0] > 0.5 and be.link_latency()[0] < 0.1  # all lost (its lower bound)


def test_the_loss_each_way_is_measured_from_the_probes_left_unanswered():
    """A vehicle answering one probe in two: half the round trips lost, 29 % each way (both ways alike), read at
    the low end of its confidence interval."""
    with (_vehicle(14662, answer_after=0.0, every=2),
          MavlinkBackend(["udpout:127.0.0.1:14662"], U_MAX, ASM.module_rotations[:1],
                         MavlinkSettings(link_timeout=0.1, max_latency=0.5)) as be):
        be.preflight()
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.0:
            be.send(np.zeros(4))
            be.telemetry()
            time.sleep(0.004)
        # 29 % each way, read at the low end of its confidence interval (~40 probes): 15-29 %
        assert 0.15 < be.link_loss()[0] <= 1.0 - 0.5 ** 0.5 + 0.02, be.link_loss()


def test_telemetry_held_back_behind_prompt_answers_counts_in_the_round_trip():
    """A relay that answers the probes itself at once and holds the rest back: the answers read 0 ms, but the
    module's own ATTITUDE comes 12 ms older on its clock than they do, and the round trip read counts that way and
    the way there (the V flipped on a relay doing so with 10 ms each way; hostile campaign 29)."""
    with (_vehicle(14664, answer_after=0.0, attitude_lag=0.012),
          MavlinkBackend(["udpout:127.0.0.1:14664"], U_MAX, ASM.module_rotations[:1]) as be):
        issues = be.preflight().issues
        assert 0.010 <= be.held_back()[0] < 0.1 and be.link_latency()[0] >= 0.02, (be.held_back(), issues)
        assert len(issues) == 1 and "link round trip" in issues[0], issues


@pytest.mark.parametrize("port, answers", [
    (14656, {"answer_after": None}),  # none at all
    (14660, {"answer_after": 0.0, "answerer": 191}),  # a companion computer's: only the way to itself
    (14666, {"answer_after": 0.0, "answer_clock": 1.0}),  # on a clock a second off the module's own stamps
    (14668, {"answer_after": 0.0, "attitude_lag": None}),  # no ATTITUDE: no clock of its own to check them on
], ids=["silent", "another-component", "another-clock", "no-clock-to-check"])
def test_a_module_whose_own_answers_do_not_come_is_refused(port, answers):
    """TIMESYNC is broadcast, and anything on the link may answer: only the module's autopilot, on the module's own
    clock, measures the link that flies."""
    with _vehicle(port, **answers), MavlinkBackend([f"udpout:127.0.0.1:{port}"], U_MAX, ASM.module_rotations[:1],
                        MavlinkSettings(preflight_timeout=0.5)) as be:
        assert be.preflight().issues == (f"module 0 (udpout:127.0.0.1:{port}) does not answer TIMESYNC: its "
                                         f"link's round trip cannot be measured",)
        assert np.isnan(be.link_latency()[0]) and be.link_loss()[0] > 0.5


def _gaps(seqs) -> list[int]:
    """The gaps counted for a module whose messages came with MAVLink sequence numbers ``seqs``, in that order."""
    from groundstation.backends.mavlink import _Module

    m = _Module(None)
    for k, seq in enumerate(seqs):
        MavlinkBackend._count_sequence(m, seq, now=k * 1e-3)
    return [gap for _, gap in m.seq_gaps]


def test_the_way_back_s_loss_is_counted_from_the_module_s_sequence_numbers():
    """The gaps in the module's own numbers, mod 256: across the wrap, a duplicate counts nothing, an overtaken
    message takes back its gap (-1: one more came, one fewer missing; 30 % reordered read 10 % lost, campaign 34),
    a gap of 127 counts; a burst of 128-255 lost reads as
    "behind" until four messages in a row go on in order from where the sequence went on (before, every later
    message was taken for an old one and the loss was never counted)."""
    assert _gaps([253, 254, 255, 0, 1]) == [0, 0, 0, 0, 0]  # the wrap loses nothing
    assert _gaps([254, 0, 3]) == [0, 1, 2]
    assert _gaps([10, 11, 11, 12]) == [0, 0, 0]  # a duplicate
    assert _gaps([10, 12, 11, 13]) == [0, 1, -1, 0]  # 11 overtaken: missing when skipped, it came after all
    assert _gaps([10, 12, 11, 11, 13]) == [0, 1, -1, 0]  # and a copy of it: nothing
    assert _gaps([0, 128]) == [0, 127]
    after_burst = [(10 + 200 + k) & 0xFF for k in range(6)]  # 199 lost after 10
    assert _gaps([10, *after_burst]) == [0, 199, 0, 0]  # counted at the fourth in order, then each
    assert _gaps([10, 210, 5, 212]) == [0]  # behind, but not in order: duplicates or overtaken, nothing counted


def test_wilson_lower_bound():
    """The low end of the Wilson interval against its closed form, and exactly 0 for nothing lost."""
    from groundstation.backends.base import wilson_lower

    assert wilson_lower(0, 250, 2.0) == 0.0
    k, n, z = 25, 250, 2.0  # 10 % seen: the bound (Wilson 1927) at 2 sigma
    p = k / n
    expect = (p + z * z / (2 * n) - z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))) / (1 + z * z / n)
    assert wilson_lower(k, n, z) == pytest.approx(expect) and 0.065 < wilson_lower(k, n, z) < 0.1
    assert wilson_lower(250, 250, 2.0) == pytest.approx(1 - 4 / (250 + 4))  # all lost
    assert wilson_lower(-1, 250, 2.0) == 0.0 and wilson_lower(251, 250, 2.0) == wilson_lower(250, 250, 2.0)


def test_a_link_carrying_another_module_s_messages_is_refused_in_preflight():
    """A relay swaps the two links after a first preflight learnt each link's system id: the next preflight hears
    each module on the other's link and refuses, naming it (before, it passed, armed and landed at take-off)."""
    from sim.udp_relay import Faults, UdpRelay

    peer, th = start_peer(14700, 7530)
    relay = UdpRelay(14704, 14700, 2, Faults(swap_after_s=1.5))
    relay_th = threading.Thread(target=relay.run, daemon=True)
    relay_th.start()
    try:
        with MavlinkBackend(links(14704), U_MAX, ASM.module_rotations, UNTIMED) as be:
            assert be.preflight().ok
            time.sleep(1.6)  # past the swap (1.5 s after the relay's first packet)
            issues = be.preflight().issues
        said = [i for i in issues if i.endswith("each link must carry its own module's messages alone")]
        assert len(said) == 1 and "module 0's messages (system id 1) came on module 1's link (udpout:127.0.0.1:14705)" \
            in said[0] and "module 1's messages (system id 2) came on module 0's link" in said[0], issues
    finally:
        relay.stop()
        relay_th.join(2)
        stop_peer(peer, th)
