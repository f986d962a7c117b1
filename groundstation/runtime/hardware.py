"""Flying real (or protocol-simulated) modules: what a hardware kind of :mod:`groundstation.backend_kinds` opens.

The world of a hardware flight is its backend's links; time passes by itself and the pose comes from whatever
publishes it on Zenoh (a mocap bridge, or ``groundstation sim-peer``).
"""

from __future__ import annotations

from collections.abc import Callable

from groundstation.assembly.assembly import Assembly
from groundstation.backend_kinds import backend_kind, load
from groundstation.backends.base import Backend
from groundstation.backends.crazyflie import CrazyflieBackend, CrazyflieSettings
from groundstation.backends.mavlink import MavlinkBackend, MavlinkSettings
from groundstation.backends.radio_budget import radio_budget_issues
from groundstation.loop_activity import LoopActivity
from groundstation.mocap.zenoh_link import Security
from groundstation.runtime.flight_config import FlightConfig


def open_crazyflie(cfg: FlightConfig, assembly: Assembly) -> CrazyflieBackend:
    b, f = cfg.backend, cfg.failsafe
    return CrazyflieBackend(b.modules, assembly.params, assembly.module_rotations,
                            CrazyflieSettings(link_timeout=b.link_timeout_s, min_battery_v=b.min_battery_v,
                                              command_period=1.0 / cfg.rate_hz,
                                              max_latency=f.max_link_latency_s, max_loss=f.max_link_loss))


def crazyflie_config_issues(cfg: FlightConfig, assembly: Assembly) -> list[tuple[str, str]]:
    """(key, issue) for what a Crazyflie flight needs of its config: the modules' thrust map, and a radio that
    carries the rate."""
    out = []
    if assembly.params.motor_command is None:
        out.append(("assembly", "the assembly's module_params has no motor_command (the thrust map of the modules' "
                                "platform, see configs/modules/paper_table2.toml)"))
    budget = radio_budget_issues(cfg.backend.modules, cfg.rate_hz, cfg.backend.radio_capacity_hz)
    if budget:
        out.append(("backend.modules", "; ".join(budget)))
    return out


def open_mavlink(cfg: FlightConfig, assembly: Assembly) -> MavlinkBackend:
    b, f = cfg.backend, cfg.failsafe
    return MavlinkBackend(b.modules, assembly.params.u_max, assembly.module_rotations,
                          MavlinkSettings(link_timeout=b.link_timeout_s, min_battery_v=b.min_battery_v,
                                          pwm_min=b.pwm_min, pwm_max=b.pwm_max, max_latency=f.max_link_latency_s,
                                          command_period=1.0 / cfg.rate_hz))


class HardwareModules:
    """The world of a hardware flight: the backend :data:`~groundstation.backend_kinds.KINDS` names for the config's
    kind, connected on entry and closed on exit. Same constructor as ``sim.world.SimulatedWorld``; the Zenoh,
    fault and mocap-key arguments are the simulator's business and unused here."""

    truth: Callable | None = None
    """No ground truth outside a simulator."""

    def __init__(self, assembly: Assembly, cfg: FlightConfig, key: str, listen: list[str], faults,
                 activity: LoopActivity, security: Security | None = None, mac_key=None) -> None:
        self.backend: Backend = load(backend_kind(cfg.backend.kind).opener)(cfg, assembly)

    def settle(self, t: float) -> None:
        """Preflight, ``t`` s after it began: real time passes by itself."""

    def before_period(self, on_period: Callable[[float], None] | None) -> Callable[[float], None] | None:
        return on_period

    def __enter__(self) -> HardwareModules:
        self.backend.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.backend.close()
