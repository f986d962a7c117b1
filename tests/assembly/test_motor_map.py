"""The thrust -> command map of each platform, against the firmware's own arithmetic written out here."""

import numpy as np
import pytest

from groundstation.assembly.module import ModuleParams
from groundstation.assembly.motor_map import MotorCommandMap
from groundstation.config import validate
from groundstation.errors import ConfigError
from tests.peers import ROOT

# crazyflie-firmware 2026.08 platform_defaults_cf2.h / _cf21bl.h (battery compensation on): THRUST_MAX per rotor,
# THRUST_MIN and the cubic fit of thrust against motor voltage, written out here from the firmware headers.
CF2_THRUST_MAX, CF21BL_THRUST_MAX = 0.12, 0.2
FIT = {"cf2": ((-0.02476537915958403, 0.06523793527519485, -0.026792504967750107, 0.006776789303971145),
               0.012817578393224994),
       "cf21bl": ((-0.014058926705279723, 0.04265273261724981, 0.0018327760144017432, 0.0020576974784587178),
                  0.02136263065537499)}


def firmware_ratio(platform, thrust, supply_v):
    """motorsCompensateBatteryVoltage, solved here with numpy's polynomial roots (not the firmware's closed form)."""
    (c0, c1, c2, c3), thrust_min = FIT[platform]
    if thrust < thrust_min:
        return 0.0
    roots = np.roots([c3, c2, c1, c0 - thrust])
    v = min(r.real for r in roots if abs(r.imag) < 1e-9 and r.real > 0)
    return v / supply_v


@pytest.mark.parametrize("platform, thrust_max", [("cf2", CF2_THRUST_MAX), ("cf21bl", CF21BL_THRUST_MAX)])
def test_compensated_platforms_give_the_thrust_asked_for_whatever_the_battery(platform, thrust_max):
    m = MotorCommandMap(platform=platform, thrust_max_n=thrust_max)
    f = np.array([[0.2, 0.4, 0.7, 1.0]]) * thrust_max
    for v in (4.2, 3.8, 3.5):
        r = m.fractions(f, [v])
        np.testing.assert_allclose(r, f / thrust_max)  # a fraction of THRUST_MAX while the battery supplies it
        ratios = m.motor_ratios(r, [v])
        expected = [firmware_ratio(platform, x, v) for x in f[0]]
        np.testing.assert_allclose(ratios[0], expected, rtol=1e-6)
        np.testing.assert_allclose(m.thrust(ratios, [v]), f, rtol=1e-6)  # the motor produces what was asked


def test_half_force_at_3_9_v_is_the_ratio_the_real_firmware_set():
    """Measured on crazyflie-firmware 2026.08 run natively (issue 19): 0.5 commanded on a cf2 at 3.9 V -> 36507."""
    m = MotorCommandMap(platform="cf2", thrust_max_n=CF2_THRUST_MAX)
    assert abs(m.motor_ratios([[0.5] * 4], [3.9])[0, 0] * 65535 - 36507) <= 1


@pytest.mark.parametrize("platform, thrust_max", [("cf2", CF2_THRUST_MAX), ("cf21bl", CF21BL_THRUST_MAX)])
def test_dead_zone_below_thrust_min(platform, thrust_max):
    m = MotorCommandMap(platform=platform, thrust_max_n=thrust_max)
    tmin = FIT[platform][1]
    assert tmin / thrust_max == pytest.approx(0.107, abs=0.001)
    just_below = m.motor_ratios([[tmin / thrust_max * 0.999] * 4], [4.0], armed=True)
    np.testing.assert_allclose(just_below, m.idle)  # nothing but the idle floor: the firmware outputs 0
    # The ground station asks for the nearer of 0 and THRUST_MIN, never for a thrust the firmware drops.
    np.testing.assert_allclose(m.fractions([[tmin * 0.4, tmin * 0.6, tmin, 0.0]], [4.0]) * thrust_max,
                               [[0.0, tmin, tmin, 0.0]], atol=1e-12)


def test_low_battery_cap_takes_the_excess_off_all_four_rotors():
    m = MotorCommandMap(platform="cf21bl", thrust_max_n=CF21BL_THRUST_MAX)
    v = 2.9  # under load: full thrust needs more than the battery's voltage
    ratios = m.motor_ratios([[1.0, 0.6, 0.6, 0.3]], [v])[0]
    raw = np.array([firmware_ratio("cf21bl", x * CF21BL_THRUST_MAX, v) for x in (1.0, 0.6, 0.6, 0.3)])
    assert raw[0] > 1.0
    np.testing.assert_allclose(ratios, raw - (raw[0] - 1.0), rtol=1e-6)  # the same excess off every rotor
    # The ground station bounds each rotor at what the battery reaches, so the cap never moves the others.
    reach = m.max_thrust([v])[0]
    assert reach < CF21BL_THRUST_MAX
    asked = np.array([[0.2, 0.12, 0.12, 0.06]])
    sent = m.motor_ratios(m.fractions(asked, [v]), [v])
    np.testing.assert_allclose(m.thrust(sent, [v])[0, 1:], asked[0, 1:], rtol=1e-6)
    assert m.thrust(sent, [v])[0, 0] == pytest.approx(reach, rel=1e-6)


