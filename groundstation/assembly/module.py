"""Parameters of one base module: an X-layout quadrotor with four connectors (paper §II, Table II)."""

from __future__ import annotations

from pathlib import Path

from pydantic import ConfigDict, Field, model_validator
from pydantic.dataclasses import dataclass

from groundstation import config
from groundstation.assembly.motor_map import MotorCommandMap

FULL_CELL_V = 4.2
"""A fully charged LiPo cell, V."""

GRAVITY = 9.81
"""Standard gravity used throughout (the weight of a module is ``mass * GRAVITY``), m/s^2."""

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


@dataclass(frozen=True, config=_STRICT)
class ModuleParams:
    """Physical parameters of one module. Defaults are the paper's Table II plus a documented ``u_max``.

    The downwash capsule of module ``i`` is the segment ``o_i - mu R_i e3, mu in [capsule_a, capsule_b]``
    with radius ``r``; two modules clear each other when their segments are at least ``2 r`` apart.
    """

    mass: float = Field(0.24, gt=0)
    """``m``: module mass, kg."""
    c_f: float = Field(3.87e-7, gt=0)
    """Thrust coefficient: rotor thrust ``f = c_f u``, N per rad^2/s^2."""
    c_m: float = Field(1.06e-8, gt=0)
    """Drag-torque coefficient: rotor yaw torque ``(-1)^q c_m u``, N m per rad^2/s^2."""
    l_arm: float = Field(0.06, gt=0)
    """Arm length from module centre to each rotor (X layout, rotors at 45 degrees), m."""
    l_c: float = Field(0.11, gt=0)
    """Distance from the module centre to each connector, m (lattice pitch is ``2 l_c``)."""
    r: float = Field(0.095, gt=0)
    """Capsule radius of the downwash volume, m."""
    u_max: float = Field(4.0e6, gt=0)
    """Upper bound of each rotor input ``u = Omega^2``, rad^2/s^2. Not in the paper: 4.0e6 gives a
    per-module thrust of ``4 c_f u_max`` = 6.19 N, a thrust-to-weight ratio of 2.63."""
    capsule_a: float = Field(0.0475, ge=0)
    """Start of the capsule axis below the module centre, m (paper: ``r / 2``)."""
    capsule_b: float = Field(0.6475, gt=0)
    """End of the capsule axis below the module centre, m (paper: ``r / 2 + 10 l_arm``)."""

    inertia: tuple[float, float, float] = (6.0e-4, 6.0e-4, 1.1e-3)
    """Principal moments of inertia of one module about its centre, module frame, kg m^2. Not in the paper:
    estimated as a 0.17 m square plate of mass ``m``; identify it on the real module before flight."""

    frame_half_extents: tuple[float, float, float] = (0.085, 0.085, 0.02)
    """Half sizes of the box that bounds one module's frame and rotors (x, y, z, module frame), m: used for
    ground contact in simulation and for drawings."""

    motor_command: MotorCommandMap | None = None
    """How rotor thrust becomes the module firmware's command (``[motor_command]``, see
    :mod:`groundstation.assembly.motor_map`); needed to fly Crazyflie modules, not for design or simulation."""

    @model_validator(mode="after")
    def _capsule_ordered(self) -> ModuleParams:
        if self.capsule_b <= self.capsule_a:
            raise ValueError("capsule_b must be greater than capsule_a")
        if min(self.inertia) <= 0:
            raise ValueError("inertia must be positive")
        if min(self.frame_half_extents) <= 0:
            raise ValueError("frame_half_extents must be positive")
        if self.motor_command is not None:
            reach = float(self.motor_command.max_thrust(self._map_reference_v())[0])
            if reach < self.c_f * self.u_max * (1 - 1e-9):
                raise ValueError(f"motor_command reaches {reach:.3g} N per rotor at full command, less than "
                                 f"c_f u_max = {self.c_f * self.u_max:.3g} N")
        return self

    def _map_reference_v(self) -> float:
        """Battery the static reach check uses: the bolt fit's reference, a full cell on compensated platforms
        (preflight checks the reach again at each module's measured battery)."""
        return self.motor_command.reference_battery_v or FULL_CELL_V

    @property
    def max_thrust_per_module(self) -> float:
        """Largest thrust one module can produce, N."""
        return 4.0 * self.c_f * self.u_max


def load_module_params(path: str | Path) -> ModuleParams:
    """Load a module file such as ``configs/modules/paper_table2.toml`` (TOML, keys as :class:`ModuleParams`)."""
    return config.load(ModuleParams, path)
