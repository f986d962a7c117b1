"""The estimator against motions written here in closed form: what it says at the control time, what it rejects,
what it learns, how its uncertainty grows without poses."""

import math

import numpy as np
import pytest

from groundstation.assembly.module import GRAVITY
from groundstation.estimation.filter import EstimatorSettings, RigidBodyFilter
from groundstation.estimation.measurement import PoseMeasurement
from groundstation.rotations import rotation_angle, rotvec_to_matrix

DT = 1 / 250
MASS = 0.5
HOVER = np.array([0.0, 0.0, MASS * GRAVITY])
"""Body force that holds the mass against gravity while level, N."""
MOCAP_NOISE = (5e-4, math.radians(0.1))
"""Std of the poses' position (m) and attitude (rad): a lab mocap's."""


def _run(f: RigidBodyFilter, seconds: float, truth, gyro=lambda t: np.zeros(3), latency=0.0, force=HOVER,
         every=0.01, pose=None, t0=0.0, noise=MOCAP_NOISE):
    """Fly ``f`` for ``seconds`` at 250 Hz: a pose every ``every`` s with mocap ``noise`` (m, rad std), captured
    ``latency`` before it is handed over (``pose(t)``, as is, instead of the noisy truth when given); returns
    (t, state) per period."""
    rng = np.random.default_rng(1)

    def measured(t):
        p, r = truth(t)
        return p + rng.normal(0.0, noise[0], 3), r @ rotvec_to_matrix(rng.normal(0.0, noise[1], 3))

    out = []
    next_pose = t0
    pending = []
    for k in range(int(round(seconds / DT))):
        t = t0 + (k + 1) * DT
        while next_pose <= t + 1e-12:
            pending.append(next_pose)
            next_pose += every
        f.predict(t, gyro(t))
        while pending and pending[0] + latency <= t + 1e-12:
            tc = pending.pop(0)
            p, r = (pose or measured)(tc)
            f.correct(PoseMeasurement(tc, p, r))
        f.command(force)
        out.append((t, f.state()))
    return out


def test_the_state_is_at_the_control_time_not_the_poses():
    """Flying at 1 m/s with poses 30 ms late: the estimate is where the body is now, not where it was seen."""
    v = np.array([1.0, 0.5, 0.0])
    truth = lambda t: (np.array([0.0, 0.0, 1.0]) + v * t, np.eye(3))  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(position_noise=1e-4), MASS)
    f.command(HOVER)
    out = _run(f, 3.0, truth, latency=0.03)
    t, s = out[-1]
    assert np.linalg.norm(s.position - truth(t)[0]) < 3e-3  # 34 mm behind without the compensation
    assert np.linalg.norm(s.velocity - v) < 0.03  # mocap noise differentiated by the filter: ~2 cm/s


def test_late_gyros_are_carried_to_the_control_time():
    """A 3 Hz pitch oscillation of 60 deg/s amplitude, gyro readings 15 ms old: told the delay, the attitude at the
    control time is 2-3 times closer to the truth than integrating the late readings as if they were current."""
    a, w = math.radians(60.0), 2 * math.pi * 3.0
    angle = lambda t: a / w * (1.0 - math.cos(w * t))  # noqa: E731  (rate a sin(w t))
    truth = lambda t: (np.array([0.0, 0.0, 1.0]), rotvec_to_matrix([0.0, angle(t), 0.0]))  # noqa: E731
    gyro = lambda t: np.array([0.0, a * math.sin(w * (t - 0.015)), 0.0])  # noqa: E731
    errors = {}
    for delay in (0.0, 0.015):
        settings = EstimatorSettings(gyro_delay=delay, gyro_timing=0.0, attitude_noise=math.radians(0.1))
        f = RigidBodyFilter(settings, MASS)
        out = _run(f, 4.0, truth, gyro, latency=0.005)
        errors[delay] = max(math.degrees(rotation_angle(s.rotation, truth(t)[1])) for t, s in out[250:])
    assert errors[0.015] < 0.5 * errors[0.0]
    assert errors[0.0] > 0.3  # what a late gyro costs here without the delay


