from dataclasses import replace

import numpy as np
import pytest

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.control.geometric import Gains, adapt_attitude, control, delay_limited, free_angles
from groundstation.control.model import ControlModel
from groundstation.control.state import RigidState, Setpoint
from groundstation.control.trajectory import euler_zyx, roll_pitch_yaw

P = ModuleParams()
V = Assembly(Topology.from_code("oS"), P, np.radians([22.5, 0, -45]))  # hinge about x: no force along body x
FLAT = Assembly(Topology.from_code("oE"), P, np.zeros(3))
FULL = Assembly(Topology.from_code("oES"), P, np.radians([0, 10, -30, 40]))


def test_actuation_classes():
    assert ControlModel.from_assembly(V).actuation == "force-deficient-1"
    np.testing.assert_allclose(np.abs(ControlModel.from_assembly(V).null_force[0]), [1, 0, 0], atol=1e-9)
    assert ControlModel.from_assembly(FLAT).actuation == "force-deficient-2"
    assert ControlModel.from_assembly(FULL).actuation == "full"


def test_the_angles_each_assembly_leaves_to_the_force():
    """What adapt_attitude frees: the V's pitch (its roll and yaw held), a flat assembly's roll and pitch, none of a
    fully actuated one's; checked on what the adaptation does with a sideways force."""
    assert free_angles(ControlModel.from_assembly(V)) == ("pitch",)
    assert free_angles(ControlModel.from_assembly(FLAT)) == ("roll", "pitch")
    assert free_angles(ControlModel.from_assembly(FULL)) == ()
    target = euler_zyx(np.radians(-5.0), 0.0, 0.3)
    for asm in (V, FLAT, FULL):
        model = ControlModel.from_assembly(asm)
        moved = np.abs(np.subtract(roll_pitch_yaw(adapt_attitude(target, np.array([1.5, -1.0, 5.0]), model)),
                                   roll_pitch_yaw(target))) > 1e-6
        moved = {name for name, m in zip(("roll", "pitch", "yaw"), moved, strict=True) if m}
        tilted = {"yaw"} if asm is FLAT else set()  # a flat assembly keeps its heading, not its ZYX yaw
        assert moved == set(free_angles(model)) | tilted


@pytest.mark.parametrize("asm", [V, FULL, FLAT], ids=["V", "full", "flat"])
def test_hover_equilibrium_wrench(asm):
    model = ControlModel.from_assembly(asm)
    sp = Setpoint(np.array([0, 0, 1.0]), np.zeros(3), np.zeros(3), np.eye(3))
    out = control(RigidState(position=np.array([0, 0, 1.0])), sp, model, Gains())
    np.testing.assert_allclose(out.wrench, [0, 0, asm.mass * 9.81, 0, 0, 0], atol=1e-9)


@pytest.mark.parametrize("roll_deg", [0.0, -5.0])
def test_v_adaptation_holds_roll_and_makes_force_producible(roll_deg):
    model = ControlModel.from_assembly(V)
    target = euler_zyx(np.radians(roll_deg), 0.0, 0.3)
    rng = np.random.default_rng(1)
    for _ in range(50):
        f = np.array([*rng.uniform(-2, 2, 2), rng.uniform(3, 7)])
        rd = adapt_attitude(target, f, model)
        roll, _pitch, yaw = roll_pitch_yaw(rd)
        assert roll == pytest.approx(np.radians(roll_deg)) and yaw == pytest.approx(0.3)
        assert abs((rd @ model.null_force[0]) @ f) < 1e-9  # no force needed along the missing direction


def test_flat_adaptation_aligns_thrust_with_force():
    model = ControlModel.from_assembly(FLAT)
    f = np.array([1.0, -0.5, 5.0])
    rd = adapt_attitude(euler_zyx(0, 0, 0.4), f, model)
    np.testing.assert_allclose(rd[:, 2], f / np.linalg.norm(f), atol=1e-12)
    assert roll_pitch_yaw(rd)[2] == pytest.approx(0.4, abs=0.1)


