"""How a rotor's thrust becomes the command a module's firmware takes, and what reaches the motors, per platform.

The motor app hands each rotor's normalized force (0..1) to the firmware's force mode (``controlModeForce``); the
stabilizer turns it into a motor ratio (crazyflie-firmware 2026.08, ``stabilizer.c`` ``controlMotors``):
``powerDistributionForce`` (force x 65535), ``batteryCompensation`` (``motors.c``), ``powerDistributionCap``
(the excess of the largest rotor over full scale is taken off all four, then the idle floor). What that means:

* ``cf2`` / ``cf21bl`` (Crazyflie 2.x brushed, 2.1 Brushless): the force is a fraction of the build's
  ``THRUST_MAX`` per rotor (0.12 N and 0.2 N by default). Battery compensation
  (``CONFIG_ENABLE_THRUST_BAT_COMPENSATED``, on by default for both) inverts the platform's cubic fit of thrust
  against motor voltage, ``f = c0 + c1 v + c2 v^2 + c3 v^3`` (``VMOTOR2THRUST0..3``), and divides by the battery
  voltage: thrust = fraction x THRUST_MAX while the battery can supply it. Below ``THRUST_MIN`` the compensation
  returns 0 (a dead zone of ~0.107 of THRUST_MAX); when the battery cannot supply the largest rotor's thrust
  (about 3.1 V under load at THRUST_MAX on a 2.1 Brushless), the cap takes the excess off all four rotors.
* ``bolt`` (Crazyflie Bolt with ESCs): the fraction goes linearly to the ESC; nothing compensates the battery.
  The map is a thrust-stand fit ``f = k0 + k1 x + k2 x^2`` per rotor of the effective command
  ``x = r V / V_ref`` (duty times battery voltage: motor speed follows the voltage the ESC applies), and the
  ground station compensates with the module's reported battery voltage: ``r = x(f) V_ref / V``.
* ``bolt`` and ``cf21bl`` require arming and keep an idle floor while armed (``powerDist.idleThrust``, 7000 of
  65535 by default): no rotor of an armed module turns slower.

The ground station never asks for more than :meth:`MotorCommandMap.max_thrust` at the module's battery, so the
firmware's shared cap never moves the other rotors; :meth:`MotorCommandMap.motor_ratios` is the firmware's
arithmetic (the simulated modules run it), :meth:`MotorCommandMap.thrust` what a motor ratio produces (the
modules report their ratios).

The rotor order is the firmware's: rotor q = 1..4 of the assembly model (``kinematics.ROTOR_DIRECTIONS``) is
motor Mq, and the module frame is the firmware's body frame (M1 front right, yaw signs -, +, -, + as in the
firmware's force-torque distribution), so no remapping is needed.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field, model_validator
from pydantic.dataclasses import dataclass

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)

MAX_ROTOR_THRUST_N = 100.0
"""Most thrust one rotor of a module may give at full command, N (a Crazyflie's ~0.15 N, a Bolt-class frame's
1-2 N; 1e300 was taken, and overflowed what was computed from it)."""
MIN_BATTERY_V, MAX_BATTERY_V = 3.0, 51.0
"""A module's LiPo, one cell empty to twelve full, V."""
FULL_SCALE = 65535
DEFAULT_IDLE_RATIO = 7000 / FULL_SCALE
"""``CONFIG_MOTORS_DEFAULT_IDLE_THRUST`` (7000) of builds that require arming, as a fraction of full scale."""
COMPENSATED = {
    # platform: (VMOTOR2THRUST0..3 (N, per V^k), THRUST_MIN N), crazyflie-firmware 2026.08 platform_defaults_*.h
    "cf2": ((-0.02476537915958403, 0.06523793527519485, -0.026792504967750107, 0.006776789303971145),
            0.012817578393224994),
    "cf21bl": ((-0.014058926705279723, 0.04265273261724981, 0.0018327760144017432, 0.0020576974784587178),
               0.02136263065537499),
}
"""The battery-compensated platforms' thrust fit against motor voltage and their ``THRUST_MIN`` (2.1+ propellers on
the cf2)."""
REQUIRES_ARMING = {"cf2": False, "cf21bl": True, "bolt": True}
"""``CONFIG_MOTORS_REQUIRE_ARMING`` in each platform's defconfig (2026.08); such builds keep the idle floor."""