def test_a_gyro_bias_is_learnt_from_the_poses():
    bias = np.array([0.02, -0.01, 0.015])
    truth = lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3))  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    out = _run(f, 20.0, truth, gyro=lambda t: bias)
    assert np.allclose(f.estimate().gyro_bias, bias, atol=2e-3)
    assert np.allclose(out[-1][1].omega, 0.0, atol=2e-3)  # the body rate handed to the controller: unbiased


def test_the_model_acceleration_and_a_thrust_map_error():
    """The command asks for 1 m/s^2 up, the body gets 1.5 (its thrust is 5 % stronger than the model says): the
    velocity follows, and the missing 0.5 m/s^2 is learnt as the disturbance."""
    truth = lambda t: (np.array([0.0, 0.0, 0.75 * t * t]), np.eye(3))  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    out = _run(f, 3.0, truth, force=MASS * np.array([0.0, 0.0, GRAVITY + 1.0]))
    t, s = out[-1]
    assert s.velocity[2] == pytest.approx(1.5 * t, abs=0.02)
    assert f.estimate().disturbance[2] == pytest.approx(0.5, abs=0.05)


def test_an_outlier_is_rejected_and_counted_the_estimate_unmoved():
    truth = lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3))  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    _run(f, 1.0, truth)
    assert not f.correct(PoseMeasurement(1.0, np.array([1.0, 0.0, 1.0]), np.eye(3)))
    assert f.rejected == 1 and f.last_rejection == "position 100.0 cm off the estimate"
    assert np.linalg.norm(f.state().position - [0.0, 0.0, 1.0]) < 1e-3 and not f.fault()
    assert not f.correct(PoseMeasurement(1.0, np.array([0.0, 0.0, 1.0]), rotvec_to_matrix([0.2, 0.0, 0.0])))
    assert f.last_rejection.startswith("attitude 11.") and f.last_rejection.endswith(" deg off the gyros' prediction")
    assert not f.correct(PoseMeasurement(1.0, np.array([np.nan, 0.0, 1.0]), np.eye(3)))
    assert f.last_rejection == "not finite" and f.rejected == 3


RATE = math.radians(30.0)
"""The body's yaw rate in the frozen-pose tests, rad/s."""


def _turning(t):
    return np.array([0.0, 0.0, 1.0]), rotvec_to_matrix([0.0, 0.0, RATE * t])


def _first_fault(pose, seconds: float) -> tuple[float | None, str]:
    """Flight time of the first fault of a body turning at :data:`RATE` whose poses come from ``pose``."""
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    for t, _ in _run(f, seconds, _turning, gyro=lambda t: np.array([0.0, 0.0, RATE]), pose=pose):
        if f.fault():
            return t, f.fault()
    return None, ""


def test_a_frozen_pose_while_the_gyros_turn_is_a_fault_within_100_ms():
    """From 2 s on the poses keep coming, freshly stamped, with the pose of 2 s."""
    found, why = _first_fault(lambda t: _turning(min(t, 2.0)), 3.0)
    assert found is not None and found - 2.0 <= 0.1, found
    assert why.startswith("every pose rejected for ") and "a frozen stream" in why


def test_poses_that_stop_turning_while_the_gyros_turn_are_a_fault():
    """Not frozen to the bit (fresh noise on a pose that no longer turns: a stuck tracker): the gyros say 30 deg/s,
    the poses say none; they disagree beyond the attitude gate and stay rejected until the fault."""
    rng = np.random.default_rng(2)
    stuck = lambda t: (_turning(min(t, 2.0))[0] + rng.normal(0, 5e-4, 3),  # noqa: E731
                       _turning(min(t, 2.0))[1] @ rotvec_to_matrix(rng.normal(0, 0.0017, 3)))
    found, why = _first_fault(stuck, 4.0)
    assert found is not None and found - 2.0 <= 0.5, found
    assert "deg off the gyros' prediction" in why