def test_attitude_error_sign_restores():
    model = ControlModel.from_assembly(FULL)
    tilted = RigidState(position=np.array([0, 0, 1.0]), rotation=euler_zyx(0.1, 0, 0))
    sp = Setpoint(np.array([0, 0, 1.0]), np.zeros(3), np.zeros(3), np.eye(3))
    out = control(tilted, sp, model, Gains())
    assert out.wrench[3] < 0 and out.attitude_error[0] > 0  # positive roll error -> negative roll torque


def test_the_reference_attitude_turns_at_the_freed_pitch_rate_of_the_figure8():
    """The V (no force along body x) holding roll and yaw at 0 must pitch to theta = atan(a_x / (g + a_z)) to
    produce the reference's force: its reference attitude turns at d theta / dt about body y (what the flight feeds
    forward), recomputed here from the figure-8's accelerations alone (central differences), not from the attitude
    adaptation."""
    from groundstation.assembly.module import GRAVITY
    from groundstation.control.geometric import reference_attitude
    from groundstation.control.trajectory import Figure8
    from groundstation.rotations import matrix_to_rotvec

    model = ControlModel.from_assembly(V)
    fig8 = Figure8(l0=0.6, tc=8.0, h0=1.0, duration=8.0)
    h = 1e-4

    def pitch(t):
        a = fig8(t).acceleration
        return np.arctan2(a[0], GRAVITY + a[2])

    rates = []
    for t in np.linspace(0.0, 8.0, 17):
        w = matrix_to_rotvec(reference_attitude(fig8(t), model).T @ reference_attitude(fig8(t + 0.004), model)) / 0.004
        expected = (pitch(t + 0.002 + h) - pitch(t + 0.002 - h)) / (2 * h)  # the step's midpoint
        assert w[1] == pytest.approx(expected, rel=1e-3, abs=1e-5)
        assert abs(w[0]) < 1e-9 and abs(w[2]) < 1e-9
        rates.append(abs(w[1]))
    assert max(rates) > 0.1  # it swings: rad/s


@pytest.mark.parametrize("max_tilt_deg", [30.0, 10.0])
def test_a_reference_far_off_asks_for_a_bounded_lean_keeping_the_altitude_part(max_tilt_deg):
    """A reference 5 m to the side (a shove, a jump in the plan): the desired force leans max_tilt_deg from
    vertical, not 80 deg; its vertical part is what holds the altitude (m g here), its direction the error's."""
    model = ControlModel.from_assembly(FULL)
    state = RigidState(np.zeros(3), np.zeros(3), np.eye(3), np.zeros(3))
    sp = Setpoint(np.array([3.0, 4.0, 0.0]), np.zeros(3), np.zeros(3), np.eye(3))
    f = control(state, sp, model, Gains(max_tilt_deg=max_tilt_deg)).force_world
    assert np.degrees(np.arctan2(np.hypot(f[0], f[1]), f[2])) == pytest.approx(max_tilt_deg)
    assert f[2] == pytest.approx(model.mass * 9.81, rel=1e-3)
    assert f[1] / f[0] == pytest.approx(4.0 / 3.0)
    near = Setpoint(np.array([0.03, 0.04, 0.0]), np.zeros(3), np.zeros(3), np.eye(3))  # within the bound: as is
    f = control(state, near, model, Gains(max_tilt_deg=max_tilt_deg)).force_world
    wp = 2 * np.pi * Gains().position_hz
    np.testing.assert_allclose(f, [model.mass * wp ** 2 * 0.03, model.mass * wp ** 2 * 0.04, model.mass * 9.81],
                               rtol=1e-3)


def test_delay_limited_cuts_both_bandwidths_with_the_square_of_the_delay_beyond_its_bound():
    gains = Gains(attitude_hz=4.0, position_hz=0.8)
    assert delay_limited(gains, 0.018, 0.018) is gains and delay_limited(gains, 0.010, 0.018) is gains
    cut = delay_limited(gains, 0.036, 0.018)  # twice the delay: a quarter of each bandwidth, their ratio kept
    assert cut.attitude_hz == pytest.approx(1.0) and cut.position_hz == pytest.approx(0.2)
    assert replace(cut, attitude_hz=4.0, position_hz=0.8) == gains  # dampings and the lean bound as they were
    assert delay_limited(gains, float("nan"), 0.018) is gains  # nothing measured: nothing cut
    assert delay_limited(gains, float("inf"), 0.018) is gains  # the stop bound acts first
