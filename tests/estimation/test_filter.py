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


def test_the_ground_holds_a_blind_estimate():
    """Told where the ground is, an estimate that the model lets sink stops there (a blind landing)."""
    truth = lambda t: (np.array([0.0, 0.0, 0.3]), np.eye(3))  # noqa: E731
    f = RigidBodyFilter(EstimatorSettings(), MASS)
    _run(f, 1.0, truth)
    f.set_ground(0.05)
    for k in range(500):  # thrust at half the weight, no poses: the model says it falls
        f.predict(1.0 + (k + 1) * DT, np.zeros(3))
        f.command(HOVER / 2)
    assert f.state().position[2] == pytest.approx(0.05) and f.state().velocity[2] == 0.0


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
