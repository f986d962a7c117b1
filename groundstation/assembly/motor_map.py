"""How a rotor's thrust becomes the command a module's firmware takes, per platform (the motor app's forces).

The motor app hands each rotor's normalized force (0..1) to the firmware's force mode
(``controlModeForce``), and what that number means differs by platform (crazyflie-firmware 2026.08,
``power_distribution_quadrotor.c`` and ``motors.c``):

* ``cf2`` / ``cf21bl`` (Crazyflie 2.x brushed, 2.1 Brushless): the force is a fraction of the build's
  ``THRUST_MAX`` per rotor (0.12 N and 0.2 N by default), and the firmware compensates the battery voltage
  (``CONFIG_ENABLE_THRUST_BAT_COMPENSATED``, on by default for both), so thrust = fraction x THRUST_MAX.
* ``bolt`` (Crazyflie Bolt with ESCs): the fraction goes linearly to the ESC; nothing compensates the battery.
  The map is a thrust-stand fit ``f = k0 + k1 x + k2 x^2`` per rotor of the effective command
  ``x = r V / V_ref`` (duty times battery voltage: motor speed follows the voltage the ESC applies), and the
  ground station compensates with the module's reported battery voltage: ``r = x(f) V_ref / V``.

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


@dataclass(frozen=True, config=_STRICT)
class MotorCommandMap:
    """The thrust -> normalized-force map of one module type (a ``[motor_command]`` table of a module file)."""

    platform: Literal["cf2", "cf21bl", "bolt"]
    thrust_max_n: float | None = Field(None, gt=0)
    """cf2, cf21bl: the firmware build's ``THRUST_MAX``, thrust of one rotor at force 1.0, N."""
    thrust_poly_n: tuple[float, float, float] | None = None
    """bolt: ``(k0, k1, k2)`` of one rotor's thrust ``k0 + k1 x + k2 x^2``, N, at effective command x (ESC
    command r times battery voltage over ``reference_battery_v``)."""
    reference_battery_v: float | None = Field(None, gt=0)
    """bolt: battery voltage of the thrust-stand fit, V."""
    battery_compensation: bool = True
    """bolt: scale the command by ``reference_battery_v / V`` with the module's reported voltage."""

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
        return self

    # -- the map ------------------------------------------------------------------------------------------------
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
        0 = unknown, taken as the reference)."""
        f = np.maximum(np.asarray(thrust_n, float), 0.0)
        if self.platform != "bolt":
            return np.clip(f / self.thrust_max_n, 0.0, 1.0)
        x = self._x_of_thrust(f)
        return np.clip(x / self._effective_scale(battery_v)[..., None], 0.0, 1.0)

    def thrust(self, fractions, battery_v) -> np.ndarray:
        """Rotor thrusts (N) a module at ``battery_v`` produces for normalized forces ``fractions``."""
        r = np.clip(np.asarray(fractions, float), 0.0, 1.0)
        if self.platform != "bolt":
            return r * self.thrust_max_n
        return self._thrust_of_x(r * self._effective_scale(battery_v)[..., None])

    def max_thrust(self, battery_v) -> np.ndarray:
        """Largest thrust of one rotor of each module at ``battery_v``, N."""
        v = np.atleast_1d(np.asarray(battery_v, float))
        return self.thrust(np.ones((v.size, 1)), v)[:, 0]
