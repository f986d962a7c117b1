import numpy as np
import pytest

from groundstation.control.trajectory import (
    LANDING_BRAKE,
    MAX_LANDING_MPS,
    Attitude,
    Circle,
    Figure8,
    FlightPlan,
    Hover,
    Landing,
    Ramp,
    euler_zyx,
    roll_pitch_yaw,
)

TRAJECTORIES = [
    Ramp((0, 0, 0.05), (0.3, -0.2, 1.0), 3.0),
    Landing((0.1, 0.2, 1.0), (0.5, -0.3, 0.1), (0.4, 0.6, 0.0), -0.02, 2.0),
    Circle((0, 0, 1), 0.5, 8.0, 16.0),
    Figure8(0.6, 8.0, 1.0, 16.0),
    FlightPlan((0, 0, 0.05), Figure8(0.6, 8.0, 1.0, 16.0)),
    FlightPlan((0, 0, 0.05), Circle((-0.5, 0, 1), 0.5, 6.0, 12.0)),
]


@pytest.mark.parametrize("traj", TRAJECTORIES, ids=lambda t: type(t).__name__)
def test_derivatives_match_finite_differences(traj):
    h = 1e-5
    duration = traj.duration
    for t in np.linspace(0.01, duration - 0.01, 157):
        sp, before, after = traj(t), traj(t - h), traj(t + h)
        np.testing.assert_allclose(sp.velocity, (after.position - before.position) / (2 * h), atol=1e-5)
        np.testing.assert_allclose(sp.acceleration, (after.velocity - before.velocity) / (2 * h), atol=1e-4)


def test_figure8_is_the_papers_formula():
    f = Figure8(l0=0.6, tc=8.0, h0=1.0, duration=8.0)
    for t in (0.0, 1.3, 5.1):
        w = 2 * np.pi * t / 8.0
        np.testing.assert_allclose(f(t).position, [0.6 * np.sin(w) * np.cos(w), 0.6 * np.sin(w),
                                                   1.0 - 0.2 * np.sin(w)])


def test_plan_is_continuous_and_starts_and_ends_at_rest():
    plan = FlightPlan((0.1, 0.2, 0.05), Figure8(0.6, 8.0, 1.0, 16.0, attitude=Attitude(roll=np.radians(-5))))
    ts = np.arange(0, plan.duration, 0.002)
    sps = [plan(t) for t in ts]
    p = np.array([s.position for s in sps])
    v = np.array([s.velocity for s in sps])
    assert np.max(np.abs(np.diff(p, axis=0))) < 0.01 and np.max(np.abs(np.diff(v, axis=0))) < 0.01
    np.testing.assert_allclose(p[0], (0.1, 0.2, 0.05))
    assert np.linalg.norm(v[0]) == 0 and np.linalg.norm(v[-1]) < 1e-3
    rolls = [roll_pitch_yaw(s.rotation)[0] for s in sps]
    assert rolls[0] == 0 and np.degrees(rolls[len(rolls) // 2]) == pytest.approx(-5) and abs(rolls[-1]) < 1e-9
    assert [name for name, *_ in plan.phases] == ["takeoff", "settle", "track", "hold", "landing"]


def test_euler_round_trip_and_hover():
    r = euler_zyx(0.1, -0.2, 0.3)
    np.testing.assert_allclose(roll_pitch_yaw(r), (0.1, -0.2, 0.3))
    assert np.allclose(Hover((0, 0, 1), 1.0)(0.4).velocity, 0)


@pytest.mark.parametrize("velocity, acceleration", [((0.5, -0.3, 0.1), (0.4, 0.6, 0.0)), ((0.0, 0.0, -0.2), (0, 0, 0)),
                                                    ((-0.7, 0.1, 0.0), (0.0, -1.5, 0.3))])
def test_a_landing_goes_on_from_the_motion_and_comes_to_rest(velocity, acceleration):
    landing = Landing((0.1, 0.2, 1.0), velocity, acceleration, -0.02, 2.0)
    first = landing(0.0)
    np.testing.assert_allclose(first.position, (0.1, 0.2, 1.0))
    np.testing.assert_allclose(first.velocity, velocity)
    np.testing.assert_allclose(first.acceleration, acceleration, atol=1e-12)
    sps = [landing(t) for t in np.linspace(0.0, 2.0, 2001)]
    last = sps[-1]
    np.testing.assert_allclose(last.position, landing.end)
    assert landing.end[2] == -0.02 and np.allclose(last.velocity, 0) and np.allclose(last.acceleration, 0)
    # brakes about as hard as LANDING_BRAKE, or as the reference already accelerated
    a_h = max(float(np.linalg.norm(sp.acceleration[:2])) for sp in sps)
    assert a_h <= 1.1 * max(LANDING_BRAKE, float(np.linalg.norm(acceleration[:2])))
    # and comes to rest no farther than it would at LANDING_BRAKE from its speed (plus what its acceleration adds)
    speed = float(np.linalg.norm(velocity[:2]))
    reach = float(np.linalg.norm(np.subtract(landing.end[:2], (0.1, 0.2))))
    assert reach <= 0.75 * speed ** 2 / LANDING_BRAKE + 0.3 * speed + 0.1 * float(np.linalg.norm(acceleration[:2]))


@pytest.mark.parametrize("landing_s", [0.5, 1.0, 3.0])
def test_a_landing_never_descends_faster_than_its_bound(landing_s):
    """The plan's landing lasts ``landing_s``, or its height over MAX_LANDING_MPS when that is longer (0.86 s from
    0.76 m touched down at 1.64 m/s with an unknown payload): its phase, its reference and its bounds alike."""
    plan = FlightPlan((0.0, 0.0, 0.05), Hover((0.0, 0.0, 1.0), 2.0), takeoff_s=1.0, settle_s=0.5, landing_s=landing_s)
    drop = 1.0 - (0.05 - 0.02)
    expected = max(landing_s, drop / MAX_LANDING_MPS)
    name, start, end = plan.phases[-1]
    assert end - start == pytest.approx(expected)
    assert plan(end).position[2] == pytest.approx(0.03) and plan(start).position[2] == pytest.approx(1.0)
    mean = drop / (end - start)
    assert mean <= MAX_LANDING_MPS + 1e-12 and (mean == pytest.approx(MAX_LANDING_MPS)) == (landing_s < 1.2)