@pytest.mark.parametrize("shove_m, over_s", [(0.1, 0.05), (0.15, 0.05), (0.3, 0.1)])
def test_a_shove_the_model_did_not_see_is_followed(shove_m, over_s):
    """The body shoved sideways by ``shove_m`` in ``over_s`` (2-3 m/s: a knock), stopping dead: its poses are ones
    it could have reached, the gate opens to them before the fault, and the estimate follows within a few mm (the
    disturbance inflated as much as the velocity took up the 3 m/s shove: a fault, then a blind estimate that ran
    24 m in 2 s)."""
    def shoved(t):
        return np.array([shove_m * min(max(t - 3.0, 0.0) / over_s, 1.0), 0.0, 2.5]), np.eye(3)

    f = RigidBodyFilter(EstimatorSettings(), MASS)
    _run(f, 3.0, shoved)
    out = _run(f, 2.0, shoved, t0=3.0)
    assert not f.fault()
    assert max(abs(st.position[0] - shoved(t)[0][0]) for t, st in out[50:]) < 0.005


@pytest.mark.parametrize("weights", [1.2, 2.0])
def test_an_assembly_tied_down_is_where_its_poses_say(weights):
    """Thrust of 1.2 and 2 times the weight on an assembly tied to the ground: the disturbance learns the tether
    (not inflated like the velocity, it learnt too slowly: 5-7 cm off for seconds)."""
    ground = lambda t: (np.array([0.0, 0.0, 0.05]), np.eye(3))  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    _run(f, 2.0, ground, force=np.zeros(3))
    out = _run(f, 2.0, ground, force=HOVER * weights, t0=2.0)
    assert not f.fault()
    assert max(abs(st.position[2] - 0.05) for _, st in out[-100:]) < 0.005


def test_a_body_a_metre_off_is_never_fused_and_the_blind_estimate_stays_certain():
    """From 2 s the poses are another body's, 0.8 m off and moving as smoothly as the genuine one (a swap, a forger
    with the source's id). The bounded inflation never opens the gate that wide (unbounded, it fused the other body
    after eight rejections), the fault comes, and no pose is fused after it; the estimate stays on the true body
    (at rest), its position uncertainty that of a blind estimate, not of the inflated one (which passed the blind
    landing's 0.5 m bound in 0.36 s)."""
    rng = np.random.default_rng(3)
    truth = lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3))  # noqa: E731

    def other(t):
        p = np.array([0.8 + 0.1 * t, 0.0, 1.0]) if t >= 2.0 else truth(t)[0]
        return p + rng.normal(0.0, MOCAP_NOISE[0], 3), np.eye(3)

    f = RigidBodyFilter(EstimatorSettings(), MASS)
    states = _run(f, 2.0, truth, pose=other)
    assert not f.fault() and f.last_fused_t > 1.98  # the genuine poses were fused
    states += _run(f, 1.0, truth, pose=other, t0=2.0)
    assert f.fault().startswith("every pose rejected for ") and "cm off the estimate" in f.fault()
    assert f.last_fused_t < 2.0
    assert max(np.linalg.norm(st.position - [0.0, 0.0, 1.0]) for _, st in states) < 0.01
    assert f.estimate().position_sigma < 0.1  # 1 s blind


def test_after_the_fault_the_uncertainty_is_that_of_an_estimate_that_never_saw_the_rejected_poses():
    """From 2 s the poses are 12 cm off (soon a place it could have reached: each rejection then inflates the
    covariance); once the fault latches the inflation goes, and what is left is exactly the covariance of a twin
    that had no pose since 2 s, process noise included (undone by division, it was 5-23 % low)."""
    truth = lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3))  # noqa: E731
    rng = np.random.default_rng(4)
    off = lambda t: (np.array([0.12, 0.0, 1.0]) + rng.normal(0.0, MOCAP_NOISE[0], 3), np.eye(3))  # noqa: E731
    judged, twin = RigidBodyFilter(EstimatorSettings(), MASS), RigidBodyFilter(EstimatorSettings(), MASS)
    for f in (judged, twin):
        _run(f, 2.0, truth)
    inflated = []
    for k in range(125):  # 0.5 s
        t = 2.0 + (k + 1) * DT
        for f in (judged, twin):
            f.predict(t, np.zeros(3))
        if k % 2 == 0:
            judged.correct(PoseMeasurement(t, *off(t)))
        if not judged.fault():
            inflated.append(judged.estimate().position_sigma / twin.estimate().position_sigma)
        for f in (judged, twin):
            f.command(HOVER)
    assert "cm off the estimate" in judged.fault() and judged.last_fused_t <= 2.0 + 1e-9
    assert max(inflated) > 2.0  # inflated, then the fault
    assert judged.estimate().position_sigma == pytest.approx(twin.estimate().position_sigma, rel=1e-12)
    assert judged.state().position == pytest.approx(twin.state().position, abs=1e-12)


