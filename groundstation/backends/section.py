"""The ``[backend]`` section of a flight config: which modules fly and over which links.

It belongs to the backends (the firmware-parameter check and every backend read it); the flight config
(:mod:`groundstation.runtime.flight_config`) embeds it.
"""

from __future__ import annotations

from typing import Annotated, Union

from pydantic import ConfigDict, Discriminator, Field, Tag, ValidationInfo, field_validator, model_validator
from pydantic.dataclasses import dataclass

from groundstation.backend_kinds import KINDS, link_problem, load

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)

SIM_PHYSICS_HZ = 240.0
"""Physics rate of the simulated modules (PyBullet's default step, 1/240 s), Hz: the one default every simulator
(``sim``, ``sim-peer``, ``simulate``) starts from."""
SIM_MOTOR_TIME_CONSTANT = 0.02
"""First-order lag of a simulated rotor, s."""
SIM_GYRO_DELAY = 0.004
"""Age of a simulated module's gyro reading, s (a Crazyflie's IMU low-pass and sampling: a few ms)."""
MAX_THRUST_LAG = 0.1
"""Largest ``thrust_lag_s``, s: rotors slower than this cannot carry an attitude loop (``motor_time_constant`` is
bounded by the attitude loop's own time constant: :func:`~groundstation.runtime.flight_config.bound_issues`)."""
MAX_GYRO_DELAY = 0.1
"""Largest ``gyro_delay_s``, s: a body rate older than this is no use to an attitude loop."""


@dataclass(frozen=True, config=_STRICT)
class SimSection:
    """``kind = "sim"``: PyBullet in this process, publishing its pose through a virtual mocap."""

    kind: str = "sim"
    physics_hz: float = Field(SIM_PHYSICS_HZ, gt=0)
    """Hz."""
    motor_time_constant: float = Field(SIM_MOTOR_TIME_CONSTANT, ge=0)
    """s."""
    gyro_delay_s: float = Field(SIM_GYRO_DELAY, ge=0, le=MAX_GYRO_DELAY)
    """Age of the simulated gyro readings, s (the simulator delays them by this and the estimator compensates it)."""
    modules: tuple[str, ...] = ()
    """Ignored by the simulator; if given, its length must match the assembly (a config about to become a
    hardware one)."""


@dataclass(frozen=True, config=_STRICT)
class LinkedSection:
    """Modules reached over one link each (the fields every hardware kind has)."""

    kind: str
    modules: tuple[str, ...] = ()
    """One link per module in assembly order (its form per kind: :data:`groundstation.backend_kinds.KINDS`).
    Crazyflie URIs: ``radio://0/80/2M/E7E7E7E701``, or ``udp://127.0.0.1:19850`` for simulated modules. MAVLink
    connection strings: ``/dev/ttyACM0,921600``, ``udpin:0.0.0.0:14550``, or ``udpout:127.0.0.1:14560``."""
    link_timeout_s: float = Field(0.1, gt=0)
    """A module silent for longer is lost (the flight stops the motors), s."""
    thrust_lag_s: float = Field(SIM_MOTOR_TIME_CONSTANT, ge=0, le=MAX_THRUST_LAG)
    """Time constant of the modules' rotors behind a thrust command, s (the estimator predicts with it): the
    simulated modules' (``sim-peer``) 20 ms by default; a Crazyflie's brushed motors are of that order."""
    min_battery_v: float = Field(3.5, ge=0)
    """Preflight rejects a module below this battery voltage, V."""
    firmware_params: str | None = None
    """A parameter file (``firmware_params/crazyflie.toml``, ``firmware_params/px4/module_params.toml``; relative
    to this config) that preflight checks on every module before arming."""
    gyro_delay_s: float = Field(0.0, ge=0, le=MAX_GYRO_DELAY)
    """Age of the modules' gyro readings when the ground station gets them, s: the estimator compensates it (each
    kind's default: measured against ``sim-peer``; on hardware, measure yours with ``groundstation replay LOG
    --gyro-lag``)."""

    @field_validator("modules")
    @classmethod
    def _links(cls, links: tuple[str, ...], info: ValidationInfo) -> tuple[str, ...]:
        for link in links:
            problem = link_problem(info.data["kind"], link)
            if problem:
                raise ValueError(problem)
        return links


@dataclass(frozen=True, config=_STRICT)
class CrazyflieSection(LinkedSection):
    """``kind = "crazyflie"``."""

    kind: str = "crazyflie"
    gyro_delay_s: float = Field(0.013, ge=0, le=MAX_GYRO_DELAY)
    """The default: 13 ms against ``sim-peer`` (its 4 ms IMU delay, then the state packet's way back; a
    delay 4 ms shorter or longer flies as well)."""
    radio_capacity_hz: float = Field(450.0, gt=0)
    """Packets a second one Crazyradio carries (Bitcraze: about 450-500 round trips); every module takes one per
    control period, so modules on one dongle x ``rate_hz`` must stay below it."""


@dataclass(frozen=True, config=_STRICT)
class MavlinkSection(LinkedSection):
    """``kind = "mavlink"``."""

    kind: str = "mavlink"
    gyro_delay_s: float = Field(0.012, ge=0, le=MAX_GYRO_DELAY)
    """The default: 11-13 ms against ``sim-peer`` (its 4 ms IMU delay, ATTITUDE at 250 Hz, the link)."""
    pwm_min: int = Field(1000, ge=0)
    """The modules' PWM_MAIN_MIN (zero thrust), us."""
    pwm_max: int = Field(2000, gt=0)
    """The modules' PWM_MAIN_MAX (full thrust), us."""

    @model_validator(mode="after")
    def _range(self) -> MavlinkSection:
        if self.pwm_max <= self.pwm_min:
            raise ValueError("pwm_max must be greater than pwm_min")
        return self


def _kind_of(value) -> str:
    return value.get("kind", "sim") if isinstance(value, dict) else getattr(value, "kind", "sim")


BackendSection = Annotated[Union[tuple(Annotated[load(k.section), Tag(k.name)] for k in KINDS.values())],  # noqa: UP007
                           Discriminator(_kind_of, custom_error_type="backend_kind",
                                         custom_error_message=f"kind must be one of {', '.join(KINDS)}")]
"""The ``[backend]`` section: the section class of its ``kind`` (each kind names its class in
:data:`~groundstation.backend_kinds.KINDS`), so a key of another kind is an unknown key."""
