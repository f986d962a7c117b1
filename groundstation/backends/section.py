"""The ``[backend]`` section of a flight config: which modules fly and over which links.

It belongs to the backends (the firmware-parameter check and every backend read it); the flight config
(:mod:`groundstation.runtime.flight_config`) embeds it.
"""

from __future__ import annotations

from pydantic import ConfigDict, Field, ValidationInfo, field_validator, model_validator
from pydantic.dataclasses import dataclass

from groundstation.backend_kinds import KINDS, backend_kind, link_problem

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)

SIM_PHYSICS_HZ = 240.0
"""Physics rate of the simulated modules (PyBullet's default step, 1/240 s), Hz: the one default every simulator
(``sim``, ``sim-peer``, ``simulate``) starts from."""
SIM_MOTOR_TIME_CONSTANT = 0.02
"""First-order lag of a simulated rotor, s."""


@dataclass(frozen=True, config=_STRICT)
class BackendSection:
    kind: str = "sim"
    """A name in :data:`groundstation.backend_kinds.KINDS`: ``sim`` (PyBullet in this process), ``crazyflie``
    (modules over cflib links) or ``mavlink`` (PX4 modules over pymavlink connections; see ``modules``)."""
    physics_hz: float = Field(SIM_PHYSICS_HZ, gt=0)
    """sim only."""
    motor_time_constant: float = Field(SIM_MOTOR_TIME_CONSTANT, ge=0)
    """sim only, s"""
    modules: tuple[str, ...] = ()
    """One link per module in assembly order; required for ``crazyflie`` and ``mavlink``, optional for ``sim``.
    Its length must match the assembly. Crazyflie URIs: ``radio://0/80/2M/E7E7E7E701``, or
    ``udp://127.0.0.1:19850`` for simulated modules. MAVLink connection strings: ``/dev/ttyACM0,921600``,
    ``udpin:0.0.0.0:14550``, or ``udpout:127.0.0.1:14560`` for simulated modules."""
    link_timeout_s: float = Field(0.1, gt=0)
    """crazyflie, mavlink: a module silent for longer is lost (the flight stops the motors), s."""
    min_battery_v: float = Field(3.5, ge=0)
    """crazyflie, mavlink: preflight rejects a module below this battery voltage, V."""
    pwm_min: int = Field(1000, ge=0)
    """mavlink: the modules' PWM_MAIN_MIN (zero thrust), us."""
    pwm_max: int = Field(2000, gt=0)
    """mavlink: the modules' PWM_MAIN_MAX (full thrust), us."""
    radio_capacity_hz: float = Field(450.0, gt=0)
    """crazyflie: packets a second one Crazyradio carries (Bitcraze: about 450-500 round trips); every module
    takes one per control period, so modules on one dongle x ``rate_hz`` must stay below it."""
    firmware_params: str | None = None
    """crazyflie, mavlink: a parameter file (``firmware_params/crazyflie.toml``, ``firmware_params/px4/
    module_params.toml``; relative to this config) that preflight checks on every module before arming."""

    @field_validator("kind")
    @classmethod
    def _known(cls, kind: str) -> str:
        backend_kind(kind)
        return kind

    @field_validator("modules")
    @classmethod
    def _links(cls, links: tuple[str, ...], info: ValidationInfo) -> tuple[str, ...]:
        for link in links:
            problem = link_problem(info.data.get("kind", "sim"), link)
            if problem:
                raise ValueError(problem)
        return links

    @model_validator(mode="after")
    def _consistent(self) -> BackendSection:
        if self.pwm_max <= self.pwm_min:
            raise ValueError("pwm_max must be greater than pwm_min")
        if backend_kind(self.kind).check_params is None and self.firmware_params is not None:
            firmware = " or ".join(k.name for k in KINDS.values() if k.check_params is not None)
            raise ValueError(f"firmware_params needs a {firmware} backend ({self.kind} has no module firmware)")
        return self