def test_poses_taken_back_leave_the_estimate_of_a_twin_that_never_saw_them():
    """From 2 s a forger's poses drag the body down at 0.5 m/s (each within the gates); 60 ms later they are found
    out and taken back: position, velocity and disturbance are a twin's that had no pose since 2 s (to what the
    attitude's kept corrections change in the model's acceleration), its uncertainty too, and its age counts from
    the last genuine pose."""
    truth = lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3))  # noqa: E731
    forged, twin, kept = (RigidBodyFilter(EstimatorSettings(), MASS) for _ in range(3))
    for f in (forged, twin, kept):
        _run(f, 2.0, truth)
    last_genuine = forged.last_fused_t
    for k in range(15):  # 60 ms
        t = 2.0 + (k + 1) * DT
        for f in (forged, twin, kept):
            f.predict(t, np.zeros(3))
        if k % 2 == 0:
            sunk = (np.array([0.0, 0.0, 1.0 - 0.5 * (t - 2.0)]), np.eye(3))
            forged.correct(PoseMeasurement(t, *sunk))
            kept.correct(PoseMeasurement(t, *sunk))
        for f in (forged, twin, kept):
            f.command(HOVER)
    assert kept.fused == forged.fused and kept.state().velocity[2] < -0.05 and kept.disturbance > 0.2  # learnt
    assert forged.forget_since(2.0 + DT / 2) == 8 and forged.forgotten == 8  # not the genuine pose at 2 s
    assert forged.last_fused_t == last_genuine
    assert forged.state().position == pytest.approx(twin.state().position, abs=1e-5)  # the forger: 3 cm
    assert forged.state().velocity == pytest.approx(twin.state().velocity, abs=5e-4)  # kept: 0.01 deg of tilt
    assert forged.estimate().disturbance == pytest.approx(twin.estimate().disturbance, abs=1e-6)
    assert forged.estimate().velocity_sigma == pytest.approx(twin.estimate().velocity_sigma, rel=1e-4)
    # The position's includes the attitude's term for a body flown blind, and the attitude kept what it learnt.
    assert forged.estimate().position_sigma == pytest.approx(twin.estimate().position_sigma, rel=0.02)
    assert forged.forget_since(2.0 + DT / 2) == 0  # nothing left to take back


def test_a_poses_attitude_disagreement_is_reported_with_its_capture_time():
    """A pose 3 deg off the gyros' attitude (rejected for it): the filter says how far off, and when it was
    captured; poses that are no longer compared leave it as it was."""
    truth = lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3))  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    _run(f, 1.0, truth)
    seen, off = f.attitude_seen
    assert seen == pytest.approx(1.0) and off < math.radians(0.5)  # the mocap's noise (0.1 deg)
    f.predict(1.0 + DT, np.zeros(3))
    tilted = rotvec_to_matrix([math.radians(3.0), 0.0, 0.0])
    assert not f.correct(PoseMeasurement(1.0 + DT, np.array([0.0, 0.0, 1.0]), tilted))
    seen, off = f.attitude_seen
    assert seen == 1.0 + DT and math.degrees(off) == pytest.approx(3.0, abs=0.3)


def test_without_poses_the_uncertainty_grows_and_shrinks_again_when_they_return():
    truth = lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3))  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    _run(f, 2.0, truth)
    before = f.estimate().position_sigma
    grow = []
    for k in range(500):  # 2 s without a pose
        f.predict(2.0 + (k + 1) * DT, np.zeros(3))
        f.command(HOVER)
        grow.append(f.estimate().position_sigma)
    assert before < 2e-3 and all(b > a for a, b in zip(grow[:-1], grow[1:], strict=True))
    assert grow[-1] > 10 * before and f.age(4.0) > 2.0 - 1e-9
    _run(f, 0.1, truth, t0=4.0)
    assert f.estimate().position_sigma < 2e-3 and f.rejected == 0 and f.age(4.1) < 0.02


