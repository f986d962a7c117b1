"""Flight configuration files (``configs/flights/*.toml``): everything ``groundstation fly`` needs.

Paths (assembly, log directory) are relative to the config file. Unknown keys are errors that name the file and
the key path. Backends: ``sim`` (PyBullet in this process, with a virtual mocap), ``crazyflie`` (one cflib link
per module: Crazyradio, or UDP to simulated modules from ``groundstation sim-peer``) and ``mavlink`` (one
pymavlink connection per PX4 module: serial, UDP, or ``groundstation sim-peer --protocol mavlink``).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from pydantic import ConfigDict, Field, field_validator, model_validator
from pydantic.dataclasses import dataclass

from groundstation import config
from groundstation.backends.section import BackendSection, SimSection
from groundstation.control.geometric import Gains
from groundstation.runtime.flight import FailsafePolicy

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)
MAX_DURATION_S = 3600.0


@dataclass(frozen=True, config=_STRICT)
class TlsSection:
    """Zenoh over TLS for a lab network (paths relative to the flight config; endpoints ``tls/HOST:PORT``)."""

    root_ca: str
    """PEM file of the CA that signed every peer's certificate."""
    certificate: str | None = None
    """This ground station's certificate (PEM); required with ``mutual``."""
    private_key: str | None = None
    """Its private key (PEM)."""
    mutual: bool = True
    """Mutual TLS: every peer (mocap bridge, simulator) must present a certificate signed by ``root_ca``."""

    @model_validator(mode="after")
    def _pair(self) -> TlsSection:
        if (self.certificate is None) != (self.private_key is None):
            raise ValueError("certificate and private_key go together")
        if self.mutual and self.certificate is None:
            raise ValueError("mutual TLS needs this peer's certificate and private_key")
        return self


_KEY_CHUNK = re.compile(r"[^/*$?#\s]+")
"""One concrete Zenoh key chunk: not empty, no separator, wildcard or forbidden character."""


def _concrete_key(value: str, chunks: str) -> str:
    if not all(_KEY_CHUNK.fullmatch(c) for c in value.split("/")) or (chunks == "one" and "/" in value):
        what = "one key chunk" if chunks == "one" else "key chunks separated by '/'"
        raise ValueError(f"must be {what}, concrete (not empty; no '*', '$', '?', '#' or spaces), not {value!r}")
    return value


@dataclass(frozen=True, config=_STRICT)
class MocapSection:
    body: str = "assembly"
    """Rigid body name; the pose key is ``<key_prefix>/<body>/pose``: one concrete Zenoh key chunk (no ``/``, no
    wildcard ``*`` or ``$*``, no ``?`` or ``#``): a wildcard would subscribe to every body's poses."""
    key_prefix: str = "mocap"
    """Concrete chunks separated by ``/``, the same rules."""
    endpoint: str = "tcp/127.0.0.1:7448"
    """Zenoh endpoint (loopback by default; multicast scouting is always off)."""
    listen: bool = False
    """The ground station listens on the endpoint (True) or connects to it (False, the default: the mocap
    bridge or the simulator listens)."""
    rate_hz: float = Field(100.0, gt=0, le=1000)
    """Simulated mocap only: publish rate, Hz (camera systems run at 100-360 Hz; above 1 kHz is a typo)."""
    position_noise: float = Field(0.0005, ge=0)
    """Simulated mocap only: position noise std, m."""
    attitude_noise_deg: float = Field(0.1, ge=0)
    """Simulated mocap only: attitude noise std, deg."""
    latency_s: float = Field(0.005, ge=0, le=1.0)
    """Simulated mocap only: latency, s."""
    max_speed: float = Field(10.0, gt=0)
    """Poses implying faster motion than this are rejected as outliers, m/s."""
    tls: TlsSection | None = None
    """TLS on the mocap link (default: none, loopback)."""
    access_control: str | None = None
    """A JSON5 file holding Zenoh's ``access_control`` block (relative to this config)."""

    @field_validator("body")
    @classmethod
    def _body_concrete(cls, value: str) -> str:
        return _concrete_key(value, "one")

    @field_validator("key_prefix")
    @classmethod
    def _prefix_concrete(cls, value: str) -> str:
        return _concrete_key(value, "many")

    @model_validator(mode="after")
    def _secure_endpoint(self) -> MocapSection:
        if self.tls is not None and not self.endpoint.startswith("tls/"):
            raise ValueError(f"with tls the endpoint must be tls/HOST:PORT, not {self.endpoint}")
        return self


@dataclass(frozen=True, config=_STRICT)
class TrajectorySection:
    kind: Literal["hover", "circle", "figure8"] = "figure8"
    size: float = Field(0.6, gt=0)
    """Figure-8 l0 or circle radius, m (the geofence bounds it)."""
    period: float = Field(8.0, gt=0)
    """Figure-8 t_c or circle period, s (preflight bounds the speed and acceleration it asks)."""
    height: float = Field(1.0, gt=0)
    """h0, m."""
    duration: float = Field(16.0, gt=0, le=MAX_DURATION_S)
    """Tracking time, s (at most an hour: no battery lasts longer)."""
    roll_deg: float = 0.0
    takeoff_s: float = Field(3.0, gt=0)
    landing_s: float = Field(3.0, gt=0)


