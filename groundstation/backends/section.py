"""The ``[backend]`` section of a flight config: which modules fly and over which links.

It belongs to the backends (the firmware-parameter check and every backend read it); the flight config
(:mod:`groundstation.runtime.flight_config`) embeds it.
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import ConfigDict, Field, ValidationInfo, field_validator, model_validator
from pydantic.dataclasses import dataclass

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)

_PORT = r"(\d{1,5})"
_CRAZYFLIE_LINK = re.compile(r"^(radio://\w+(/\d+(/(250K|1M|2M)(/[0-9A-Fa-f]{1,10})?)?)?(\?.*)?"
                             r"|udp://[\w.\-]+:" + _PORT + r"|usb://\d+|serial://\S+|tcp://[\w.\-]+:" + _PORT + r")$")
_MAVLINK_LINK = re.compile(r"^((udpin|udpout|udp|udpbcast|tcp|tcpin):[\w.\-]+:" + _PORT + r"|/dev/\S+|COM\d+(,\d+)?)$")


def link_problem(kind: str, link: str) -> str:
    """What is wrong with a module link of a ``kind`` backend ("" if nothing): its form, and the port range."""
    pattern = _CRAZYFLIE_LINK if kind == "crazyflie" else _MAVLINK_LINK if kind == "mavlink" else None
    if pattern is None:
        return ""
    m = pattern.match(link)
    if m is None:
        example = ("radio://0/80/2M/E7E7E7E701 or udp://127.0.0.1:19850" if kind == "crazyflie" else
                   "udpout:127.0.0.1:14560, udpin:0.0.0.0:14550 or /dev/ttyACM0,921600")
        return f"{link!r} is not a {kind} link (like {example})"
    ports = [int(g) for g in re.findall(r":(\d{1,5})(?:$|\?)", link)]
    if kind == "crazyflie" and link.startswith("radio://"):
        parts = link.split("?")[0].removeprefix("radio://").split("/")
        if len(parts) > 1 and not 0 <= int(parts[1]) <= 125:
            return f"{link!r}: radio channel {parts[1]} is not in 0..125"
    bad = [p for p in ports if not 1 <= p <= 65535]
    return f"{link!r}: port {bad[0]} is not in 1..65535" if bad else ""


@dataclass(frozen=True, config=_STRICT)
class BackendSection:
    kind: Literal["sim", "crazyflie", "mavlink"] = "sim"
    """``sim``: PyBullet in this process. ``crazyflie``: modules over cflib links; ``mavlink``: PX4 modules over
    pymavlink connections (see ``modules``)."""
    physics_hz: float = Field(240.0, gt=0)
    """sim only."""
    motor_time_constant: float = Field(0.02, ge=0)
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
        if self.kind == "sim" and self.firmware_params is not None:
            raise ValueError("firmware_params needs a crazyflie or mavlink backend (sim has no module firmware)")
        return self