def test_the_poses_own_rate_and_its_end_with_the_poses():
    """The rate the poses alone show (the referee between two gyros): a body turning at 1 rad/s about a tilted
    axis, with 0.1 deg of mocap noise, read within 0.2 rad/s from 40 ms of poses (the disagreements it settles are
    over 0.5 rad/s); none once the newest is over 0.1 s old."""
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    assert f.pose_rate(0.0) is None  # no poses yet
    out = _run(f, 1.0, lambda t: (np.array([0.0, 0.0, 1.0]), rotvec_to_matrix(axis * t)), gyro=lambda t: axis)
    now = out[-1][0]
    assert np.linalg.norm(f.pose_rate(now) - axis) < 0.2
    assert f.pose_rate(now + 0.11) is None  # poses that stopped say nothing about the rate now


def test_a_flight_with_every_event_follows_the_truth_and_counts_each_event():
    """A body flying a curve and turning about a tilted axis, the command that flies it, biased noisy gyros at 250 Hz
    and poses at 100 Hz (6-9 ms latency), with an outlier, a frozen repeat, a pose too old for the history, a 0.3 s
    outage, then a blind descent onto the ground it is told: the estimate stays on the truth, computed here in
    closed form, and each event is counted as what it is."""
    rng = np.random.default_rng(3)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    r0 = rotvec_to_matrix([0.05, -0.02, 0.4])

    def truth(t):  # position, velocity, acceleration, rotation, body rate
        w = np.array([1.2, 2.4, 0.8])
        amp = np.array([0.5, 0.3, 0.1])
        p = amp * np.sin(w * t) + [0.0, 0.0, 1.0]
        return (p, amp * w * np.cos(w * t), -amp * w * w * np.sin(w * t),
                r0 @ rotvec_to_matrix(axis * 0.3 * math.sin(2.0 * t)), axis * 0.6 * math.cos(2.0 * t))

    bias = np.array([0.01, -0.02, 0.015])
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    captures = [0.002 + 0.01 * i for i in range(350) if not 2.5 <= 0.002 + 0.01 * i < 2.8]  # poses until 3.5 s
    pending = [(tc + rng.uniform(0.006, 0.009), tc) for tc in captures]
    handed, errors, sigma, blind_from = 0, [], {}, None
    for k in range(1, 1000):  # 4 s
        t = k * DT
        p, v, a, r, omega = truth(t)
        f.predict(t, omega + bias + rng.normal(0.0, 0.002, 3))
        while pending and pending[0][0] <= t:
            tc = pending.pop(0)[1]
            p_c, _, _, r_c, _ = truth(tc)
            m = PoseMeasurement(tc, p_c + rng.normal(0.0, 5e-4, 3), r_c @ rotvec_to_matrix(rng.normal(0.0, 0.0017, 3)))
            handed += 1
            if abs(tc - 1.502) < 1e-9:
                assert not f.correct(PoseMeasurement(tc, m.position + [0.3, 0.0, 0.0], m.rotation))
                assert f.last_rejection == "position 30.0 cm off the estimate"
            if abs(tc - 1.702) < 1e-9:
                assert f.correct(m)
                assert not f.correct(PoseMeasurement(tc + 0.005, m.position, m.rotation))
                assert f.last_rejection == "the same pose again, to the last bit: a frozen stream"
                continue
            if abs(tc - 2.002) < 1e-9:
                p_old, _, _, r_old, _ = truth(tc - 0.3)
                assert not f.correct(PoseMeasurement(tc - 0.3, p_old, r_old)) and f.late == 1
            assert f.correct(m), (tc, f.last_rejection)
        if t >= 3.5:  # no more poses: the model (half the weight's thrust) has it fall at g/2
            if blind_from is None:
                blind_from = (t, f.state().velocity[2])
            f.command(MASS * r.T @ (a + [0.0, 0.0, GRAVITY]) / 2)
        else:
            f.command(MASS * r.T @ (a + [0.0, 0.0, GRAVITY]))
        s = f.state()
        if 0.5 <= t < 3.5:
            errors.append((np.linalg.norm(s.position - p), np.linalg.norm(s.velocity - v),
                           math.degrees(rotation_angle(s.rotation, r)), np.linalg.norm(s.omega - omega)))
        if abs(t - 2.5) < DT / 2 or abs(t - 2.8) < DT / 2:
            sigma[round(t, 1)] = f.estimate().position_sigma
    errors = np.array(errors)
    # position (m), velocity (m/s), attitude (deg) and body rate (rad/s) errors; the outage in the largest
    assert np.all(np.percentile(errors, 95, axis=0) < [2e-3, 0.02, 0.25, 0.015])
    assert np.all(errors.max(axis=0) < [5e-3, 0.03, 0.3, 0.02])
    assert np.allclose(f.estimate().gyro_bias, bias, atol=2e-3)
    assert sigma[2.8] > 3 * sigma[2.5]
    assert (f.rejected, f.late, f.fused) == (2, 1, handed) and f.fault() == ""
    s = f.state()
    assert isinstance(s.position, np.ndarray) and s.rotation.shape == (3, 3) and s.omega.shape == (3,)
    t_blind, vz_blind = blind_from
    assert s.velocity[2] == pytest.approx(vz_blind - GRAVITY / 2 * (f.estimate().t - t_blind), abs=0.02)
    e = f.estimate()
    assert e.t == pytest.approx(999 * DT) and e.gyro_bias.shape == (3,) and e.disturbance.shape == (3,)
    assert f.innovation_position.shape == (3,) and f.innovation_attitude.shape == (3,)