@pytest.mark.parametrize("platform, idle", [("cf2", 0.0), ("cf21bl", 7000 / 65535), ("bolt", 7000 / 65535)])
def test_idle_floor_while_armed(platform, idle):
    m = (MotorCommandMap(platform="bolt", thrust_poly_n=(0.0, 0.0, 1.548), reference_battery_v=3.5)
         if platform == "bolt" else MotorCommandMap(platform=platform, thrust_max_n=0.12))
    np.testing.assert_allclose(m.motor_ratios(np.zeros((1, 4)), [4.0], armed=True), idle)
    np.testing.assert_allclose(m.motor_ratios(np.full((1, 4), 0.5), [4.0], armed=False), 0.0)


def test_bolt_command_is_the_esc_ratio_compensated_by_the_ground_station():
    m = MotorCommandMap(platform="bolt", thrust_poly_n=(0.0, 0.2, 1.3), reference_battery_v=4.0)
    f = np.array([[0.0, 0.4, 0.8, 1.2]])  # within reach at every voltage below (3.6 V: 1.233 N)
    for v in (4.0, 3.6, 4.2):
        r = m.fractions(f, [v])
        x = r * v / 4.0  # the ESC applies r of the battery: thrust is the fit at that effective command
        np.testing.assert_allclose(0.2 * x + 1.3 * x**2, f, atol=1e-12)
        idle = m.thrust([[m.idle] * 4], [v])  # an armed Bolt never turns slower than the idle floor
        np.testing.assert_allclose(m.thrust(m.motor_ratios(r, [v]), [v]), np.maximum(f, idle), atol=1e-12)
    # A weaker battery needs a larger command for the same thrust, and reaches less at full command.
    assert m.fractions(f, [3.6])[0, 2] > m.fractions(f, [4.0])[0, 2]
    np.testing.assert_allclose(m.max_thrust([4.0, 3.6]), [1.5, 0.2 * 0.9 + 1.3 * 0.81])
    # Unknown battery (0 V) is taken as the reference; without compensation the battery is ignored.
    np.testing.assert_allclose(m.fractions(f, [0.0]), m.fractions(f, [4.0]))
    fixed = MotorCommandMap(platform="bolt", thrust_poly_n=(0.0, 0.2, 1.3), reference_battery_v=4.0,
                            battery_compensation=False)
    np.testing.assert_allclose(fixed.fractions(f, [3.6]), m.fractions(f, [4.0]))


def test_paper_module_map_reaches_u_max_at_the_lowest_battery():
    p = ModuleParams(motor_command=MotorCommandMap(platform="bolt", thrust_poly_n=(0, 0, 1.548),
                                                   reference_battery_v=3.5))
    assert p.motor_command.max_thrust(3.5)[0] == pytest.approx(p.c_f * p.u_max)
    # thrust = c_f u is quadratic in the command: half the rotor speed (u / 4) is half the command at 3.5 V.
    assert p.motor_command.fractions([[p.c_f * p.u_max / 4]], [3.5])[0, 0] == pytest.approx(0.5)


@pytest.mark.parametrize("table, message", [
    ({"platform": "cf2"}, "takes thrust_max_n"),
    ({"platform": "cf2", "thrust_max_n": 0.12, "thrust_poly_n": [0, 0, 1]}, "takes thrust_max_n"),
    ({"platform": "bolt", "thrust_poly_n": [0, 0, 1]}, "takes thrust_poly_n and reference_battery_v"),
    ({"platform": "bolt", "thrust_poly_n": [0.1, 0, 1], "reference_battery_v": 4}, "start at 0 N"),
    ({"platform": "bolt", "thrust_poly_n": [0, 1, -1], "reference_battery_v": 4}, "increase"),
    ({"platform": "tinywhoop", "thrust_max_n": 1}, "platform"),
    ({"platform": "cf2", "thrust_max_n": 1e300}, "thrust_max_n"),
    ({"platform": "bolt", "thrust_poly_n": [0, 1e300, 0], "reference_battery_v": 4}, "above the 100 N"),
    ({"platform": "bolt", "thrust_poly_n": [0, 1, 1], "reference_battery_v": 1e300}, "reference_battery_v"),
])
def test_bad_maps_are_config_errors(table, message):
    with pytest.raises(ConfigError, match=message):
        validate(MotorCommandMap, table, path="m.toml", prefix="motor_command")


def test_a_map_that_cannot_reach_u_max_is_refused():
    with pytest.raises(ConfigError, match=r"reaches 0.12 N per rotor at full command, less than c_f u_max = 1.55 N"):
        validate(ModuleParams, {"motor_command": {"platform": "cf2", "thrust_max_n": 0.12}}, path="m.toml")


def test_rotor_order_is_the_firmware_motor_order():
    """Rotor q of the model is motor Mq: positions M1 front right, M2 back right, M3 back left, M4 front left and
    yaw signs -, +, -, + as in the firmware's force-torque distribution (motorForces[i] = ... -/+ yawPart)."""
    from groundstation.assembly.kinematics import ROTOR_DIRECTIONS, ROTOR_SPIN

    np.testing.assert_array_equal(np.sign(ROTOR_DIRECTIONS[:, :2]), [[1, -1], [-1, -1], [-1, 1], [1, 1]])
    np.testing.assert_array_equal(ROTOR_SPIN, [-1, 1, -1, 1])
    assert (ROOT / "configs/modules/paper_table2.toml").exists()