@dataclass(frozen=True, config=_STRICT)
class GainsSection:
    """Controller gains (defaults and meaning: :class:`~groundstation.control.geometric.Gains`)."""

    position_hz: float = Field(Gains.position_hz, gt=0)
    position_zeta: float = Field(Gains.position_zeta, gt=0)
    attitude_hz: float = Field(Gains.attitude_hz, gt=0)
    attitude_zeta: float = Field(Gains.attitude_zeta, gt=0)


@dataclass(frozen=True, config=_STRICT)
class FailsafeSection:
    """The flight's failsafes (:class:`~groundstation.runtime.flight.FailsafePolicy` holds the defaults and what
    each means)."""

    mocap_timeout_s: float = Field(FailsafePolicy.mocap_timeout_s, gt=0)
    on_mocap_stale: Literal["land", "stop"] = FailsafePolicy.on_mocap_stale
    on_mocap_fault: Literal["land", "stop"] = FailsafePolicy.on_mocap_fault
    """A second publisher on the body's key (its samples are never used)."""
    max_tilt_deg: float = Field(FailsafePolicy.max_tilt_deg, gt=0, le=180)
    geofence_lower: tuple[float, float, float] = FailsafePolicy.geofence_lower
    geofence_upper: tuple[float, float, float] = FailsafePolicy.geofence_upper
    max_link_latency_s: float = Field(FailsafePolicy.max_link_latency_s, gt=0)
    """crazyflie: a module's command round trip beyond this (median of its newest echoes) is a degraded link, s."""
    link_stop_latency_s: float = Field(FailsafePolicy.link_stop_latency_s, gt=0)
    """crazyflie: beyond this round trip the motors stop whatever ``on_link_degraded`` says (too slow to land), s."""
    max_link_loss: float = Field(FailsafePolicy.max_link_loss, gt=0, le=1)
    """crazyflie: a module that does not accept this fraction of commands (lost, reordered) is degraded."""
    on_link_degraded: Literal["land", "stop"] = FailsafePolicy.on_link_degraded
    max_stall_s: float = Field(FailsafePolicy.max_stall_s, gt=0)
    """A gap between control periods beyond this stops the motors (the modules have stopped theirs), s."""
    on_log_failure: Literal["land", "continue"] = FailsafePolicy.on_log_failure
    """The log writer failed (e.g. a full disk): land, or fly on unlogged."""
    max_tracking_error_m: float = Field(FailsafePolicy.max_tracking_error_m, gt=0)
    """Airborne, the measured position farther than this from the reference lands the flight, m."""


@dataclass(frozen=True, config=_STRICT)
class FlightConfig:
    assembly: str
    """Assembly file, relative to this config."""
    rate_hz: float = Field(250.0, ge=50, le=1000)
    """Control loop rate, Hz."""
    realtime_priority: int = Field(0, ge=0, le=99)
    """SCHED_FIFO priority of the control loop thread (0: normal scheduling). Needs CAP_SYS_NICE or an rtprio
    limit; if not permitted, the flight runs at normal priority and logs a warning."""
    log_dir: str = "../../out/flights"
    """Where MCAP logs go, relative to this config."""
    allocation: Literal["clip", "bounded"] = "clip"
    backend: BackendSection = SimSection()
    mocap: MocapSection = MocapSection()
    trajectory: TrajectorySection = TrajectorySection()
    gains: GainsSection = GainsSection()
    failsafe: FailsafeSection = FailsafeSection()


def mocap_security(m: MocapSection, base: Path, src: str):
    """The Zenoh security of the mocap link (None: plain), its files resolved against ``base``; a missing file
    is a ConfigError naming the key."""
    from groundstation.errors import ConfigError
    from groundstation.mocap.zenoh_link import Security

    def existing(value: str | None, key: str) -> str | None:
        if value is None:
            return None
        p = (base / value).resolve()
        if not p.is_file():
            raise ConfigError(f"file not found: {p}", path=src, key=key)
        return str(p)

    if m.tls is None and m.access_control is None:
        return None
    acl_path = existing(m.access_control, "mocap.access_control")
    t = m.tls
    return Security(root_ca=existing(t.root_ca, "mocap.tls.root_ca") if t else None,
                    certificate=existing(t.certificate, "mocap.tls.certificate") if t else None,
                    private_key=existing(t.private_key, "mocap.tls.private_key") if t else None,
                    mutual=t.mutual if t else True,
                    access_control=Path(acl_path).read_text() if acl_path else None)


def load_flight_config(path: str | Path) -> tuple[FlightConfig, Path]:
    """The validated config and the directory its relative paths start from."""
    p = Path(path)
    return config.load(FlightConfig, p), p.resolve().parent