def test_a_stale_gyro_reading_is_not_integrated_and_the_poses_take_the_attitude_back():
    """Pitching at 110 deg/s, the gyro packets stop for 100 ms (the reading held, getting older) while the body
    stops turning: integrated on, the held reading would turn the estimate 11 deg past the body, beyond the
    attitude gate for every later pose (the real-firmware flip). Stale after ``gyro_stale_s``: the attitude is held,
    its uncertainty grows, the next poses are fused and the estimate is back on the body."""
    rate, t_stop, gap = math.radians(110.0), 1.0, 0.1
    angle = lambda t: rate * min(t, t_stop)  # noqa: E731
    truth = lambda t: (np.array([0.0, 0.0, 1.0]), rotvec_to_matrix([0.0, angle(t), 0.0]))  # noqa: E731
    gyro = lambda t: np.array([0.0, rate if t < t_stop + gap else 0.0, 0.0])  # noqa: E731  (held through the gap)
    age = lambda t: max(t - t_stop, 0.0) if t < t_stop + gap else 0.0  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    rng = np.random.default_rng(3)
    errors, rejected_before = [], None
    next_pose = 0.0
    for k in range(int(round(1.6 / DT))):
        t = (k + 1) * DT
        f.predict(t, gyro(t) + rng.normal(0.0, 1e-3, 3), age(t))
        while next_pose <= t - 0.005 + 1e-12:  # poses 5 ms late, 100 Hz
            p, r = truth(next_pose)
            f.correct(PoseMeasurement(next_pose, p + rng.normal(0, 5e-4, 3), r @ rotvec_to_matrix(
                rng.normal(0.0, math.radians(0.1), 3))))
            next_pose += 0.01
        f.command(HOVER)
        if abs(t - t_stop) < DT / 2:
            rejected_before = f.rejected
        if f.initialized:
            errors.append((t, math.degrees(rotation_angle(f.state().rotation, truth(t)[1]))))
    in_gap = max(e for t, e in errors if t_stop <= t < t_stop + gap)
    after = max(e for t, e in errors if t >= t_stop + gap + 0.1)
    assert in_gap < 4.0  # held after 30 ms: ~3.3 deg at most, not 11
    assert after < 0.5 and f.fault() == ""
    assert f.rejected - rejected_before <= 2  # the poses in and after the gap are fused


def _turning_at(rate: np.ndarray):
    """A body turning at ``rate`` (rad/s, body frame) from level, at 1 m."""
    return lambda t: (np.array([0.0, 0.0, 1.0]), rotvec_to_matrix(rate * t))


