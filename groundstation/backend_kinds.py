"""Every kind of backend a flight config may name (``[backend] kind``), in one table: the one place that tells the
kinds apart. A new backend is its module plus one entry in :data:`KINDS`.

Parts are named ``"module:attribute"`` and imported when used, so that naming a kind (validating a config, help)
imports neither its link library nor the simulator, and a hardware flight never imports PyBullet.
"""

from __future__ import annotations

import importlib
import re
from dataclasses import dataclass

_PORT = r"(\d{1,5})"


@dataclass(frozen=True)
class BackendKind:
    name: str
    summary: str
    """One line for docs and errors."""
    section: str
    """``module:class`` of the kind's ``[backend]`` config section."""
    world: str
    """``module:class`` of what a flight flies in: a context manager built from ``(assembly, cfg, key, listen,
    faults, activity, security, mac_key)`` with ``backend``, ``settle(t)`` (preflight, ``t`` s after it began: a
    simulated world follows that clock), ``before_period(on_period)`` and ``truth`` (see
    :class:`groundstation.runtime.hardware.HardwareModules`)."""
    opener: str | None = None
    """Hardware kinds: ``module:function`` making the backend from ``(cfg, assembly)``."""
    links: re.Pattern[str] | None = None
    """Form of one module link; ``None``: the kind takes no module links."""
    link_example: str = ""
    config_issues: str | None = None
    """``module:function`` ``(cfg, assembly) -> list[str]``: what this kind needs of a flight config beyond its
    links (e.g. the radio budget); each issue names ``backend.modules`` or ``assembly``."""
    check_params: str | None = None
    """``module:function`` ``(link, module, wanted, apply, cache_dir) -> list[ParamCheck]`` (None: no firmware)."""
    implied_params: str | None = None
    """``module:function`` ``(section) -> dict``: parameters the config itself implies (PX4's PWM range)."""
    peer: str | None = None
    """``module:class`` simulating these modules behind their wire protocol (``groundstation sim-peer``)."""
    peer_protocol: str = ""
    """``sim-peer --protocol`` value."""
    peer_scheme: str = ""
    """Link prefix a peer's module ``i`` answers on: ``<scheme><host>:<port + i>``."""


KINDS: dict[str, BackendKind] = {k.name: k for k in (
    BackendKind(
        "sim", "PyBullet in this process, publishing its pose through a virtual mocap",
        section="groundstation.backends.section:SimSection", world="sim.world:SimulatedWorld"),
    BackendKind(
        "crazyflie", "Crazyflie modules with the motor app, one cflib link each (Crazyradio, or UDP to sim-peer)",
        section="groundstation.backends.section:CrazyflieSection",
        world="groundstation.runtime.hardware:HardwareModules",
        opener="groundstation.runtime.hardware:open_crazyflie",
        links=re.compile(r"^(radio://\w+(/\d+(/(250K|1M|2M)(/[0-9A-Fa-f]{1,10})?)?)?(\?.*)?"
                         r"|udp://[\w.\-]+:" + _PORT + r"|usb://\d+|serial://\S+|tcp://[\w.\-]+:" + _PORT + r")$"),
        link_example="radio://0/80/2M/E7E7E7E701 or udp://127.0.0.1:19850",
        config_issues="groundstation.runtime.hardware:crazyflie_config_issues",
        check_params="groundstation.firmware.crazyflie_params:check_module",
        peer="sim.crazyflie_peer:SimulatedCrazyflies", peer_protocol="crtp", peer_scheme="udp://"),
    BackendKind(
        "mavlink", "PX4 modules in offboard mode, one pymavlink connection each (serial, UDP, or sim-peer)",
        section="groundstation.backends.section:MavlinkSection",
        world="groundstation.runtime.hardware:HardwareModules",
        opener="groundstation.runtime.hardware:open_mavlink",
        links=re.compile(r"^((udpin|udpout|udp|udpbcast|tcp|tcpin):[\w.\-]+:" + _PORT + r"|/dev/\S+|COM\d+(,\d+)?)$"),
        link_example="udpout:127.0.0.1:14560, udpin:0.0.0.0:14550 or /dev/ttyACM0,921600",
        check_params="groundstation.firmware.px4_params:check_module",
        implied_params="groundstation.firmware.px4_params:pwm_params",
        peer="sim.mavlink_peer:SimulatedPx4", peer_protocol="mavlink", peer_scheme="udpout:"),
)}


def backend_kind(name: str) -> BackendKind:
    """The kind named ``name``; a ValueError listing the kinds otherwise."""
    try:
        return KINDS[name]
    except KeyError:
        raise ValueError(f"unknown backend kind {name!r}; one of {', '.join(KINDS)}") from None


def load(ref: str):
    """The attribute a ``"module:attribute"`` reference names, importing its module."""
    module, _, attribute = ref.partition(":")
    return getattr(importlib.import_module(module), attribute)


def link_problem(kind: str, link: str) -> str:
    """What is wrong with a module link of a ``kind`` backend ("" if nothing): its form, and the port range."""
    k = backend_kind(kind)
    if k.links is None:
        return ""
    if k.links.match(link) is None:
        return f"{link!r} is not a {kind} link (like {k.link_example})"
    if link.startswith("radio://"):
        parts = link.split("?")[0].removeprefix("radio://").split("/")
        if len(parts) > 1 and not 0 <= int(parts[1]) <= 125:
            return f"{link!r}: radio channel {parts[1]} is not in 0..125"
    ports = [int(g) for g in re.findall(r":(\d{1,5})(?:$|\?)", link)]
    bad = [p for p in ports if not 1 <= p <= 65535]
    return f"{link!r}: port {bad[0]} is not in 1..65535" if bad else ""