@dataclass(frozen=True, config=_STRICT)
class MotorCommandMap:
    """The thrust -> normalized-force map of one module type (a ``[motor_command]`` table of a module file)."""

    platform: Literal["cf2", "cf21bl", "bolt"]
    thrust_max_n: float | None = Field(None, gt=0, le=MAX_ROTOR_THRUST_N)
    """cf2, cf21bl: the firmware build's ``THRUST_MAX``, thrust of one rotor at force 1.0, N."""
    thrust_poly_n: tuple[float, float, float] | None = None
    """bolt: ``(k0, k1, k2)`` of one rotor's thrust ``k0 + k1 x + k2 x^2``, N, at effective command x (ESC
    command r times battery voltage over ``reference_battery_v``)."""
    reference_battery_v: float | None = Field(None, ge=MIN_BATTERY_V, le=MAX_BATTERY_V)
    """bolt: battery voltage of the thrust-stand fit, V (a LiPo of 1 to 12 cells)."""
    battery_compensation: bool = True
    """bolt: scale the command by ``reference_battery_v / V`` with the module's reported voltage."""
    idle_ratio: float | None = Field(None, ge=0, lt=0.25)
    """Motor ratio an armed module never goes below (``powerDist.idleThrust / 65535``); default: 7000 / 65535 on
    platforms that require arming, 0 on the cf2."""

    @model_validator(mode="after")
    def _complete(self) -> MotorCommandMap:
        if self.platform in ("cf2", "cf21bl"):
            if self.thrust_max_n is None or self.thrust_poly_n is not None:
                raise ValueError(f"platform {self.platform} takes thrust_max_n (the firmware's THRUST_MAX) only")
        else:
            if self.thrust_poly_n is None or self.reference_battery_v is None or self.thrust_max_n is not None:
                raise ValueError("platform bolt takes thrust_poly_n and reference_battery_v")
            k0, k1, k2 = self.thrust_poly_n
            # Increasing on [0, x] for every x the map meets (up to twice the reference voltage), zero at rest.
            if abs(k0) > 1e-9 or k1 < 0 or k1 + 4 * k2 < 0 or k1 + k2 <= 0:
                raise ValueError("thrust_poly_n must start at 0 N and increase with the command")
            if k1 + k2 > MAX_ROTOR_THRUST_N:
                raise ValueError(f"thrust_poly_n gives {k1 + k2:g} N at full command: above the "
                                 f"{MAX_ROTOR_THRUST_N:g} N of any rotor a module carries")
        return self

    # -- the firmware's side --------------------------------------------------------------------------------------
    @property
    def idle(self) -> float:
        """Idle floor of an armed module's motor ratios."""
        if self.idle_ratio is not None:
            return self.idle_ratio
        return DEFAULT_IDLE_RATIO if REQUIRES_ARMING[self.platform] else 0.0

    @property
    def thrust_min_n(self) -> float:
        """cf2, cf21bl: thrust below which battery compensation outputs 0 (``THRUST_MIN``), N; 0 on the bolt."""
        return COMPENSATED[self.platform][1] if self.platform in COMPENSATED else 0.0

    def _vmotor_thrust(self, v_motor: np.ndarray) -> np.ndarray:
        c0, c1, c2, c3 = COMPENSATED[self.platform][0]
        return np.maximum(c0 + v_motor * (c1 + v_motor * (c2 + c3 * v_motor)), 0.0)

    def _vmotor_of_thrust(self, f: np.ndarray) -> np.ndarray:
        """``motorsCompensateBatteryVoltage``'s inverse of the cubic (the firmware's closed form), V."""
        c0, c1, c2, c3 = COMPENSATED[self.platform][0]
        p = -c2 / (3 * c3)
        q = p**3 + (c2 * c1 - 3 * c3 * (c0 - f)) / (6 * c3 * c3)
        r = c1 / (3 * c3)
        qrp = np.sqrt(q * q + (r - p * p) ** 3)
        return np.cbrt(q + qrp) + np.cbrt(q - qrp) + p

    def motor_ratios(self, fractions, battery_v, armed=True) -> np.ndarray:
        """What the firmware's power distribution outputs for normalized forces ``(n, 4)`` at ``battery_v``
        (``(n,)``, V): compensation and its dead zone, the cap shared by the four rotors, the idle floor while
        ``armed`` (motors allowed to run)."""
        f = np.clip(np.asarray(fractions, float), 0.0, 1.0)
        v = np.asarray(battery_v, float)[..., None]
        if self.platform in COMPENSATED:
            thrust = f * self.thrust_max_n
            ratio = np.where((thrust < self.thrust_min_n) | (v < 2.0), 0.0,
                             self._vmotor_of_thrust(thrust) / np.where(v > 0, v, 1.0))
        else:
            ratio = f
        ratio = ratio - np.maximum(np.max(ratio, axis=-1, keepdims=True) - 1.0, 0.0)  # powerDistributionCap
        return np.maximum(ratio, self.idle) if armed else np.zeros_like(ratio)

    def thrust(self, ratios, battery_v) -> np.ndarray:
        """Rotor thrusts (N) of motors driven at ``ratios`` (``(n, 4)``, 0..1, as the modules report them) from a
        battery at ``battery_v`` (``(n,)``, V)."""
        r = np.clip(np.asarray(ratios, float), 0.0, 1.0)
        v = np.asarray(battery_v, float)[..., None]
        if self.platform in COMPENSATED:
            return self._vmotor_thrust(r * v)
        return self._thrust_of_x(r * self._effective_scale(battery_v)[..., None])

    # -- the ground station's side ------------------------------------------------------------------------------
    def _effective_scale(self, battery_v) -> np.ndarray:
        """x / r for each module: V / V_ref where the ground station compensates, else 1."""
        v = np.asarray(battery_v, float)
        if self.platform != "bolt" or not self.battery_compensation:
            return np.ones_like(v)
        return np.where(v > 0, v, self.reference_battery_v) / self.reference_battery_v

    def _thrust_of_x(self, x: np.ndarray) -> np.ndarray:
        k0, k1, k2 = self.thrust_poly_n
        return k0 + x * (k1 + k2 * x)

    def _x_of_thrust(self, f: np.ndarray) -> np.ndarray:
        k0, k1, k2 = self.thrust_poly_n
        if abs(k2) < 1e-15:
            return (f - k0) / k1
        return (-k1 + np.sqrt(np.maximum(k1 * k1 - 4 * k2 * (k0 - f), 0.0))) / (2 * k2)

    def fractions(self, thrust_n, battery_v) -> np.ndarray:
        """Normalized forces (0..1) for rotor thrusts (N, ``(n, 4)``) of modules at ``battery_v`` (V, ``(n,)``;
        0 = unknown, taken as the reference). Each thrust is first bounded by what the module reaches at its
        battery (so the firmware's shared cap never takes thrust off the other rotors), and on compensated
        platforms a thrust inside the dead zone goes to the nearer of 0 and ``THRUST_MIN``."""
        f = np.maximum(np.asarray(thrust_n, float), 0.0)
        if self.platform in COMPENSATED:
            f = np.minimum(f, self.max_thrust(battery_v)[..., None])
            tmin = self.thrust_min_n
            f = np.where(f < tmin, np.where(f < tmin / 2, 0.0, tmin), f)
            return np.clip(f / self.thrust_max_n, 0.0, 1.0)
        x = self._x_of_thrust(f)
        return np.clip(x / self._effective_scale(battery_v)[..., None], 0.0, 1.0)

    def max_thrust(self, battery_v) -> np.ndarray:
        """Largest thrust of one rotor of each module at ``battery_v`` (V), N: on compensated platforms
        ``THRUST_MAX`` while the battery supplies it, the fit at full motor voltage below that."""
        v = np.atleast_1d(np.asarray(battery_v, float))
        if self.platform in COMPENSATED:
            return np.minimum(self.thrust_max_n, self._vmotor_thrust(v))
        return self.thrust(np.ones((v.size, 1)), v)[:, 0]