def test_without_gyros_the_poses_give_the_attitude_and_the_rate():
    """The gyros lost (NaN, as :class:`GyroAgreement` hands on, with the age of the last usable reading) while the
    body turns at 1 rad/s: the attitude follows the poses within 0.5 deg, and the rate learnt from them is the
    true one on average (not zero, not a stuck reading's); a usable reading again brings the gyros back."""
    rate = np.array([0.3, -0.5, 0.8])
    truth = _turning_at(rate)
    f = RigidBodyFilter(EstimatorSettings(attitude_noise=math.radians(0.1)), MASS)
    lost_at = 1.0
    gyro = lambda t: rate if t < lost_at else np.full(3, np.nan)  # noqa: E731
    out = _run(f, 0.99, truth, gyro)
    rng = np.random.default_rng(2)
    for k in range(int(round(1.0 / DT))):  # the gyros lost, the age growing: predict by hand
        t = lost_at + k * DT
        f.predict(t, gyro(t), gyro_age=t - (lost_at - DT))
        if k % 2 == 0:  # poses at 125 Hz
            p, r = truth(t)
            f.correct(PoseMeasurement(t, p, r @ rotvec_to_matrix(rng.normal(0.0, MOCAP_NOISE[1], 3))))
        out.append((t, f.state()))
    after = [(t, s) for t, s in out if t >= lost_at + 0.2]
    assert max(math.degrees(rotation_angle(s.rotation, truth(t)[1])) for t, s in after) < 0.5
    errors = np.array([s.omega - rate for _, s in after])
    # A rate from 0.1 deg poses at 125 Hz: unbiased, and noisy (lost_rate_walk trades its noise for its lag)
    assert np.all(np.abs(errors.mean(axis=0)) < 0.05) and np.sqrt((errors ** 2).sum(axis=1).mean()) < 0.35
    f.predict(2.0 + DT, rate * 1.0001, gyro_age=0.0)
    np.testing.assert_allclose(f.state().omega, rate, atol=0.03)  # the gyros' again, less the bias they had


@pytest.mark.parametrize("why", ["attitude", "position"])
def test_lost_gyros_take_back_a_fault_of_poses_rejected_for_their_attitude_alone(why):
    """A gyro stuck at zero holds the estimate while the poses turn: they are rejected as off the gyros'
    prediction and the fault latches; told the gyros are lost, the filter takes it back and fuses the poses. A
    fault of poses whose positions were off (a swapped body) stays."""
    rate = np.array([0.0, 3.0, 0.0])
    truth = _turning_at(rate)
    if why == "position":
        truth = lambda t, _r=truth: (_r(t)[0] + [0.0, 0.0, 0.5 if t > 0.5 else 0.0], _r(t)[1])  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    _run(f, 0.5, lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3)))
    _run(f, 0.2, truth, t0=0.5)  # the gyros read 0 while the poses turn (or jump 0.5 m)
    assert f.fault().startswith("every pose rejected")
    f.gyros_lost(since=0.6)  # found after the run began: not the gyros' doing
    assert f.fault().startswith("every pose rejected")
    f.gyros_lost(since=0.5)
    assert (f.fault() == "") == (why == "attitude")


def test_without_gyros_or_poses_the_attitude_is_held_and_unobserved():
    """The gyros lost, then no pose for 200 ms: the attitude is held (turned on at the rate learnt, it spun the V
    over), :attr:`attitude_unobserved` says so, its uncertainty grows, and the first pose after is fused."""
    rate = np.array([0.0, 0.0, 0.8])  # a yaw: the hovering thrust stays vertical
    truth = _turning_at(rate)
    f = RigidBodyFilter(EstimatorSettings(attitude_noise=math.radians(0.1)), MASS)
    _run(f, 0.99, truth, lambda t: rate)
    for k in range(int(round(0.5 / DT))):  # gyros lost at 1 s; poses until 1.2 s, none until 1.4 s, then again
        t = 1.0 + k * DT
        f.predict(t, np.full(3, np.nan), gyro_age=t - (1.0 - DT))
        if k % 2 == 0 and not 1.2 < t < 1.4:
            p, r = truth(t)
            fused = f.correct(PoseMeasurement(t, p, r))
            if t > 1.4:
                assert fused, (t, f.last_rejection)
        if t == pytest.approx(1.2 + 10 * DT):  # 40 ms into the gap
            assert f.attitude_unobserved
            held = f.state().rotation
        if 1.24 < t < 1.4:
            np.testing.assert_allclose(f.state().rotation, held)  # held, not turned on
        if 1.1 < t < 1.2:
            assert not f.attitude_unobserved
    assert not f.attitude_unobserved
    assert math.degrees(rotation_angle(f.state().rotation, truth(1.5 - DT)[1])) < 1.0


