"""Parameters of one base module: an X-layout quadrotor with four connectors (paper §II, Table II)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import ConfigDict, Field, ValidationInfo, field_validator, model_validator
from pydantic.dataclasses import dataclass

from groundstation import config
from groundstation.assembly.motor_map import MotorCommandMap

FULL_CELL_V = 4.2
"""A fully charged LiPo cell, V."""

GRAVITY = 9.81
"""Standard gravity used throughout (the weight of a module is ``mass * GRAVITY``), m/s^2."""

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)

MIN_MASS_KG, MAX_MASS_KG = 0.005, 100.0
"""A module's mass, kg: the smallest quadrotors that carry a flight controller weigh 10-30 g (a Crazyflie 27 g), the
heaviest multirotors tens of kg. At 1e300 kg ``optimize`` overflowed its wrenches to inf."""
MIN_LENGTH_M, MAX_LENGTH_M = 0.001, 2.0
"""A module's lengths (arm, connector distance, capsule radius, frame half sizes), m: a rotor arm of 1 mm carries no
rotor, and no multirotor's arm is 2 m long (the paper's 0.06 m, a Crazyflie's 0.046 m). At 1e300 m ``optimize``
overflowed its allocation."""
TORQUE_RATIO_M = (1e-3, 0.1)
"""Range of a rotor's yaw torque per thrust, ``c_m / c_f``, m: a propeller's drag torque is its thrust times a few
per cent of its diameter (the paper's 0.027 m, a Crazyflie 2.1's 0.025 m, a 2.1 Brushless' 0.006 m)."""
GYRATION_OF_ARM = 0.1
"""A module's radius of gyration (``sqrt(inertia / mass)``) is at least this share of ``l_arm``: its four rotors sit
at ``l_arm`` (motors and propellers are well over 1 % of its mass; the shipped module files: 0.83-1.1)..."""
GYRATION_OF_CELL = 2.0
"""...and at most this many times ``l_c``: the module's mass is within its lattice cell (half side ``l_c``). At
1e-300 kg m^2 ``optimize`` took it (exit 0), for designs no controller could fly."""


_Length = Annotated[float, Field(ge=MIN_LENGTH_M, le=MAX_LENGTH_M)]


@dataclass(frozen=True, config=_STRICT)
class ModuleParams:
    """Physical parameters of one module. Defaults are the paper's Table II plus a documented ``u_max``.

    The downwash capsule of module ``i`` is the segment ``o_i - mu R_i e3, mu in [capsule_a, capsule_b]``
    with radius ``r``; two modules clear each other when their segments are at least ``2 r`` apart.
    """

    mass: float = Field(0.24, ge=MIN_MASS_KG, le=MAX_MASS_KG)
    """``m``: module mass, kg (:data:`MIN_MASS_KG` to :data:`MAX_MASS_KG`)."""
    c_f: float = Field(3.87e-7, gt=0)
    """Thrust coefficient: rotor thrust ``f = c_f u``, N per rad^2/s^2."""
    c_m: float = Field(1.06e-8, gt=0)
    """Drag-torque coefficient: rotor yaw torque ``(-1)^q c_m u``, N m per rad^2/s^2 (``c_m / c_f`` within
    :data:`TORQUE_RATIO_M`)."""
    l_arm: float = Field(0.06, ge=MIN_LENGTH_M, le=MAX_LENGTH_M)
    """Arm length from module centre to each rotor (X layout, rotors at 45 degrees), m (lengths: within
    :data:`MIN_LENGTH_M` and :data:`MAX_LENGTH_M`)."""
    l_c: float = Field(0.11, ge=MIN_LENGTH_M, le=MAX_LENGTH_M)
    """Distance from the module centre to each connector, m (lattice pitch is ``2 l_c``)."""
    r: float = Field(0.095, ge=MIN_LENGTH_M, le=MAX_LENGTH_M)
    """Capsule radius of the downwash volume, m."""
    u_max: float = Field(4.0e6, gt=0)
    """Upper bound of each rotor input ``u = Omega^2``, rad^2/s^2. Not in the paper: 4.0e6 gives a
    per-module thrust of ``4 c_f u_max`` = 6.19 N, a thrust-to-weight ratio of 2.63 (no bound of its own: the design
    study sets it to a design's least, :func:`~groundstation.design.optimize.with_input_bound`)."""
    capsule_a: float = Field(0.0475, ge=0)
    """Start of the capsule axis below the module centre, m (paper: ``r / 2``)."""
    capsule_b: float = Field(0.6475, gt=0)
    """End of the capsule axis below the module centre, m (paper: ``r / 2 + 10 l_arm``)."""

    inertia: tuple[float, float, float] = (6.0e-4, 6.0e-4, 1.1e-3)
    """Principal moments of inertia of one module about its centre, module frame, kg m^2. Not in the paper:
    estimated as a 0.17 m square plate of mass ``m``; identify it on the real module before flight."""

    frame_half_extents: tuple[_Length, _Length, _Length] = (0.085, 0.085, 0.02)
    """Half sizes of the box that bounds one module's frame and rotors (x, y, z, module frame), m: used for
    ground contact in simulation and for drawings."""

    motor_command: MotorCommandMap | None = None
    """How rotor thrust becomes the module firmware's command (``[motor_command]``, see
    :mod:`groundstation.assembly.motor_map`); needed to fly Crazyflie modules, not for design or simulation."""

    @field_validator("c_m")
    @classmethod
    def _torque_ratio(cls, c_m: float, info: ValidationInfo) -> float:
        c_f = info.data.get("c_f")
        lo, hi = TORQUE_RATIO_M
        if c_f is not None and not lo <= c_m / c_f <= hi:
            raise ValueError(f"c_m / c_f = {c_m / c_f:.3g} m is outside {lo:g}..{hi:g} m (a rotor's yaw torque per "
                             f"thrust)")
        return c_m

    @field_validator("inertia")
    @classmethod
    def _inertia_of_a_module(cls, inertia: tuple[float, float, float], info: ValidationInfo):
        if min(inertia) <= 0:
            raise ValueError("inertia must be positive")
        if 2 * max(inertia) > sum(inertia) * (1 + 1e-9):
            raise ValueError(f"{list(inertia)} kg m^2: no body has one principal moment above the sum of the "
                             f"other two")
        mass, l_arm, l_c = (info.data.get(k) for k in ("mass", "l_arm", "l_c"))
        if None not in (mass, l_arm, l_c):
            lo, hi = GYRATION_OF_ARM * l_arm, GYRATION_OF_CELL * l_c
            k = [(i / mass) ** 0.5 for i in inertia]
            if not lo <= min(k) <= max(k) <= hi:
                raise ValueError(f"{list(inertia)} kg m^2 for {mass:g} kg: radii of gyration "
                                 f"{', '.join(f'{x:.3g}' for x in k)} m, outside {lo:.3g} ({GYRATION_OF_ARM:g} "
                                 f"l_arm)..{hi:.3g} m ({GYRATION_OF_CELL:g} l_c)")
        return inertia

    @model_validator(mode="after")
    def _capsule_ordered(self) -> ModuleParams:
        if self.capsule_b <= self.capsule_a:
            raise ValueError("capsule_b must be greater than capsule_a")
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
