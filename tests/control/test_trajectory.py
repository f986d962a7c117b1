import math

import numpy as np
import pytest

from groundstation.control.trajectory import (
    LANDING_BRAKE,
    MAX_LANDING_MPS,
    Attitude,
    Circle,
    Descent,
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
    Landing.blind((0.1, 0.2, 1.0), (0.5, -0.3, 0.1), (0.4, 0.6, 0.3),
                  Descent(1.0, 0.1, -0.02, 1.0, 0.5, 0.5, 0.15, 1.5, 0.5, a0=0.3)),
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


BLIND = dict(ground_z=0.05, cruise_mps=1.0, touchdown_mps=0.5, slow_m=0.5, depth_m=0.15, accel_mps2=1.5,
             press_mps2=0.5)


@pytest.mark.parametrize("z0, v0", [(1.6, 0.0), (2.5, 0.0), (1.0, -0.3), (1.0, 0.5), (0.3, 1.8), (0.6, -0.3),
                                    (0.3, 0.0), (0.05, 0.0), (1.0, -1.8), (0.551, -0.9), (0.6, -1.0), (0.25, -1.5),
                                    (-0.2, -0.5)])
def test_a_blind_descent_cruises_high_and_touches_down_at_its_speed(z0, v0):
    """Kinematics recomputed here by integrating the profile's own acceleration and velocity (0.1 ms steps): it
    starts where and as the assembly moves, never exceeds its cruise speed (unless it started faster), changes
    speed at its bound (twice that to stop a climb, and at most that to shed a speed it could not shed at its
    bound by the ground: a start just above the slow height at 1 m/s asked 100-400 m/s^2 before), passes the
    ground at the touchdown speed when it has room to reach it, then speeds up at its press rate, is its depth
    below the ground after its duration (lower only where it brakes harder still) and goes on: the flight ends
    it."""
    d = Descent(z0, v0, **BLIND)
    assert d(0.0)[:2] == pytest.approx((z0, v0))
    blended = Descent(z0, v0, **BLIND, a0=0.8)  # from the start's acceleration into the first piece's, in 0.3 s
    assert blended(0.0) == pytest.approx((z0, v0, 0.8)) and blended(0.3) == pytest.approx(d(0.3))
    dt = 1e-4
    ts = np.arange(0.0, d.duration + 0.3, dt)
    zs, vs, accels = np.array([d(t) for t in ts]).T
    mid = np.array([d(t + dt / 2)[2] for t in ts[:-1]])
    np.testing.assert_allclose(vs[1:], v0 + np.cumsum(mid) * dt, atol=1e-3)
    np.testing.assert_allclose(zs[1:], z0 + np.cumsum(0.5 * (vs[1:] + vs[:-1])) * dt, atol=1e-5)
    ground, slow = BLIND["ground_z"], BLIND["touchdown_mps"]
    end, accel, room = ground - BLIND["depth_m"], BLIND["accel_mps2"], z0 - ground
    forced = (v0 * v0 - slow * slow) / (2 * room) if -v0 > slow and room > 0 else 0.0  # to shed by the ground
    assert accels[-1] == -BLIND["press_mps2"] and d(d.duration)[0] == pytest.approx(d.end_z)
    if z0 > end:  # at its depth, or past it if even at twice its rate it could not shed its speed by then
        overshoots = -v0 > slow and (v0 * v0 - slow * slow) / (4 * accel) > z0 - end
        assert d.end_z < end if overshoots else d.end_z == pytest.approx(end)
    assert -vs[zs >= ground].min(initial=0.0) <= max(BLIND["cruise_mps"], -v0) + 1e-9
    assert np.abs(accels).max() <= (accel if forced <= accel and v0 <= 0 else 2 * accel) + 1e-12
    assert zs.max() == pytest.approx(z0 + max(v0, 0.0) ** 2 / (4 * accel))  # a climb stops at twice the rate
    room_to_touchdown = z0 - BLIND["ground_z"] - (slow ** 2 - v0 ** 2) / (2 * accel)
    if -v0 <= slow and room_to_touchdown > 0:
        at_ground = np.flatnonzero(zs <= BLIND["ground_z"])[0]
        assert vs[at_ground] == pytest.approx(-slow, abs=2e-3)


def test_a_blind_descent_from_high_up_is_quicker_than_the_mean_speed_it_touches_down_at():
    """From 1.6 m: under 2.75 s to its depth, where descending at 0.5 m/s on average (the quintic of the landings
    before) took 3.4 s, and the height's uncertainty grows with the time flown blind to the 2.5th power."""
    d = Descent(1.6, 0.0, **BLIND)
    # 0 -> 1 m/s at 1.5 m/s^2 (0.667 s, 0.333 m), 1 -> 0.5 (0.333 s, 0.25 m), 1 m/s to 0.5 m above the ground (0.467
    # m), 0.5 m/s to the ground (1 s), 0.15 m from 0.5 m/s at 0.5 m/s^2
    expected = 2 / 3 + 1 / 3 + (1.6 - 0.55 - 0.25 - 1 / 3) / 1.0 + 0.5 / 0.5 + (-0.5 + math.sqrt(0.25 + 0.15)) / 0.5
    drop = 1.6 - (BLIND["ground_z"] - BLIND["depth_m"])
    assert d.duration == pytest.approx(expected) and expected < 2.75 and drop / 0.5 == pytest.approx(3.4)
    landing = Landing.blind((0.1, 0.2, 1.6), (0.3, 0.0, 0.0), (0.0, 0.0, 0.0), d)
    assert landing.duration == d.duration and landing.end[2] == d.end_z
    for t in (0.0, 0.4, 1.7, 2.9, 3.5):
        assert landing(t).position[2] == d(t)[0] and landing(t).velocity[2] == d(t)[1]
