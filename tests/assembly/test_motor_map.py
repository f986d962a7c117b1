"""The thrust -> command map of each platform, against the firmware's own arithmetic written out here."""

import numpy as np
import pytest

from groundstation.assembly.module import ModuleParams
from groundstation.assembly.motor_map import MotorCommandMap
from groundstation.config import validate
from groundstation.errors import ConfigError
from tests.peers import ROOT

# crazyflie-firmware 2026.08 platform_defaults_cf2.h / _cf21bl.h (battery compensation on): THRUST_MAX per rotor.
CF2_THRUST_MAX, CF21BL_THRUST_MAX = 0.12, 0.2


@pytest.mark.parametrize("platform, thrust_max", [("cf2", CF2_THRUST_MAX), ("cf21bl", CF21BL_THRUST_MAX)])
def test_crazyflie_force_is_a_fraction_of_thrust_max_whatever_the_battery(platform, thrust_max):
    m = MotorCommandMap(platform=platform, thrust_max_n=thrust_max)
    f = np.array([[0.0, thrust_max / 4, thrust_max / 2, thrust_max], [thrust_max * 2, -1.0, 0.03, 0.06]])
    for battery in ([4.2, 3.7], [3.3, 0.0]):  # the firmware compensates the battery: the map does not move
        r = m.fractions(f, battery)
        np.testing.assert_allclose(r, [[0, 0.25, 0.5, 1], [1, 0, 0.03 / thrust_max, 0.06 / thrust_max]])
        # What the firmware's power distribution and battery compensation turn back into thrust: r * THRUST_MAX.
        np.testing.assert_allclose(m.thrust(r, battery), np.clip(f, 0, thrust_max))
    np.testing.assert_allclose(m.max_thrust([3.0, 4.2]), thrust_max)


def test_bolt_command_is_the_esc_ratio_compensated_by_the_ground_station():
    m = MotorCommandMap(platform="bolt", thrust_poly_n=(0.0, 0.2, 1.3), reference_battery_v=4.0)
    f = np.array([[0.0, 0.4, 0.8, 1.2]])  # within reach at every voltage below (3.6 V: 1.233 N)
    for v in (4.0, 3.6, 4.2):
        r = m.fractions(f, [v])
        x = r * v / 4.0  # the ESC applies r of the battery: thrust is the fit at that effective command
        np.testing.assert_allclose(0.2 * x + 1.3 * x**2, f, atol=1e-12)
        np.testing.assert_allclose(m.thrust(r, [v]), f, atol=1e-12)
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