def test_the_rotors_lag_behind_a_thrust_step_as_a_first_order_lag():
    """With ``thrust_lag`` tau, a thrust step of dF (no poses) changes the velocity by dF/m (T - tau (1 - e^-T/tau))
    after T s, the closed form of the lagged force's integral; without the lag (tau = 0) by dF/m T."""
    hold = lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3))  # noqa: E731
    for tau in (0.0, 0.02):
        f = RigidBodyFilter(EstimatorSettings(thrust_lag=tau), MASS)
        _run(f, 0.5, hold)
        t0, v0 = f.estimate().t, f.state().velocity[2]
        step = np.array([0.0, 0.0, 1.0])  # N
        for k in range(25):  # 0.1 s, no poses
            f.command(HOVER + step)
            f.predict(t0 + (k + 1) * DT, np.zeros(3))
        seconds = 25 * DT
        lagged = seconds - tau * (1.0 - math.exp(-seconds / tau)) if tau else seconds
        assert f.state().velocity[2] - v0 == pytest.approx(1.0 / MASS * lagged, rel=1e-3)  # the lag: 20 %


def test_a_disturbance_set_acts_from_then_on():
    """``set_disturbance``: no jump (the position and velocity as they were), then the estimate moves by what the
    difference does: dd tau after tau s, against a twin left alone."""
    hold = lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3))  # noqa: E731
    f, twin = RigidBodyFilter(EstimatorSettings(), MASS), RigidBodyFilter(EstimatorSettings(), MASS)
    for g in (f, twin):
        _run(g, 1.0, hold)
    before, d = f.state(), np.array(f.disturbance_vector)
    f.set_disturbance((d[0], d[1], d[2] - 0.5))
    assert f.disturbance_vector[2] == pytest.approx(d[2] - 0.5)
    np.testing.assert_array_equal(f.state().position, before.position)
    np.testing.assert_array_equal(f.state().velocity, before.velocity)
    for k in range(50):  # 0.2 s blind
        for g in (f, twin):
            g.command(HOVER)
            g.predict(1.0 + (k + 1) * DT, np.zeros(3))
    assert f.state().velocity[2] - twin.state().velocity[2] == pytest.approx(-0.5 * 50 * DT, rel=1e-9)


def test_the_tilts_share_of_a_blind_estimates_position_std_matches_its_model_sampled():
    """The horizontal std's attitude share with the gyros integrated throughout: the double integral of g theta,
    theta(tau) = theta0 - b0 tau + w(tau) (angle and bias errors as the last pose left them, correlated; the gyros'
    noise a random walk), sampled 40000 times here against the closed form the filter uses."""
    hold = lambda t: (np.array([0.0, 0.0, 1.0]), np.eye(3))  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    _run(f, 0.3, hold)  # early: the bias barely learnt, as in a take-off
    tt, tb, bb = f._pa_fused
    tau, steps = 2.0, 400
    h = tau / steps
    rng = np.random.default_rng(3)
    cov = np.array([[tt, tb], [tb, bb]])
    theta0, b0 = rng.multivariate_normal([0.0, 0.0], cov, 40000).T
    walk = np.cumsum(rng.normal(0.0, f.settings.gyro_noise * math.sqrt(h), (steps, 40000)), axis=0)
    bias_walk = np.cumsum(rng.normal(0.0, f.settings.gyro_bias_walk * math.sqrt(h), (steps, 40000)), axis=0)
    times = np.arange(1, steps + 1)[:, None] * h
    theta = theta0 - b0 * times + walk - np.cumsum(bias_walk, axis=0) * h
    x = GRAVITY * np.cumsum(np.cumsum(theta, axis=0) * h, axis=0)[-1] * h
    assert f._tilt_drift(tau, 0.0) == pytest.approx(float(np.std(x)), rel=0.03)
    # and well under the bound before (the attitude's std at the end, as if it had been so throughout)
    coarse = 0.5 * GRAVITY * math.sqrt(tt - 2 * tau * tb + tau * tau * bb + f.settings.gyro_noise ** 2 * tau) * tau ** 2
    assert f._tilt_drift(tau, 0.0) < coarse / 2
