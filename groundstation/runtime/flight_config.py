"""Flight configuration files (``configs/flights/*.toml``): everything ``groundstation fly`` needs.

Paths (assembly, log directory) are relative to the config file. Unknown keys are errors that name the file and
the key path. Backends: ``sim`` (PyBullet in this process, with a virtual mocap), ``crazyflie`` (one cflib link
per module: Crazyradio, or UDP to simulated modules from ``groundstation sim-peer``) and ``mavlink`` (one
pymavlink connection per PX4 module: serial, UDP, or ``groundstation sim-peer --protocol mavlink``).

Every number has a physical bound, checked by :func:`load_flight_config` before anything is opened: a bound of
its own where one exists (``Field``), and where it depends on other keys or on the assembly (the loop rate the
gains need, the mocap latency the stale bound must see, ...) in :func:`bound_issues`. Non-finite numbers are
refused everywhere (``allow_inf_nan=False``).
"""

from __future__ import annotations

import ipaddress
import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Literal

from pydantic import ConfigDict, Field, field_validator, model_validator
from pydantic.dataclasses import dataclass

from groundstation import config
from groundstation.backends.section import BackendSection, SimSection
from groundstation.control.geometric import Gains
from groundstation.errors import ConfigError, GroundstationError
from groundstation.estimation.filter import EstimatorSettings
from groundstation.mocap.stamp_clock import StampClockSettings
from groundstation.runtime.flight import MAX_BLIND_DESCENT_MPS, MAX_HEIGHT_SIGMA_M, FailsafePolicy, QualityBounds

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)
MAX_DURATION_S = 3600.0
"""Longest take-off, tracking, landing or trajectory period, s: no battery of these modules lasts an hour."""
MIN_PHASE_S = 0.1
"""Shortest take-off, landing or trajectory period, s: shorter asks for accelerations no assembly has (a take-off to
1 m in 0.1 s peaks at 580 m/s^2, refused by preflight), and below ~1e-162 s their square is 0 (a traceback)."""
MAX_REACTION_S = 0.5
"""Longest a failsafe may wait before it acts (stale mocap, a loop stall, a silent module, a slow link), s. In
0.5 s an assembly that lost its lift falls g t^2 / 2 = 1.2 m, more than the flight height (h0 = 1 m), and one
flying blind at 2 m/s moves 1 m: a failsafe that waits longer acts after the crash."""
MAX_GEOFENCE_M = 100.0
"""Largest geofence coordinate, m: motion capture covers tens of metres; a fence beyond it fences nothing."""
MAX_MOCAP_SPEED = 50.0
"""Largest ``mocap.max_speed``, m/s: racing quadrotors, the fastest multirotors, reach about 40 m/s; a larger
bound turns the speed gate off."""
MAX_PHYSICS_HZ = 2000.0
"""Highest simulated physics rate, Hz. A PyBullet step costs ~0.13 ms (measured, 2 and 60 modules): at 2 kHz
physics takes a quarter of each second of a real-time flight; at 10 kHz it falls behind real time."""
BATTERY_CELLS = {"crazyflie": 1, "mavlink": 14}
"""Most LiPo cells in series a module of each backend kind flies on: every Crazyflie has one; PX4 multirotors fly
packs of up to 12-14 cells."""
LOOP_DELAY_PERIODS = 1.5
"""Delay of the sampled control loop, in control periods: the zero-order hold of the command (half a period)
and one period of transport (the command is computed from a state measured up to a period earlier: the
modules' gyro rates arrive with the echo of the previous command, mocap with its latency)."""
MIN_STALL_PERIODS = 2.0
"""Shortest stall bound, link timeout or link latency bound, in control periods: a healthy loop has one period
between commands and a healthy link answers within one, so a bound of less than two fires in a healthy flight
(and a stall or lost link stops the motors)."""


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


IP_PROTOCOLS = ("tcp", "tls", "udp", "quic")
"""Zenoh endpoint protocols addressed by host and port."""


def endpoint_port_problem(endpoint: str) -> str:
    """Why ``endpoint`` is no Zenoh endpoint to use ("" if it is): ``<protocol>/<address>`` (else Zenoh's own
    error, a traceback, named no option or key), and an IP one's port (``tcp/HOST:PORT``, ``tls``, ``udp``,
    ``quic``) 1-65535 (0 listens on a port no one is told of)."""
    proto, _, address = endpoint.partition("/")
    if not proto or not address.split("?")[0].split("#")[0]:
        return f"{endpoint!r} is not a Zenoh endpoint: <protocol>/<address>, e.g. tcp/127.0.0.1:7448"
    if proto in IP_PROTOCOLS:
        port = address.split("?")[0].split("#")[0].rpartition(":")[2]
        if not port.isdigit() or not 1 <= int(port) <= 65535:
            return f"{endpoint}: the port must be 1-65535, not {port!r}"
    return ""


def _loopback(endpoint: str) -> bool:
    """A Zenoh endpoint (``proto/host:port``) on this machine only."""
    host = endpoint.split("/", 1)[-1].rsplit(":", 1)[0].strip("[]").lower()
    try:
        return host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:  # a name or a malformed address: not known to stay on this machine
        return False


_KEY_CHUNK = re.compile(r"[^/*$?#\s]+")
"""One concrete Zenoh key chunk: not empty, no separator, wildcard or forbidden character."""


MAX_KEY_CHARS = 100
"""Longest ``mocap.body`` and ``mocap.key_prefix``, characters: a name, not a payload (a 70000-character prefix made
Zenoh panic declaring the subscriber)."""


def _concrete_key(value: str, chunks: str) -> str:
    if len(value) > MAX_KEY_CHARS:
        raise ValueError(f"must be at most {MAX_KEY_CHARS} characters, not {len(value)}")
    if not all(_KEY_CHUNK.fullmatch(c) for c in value.split("/")) or (chunks == "one" and "/" in value):
        what = "one key chunk" if chunks == "one" else "key chunks separated by '/'"
        raise ValueError(f"must be {what}, concrete (not empty; no '*', '$', '?', '#' or spaces), not {value!r}")
    return value


MIN_MOCAP_HZ = 50.0
"""Slowest mocap the flight takes, Hz (simulated: ``mocap.rate_hz``; a real system's rate is its own): the estimator
calls poses rejected for :attr:`~groundstation.estimation.filter.EstimatorSettings.inconsistent_s` (50 ms) on end a
fault (a frozen, swapped or forged stream), and at 20 Hz one pose rejected was that: a healthy flight landed on
"every pose rejected for 52 ms" (hostile campaign); at 5 Hz it went stale in the take-off."""


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
    rate_hz: float = Field(100.0, ge=MIN_MOCAP_HZ, le=1000)
    """Simulated mocap only: publish rate, Hz (camera systems run at 100-360 Hz; above 1 kHz is a typo; at least
    :data:`MIN_MOCAP_HZ`)."""
    position_noise: float = Field(0.0005, ge=0, le=0.05)
    """The mocap's position noise std per axis, m: what the estimator assumes (at least
    :data:`MIN_POSITION_NOISE`) and what simulated mocap adds (at most 5 cm: a worse mocap is no mocap)."""
    attitude_noise_deg: float = Field(0.1, ge=0, le=5)
    """The mocap's attitude noise std per axis, deg: assumed (at least :data:`MIN_ATTITUDE_NOISE_DEG`) and
    simulated, likewise."""
    latency_s: float = Field(0.005, ge=0)
    """The mocap's latency from capture to the ground station, s (with one sample interval below
    ``failsafe.mocap_timeout_s``: :func:`bound_issues`): the estimator times each pose this long before its stamp
    on the local clock (a mocap bridge stamps when it gets the frame: the camera system's own latency, a few ms),
    and simulated mocap delivers its poses this late."""
    clock_drift_s: float = Field(StampClockSettings.max_rise_s, ge=0, le=StampClockSettings.max_skew_s)
    """How far the mocap host's clock may drift from this one's over a flight, s: 0 with the bridge on this host,
    a few ms with both hosts on NTP (chrony); free-running clocks drift apart up to ~6 ms a minute. The stream's
    clock offset rises at most this much in all: a delay grown slowly on the path (a man in the middle) is taken
    for drift only this far, beyond it the poses are known to be late and past ``max_skew_s`` (50 ms) more they are
    rejected: a blind landing. At most 50 ms: more would let a delay that long pass as drift."""
    max_speed: float = Field(10.0, gt=0, le=MAX_MOCAP_SPEED)
    """Poses implying faster motion than this are rejected as outliers, m/s (at most :data:`MAX_MOCAP_SPEED`)."""
    preflight_watch_s: float = Field(1.0, ge=0.2, le=2.0)
    """Preflight watches the stream at least this long before arming, s: a second publisher on the key (another
    bridge, a forger) shows up as a conflict, and the assembly must be seen resting meanwhile. At least 0.2 s (20
    samples of each of two 100 Hz publishers), at most 2 s (preflight waits 3 s in all for the stream)."""
    tls: TlsSection | None = None
    """TLS on the mocap link (default: none, loopback)."""
    access_control: str | None = None
    """A JSON5 file holding Zenoh's ``access_control`` block (relative to this config)."""
    key_file: str | None = None
    """The key shared with the mocap bridge (``groundstation mocap-key``; relative to this config): samples
    without its MAC are never used. Required, like TLS, on an endpoint that is not loopback."""

    @field_validator("body")
    @classmethod
    def _body_concrete(cls, value: str) -> str:
        if value == "stats":  # its poses would be logged on /mocap/stats, the subscriber's counters' channel
            raise ValueError("'stats' is the name of the log's /mocap/stats channel: name the body otherwise")
        return _concrete_key(value, "one")

    @field_validator("key_prefix")
    @classmethod
    def _prefix_concrete(cls, value: str) -> str:
        return _concrete_key(value, "many")

    @field_validator("endpoint")
    @classmethod
    def _endpoint_port(cls, value: str) -> str:
        problem = endpoint_port_problem(value)
        if problem:
            raise ValueError(problem)
        return value

    @model_validator(mode="after")
    def _secure_endpoint(self) -> MocapSection:
        if self.tls is not None and not self.endpoint.startswith("tls/"):
            raise ValueError(f"with tls the endpoint must be tls/HOST:PORT, not {self.endpoint}")
        if self.key_file is None and self.tls is None and not _loopback(self.endpoint):
            raise ValueError(f"{self.endpoint} is not loopback: anyone on that network could publish poses; set "
                             f"key_file (groundstation mocap-key) or tls")
        return self


MIN_POSITION_NOISE = 1e-4
"""Least position noise the estimator assumes, m: a simulator's exact poses still differ from the estimator's
model, and a zero would make it trust one pose without limit."""
MIN_ATTITUDE_NOISE_DEG = 0.02
"""Least attitude noise the estimator assumes, deg (likewise)."""


@dataclass(frozen=True, config=_STRICT)
class TrajectorySection:
    kind: Literal["hover", "circle", "figure8"] = "figure8"
    size: float = Field(0.6, gt=0, le=MAX_GEOFENCE_M)
    """Figure-8 l0 or circle radius, m (the geofence bounds it)."""
    period: float = Field(8.0, ge=MIN_PHASE_S, le=MAX_DURATION_S)
    """Figure-8 t_c or circle period, s (preflight bounds the speed and acceleration it asks; at most an hour)."""
    height: float = Field(1.0, gt=0, le=MAX_GEOFENCE_M)
    """h0, m (the geofence bounds it)."""
    duration: float = Field(16.0, ge=MIN_PHASE_S, le=MAX_DURATION_S)
    """Tracking time, s (at most an hour: no battery lasts longer; at least :data:`MIN_PHASE_S`: 5e-324 s flew, with
    a NaN tracking error, hostile campaign 32)."""
    roll_deg: float = 0.0
    """Roll target while tracking, deg (one the assembly hovers at, and with the controller's lean below
    ``failsafe.max_tilt_deg``: :func:`bound_issues`)."""
    takeoff_s: float = Field(3.0, ge=MIN_PHASE_S, le=MAX_DURATION_S)
    """Take-off time, s (at most an hour)."""
    settle_s: float = Field(1.5, ge=0, le=MAX_DURATION_S)
    """Settling before tracking (the attitude target blended to the trajectory's) and holding after it, s each."""
    landing_s: float = Field(3.0, ge=MIN_PHASE_S, le=MAX_DURATION_S)
    """Landing time, s (at most an hour; at least the height over 0.8 m/s: a shorter one is stretched to that,
    ``trajectory.MAX_LANDING_MPS``)."""


@dataclass(frozen=True, config=_STRICT)
class GainsSection:
    """Controller gains (defaults and meaning: :class:`~groundstation.control.geometric.Gains`): bandwidths, Hz,
    and damping ratios. The loop rate bounds them (:func:`loop_rate_needed`)."""

    position_hz: float = Field(Gains.position_hz, ge=0.3)
    """At least 0.3 Hz: slower, a take-off of seconds is not followed (at 1e-9 Hz one armed, and its landing time ran
    out while it still climbed)."""
    position_zeta: float = Field(Gains.position_zeta, ge=0.3)
    """At least 0.3: less damped, a step overshoots by more than 37 %."""
    attitude_hz: float = Field(Gains.attitude_hz, ge=1.0)
    """At least 1 Hz: slower, the attitude cannot follow the lean the position loop asks."""
    attitude_zeta: float = Field(Gains.attitude_zeta, gt=0)
    max_tilt_deg: float = Field(Gains.max_tilt_deg, gt=0, le=60)


_FenceM = Annotated[float, Field(ge=-MAX_GEOFENCE_M, le=MAX_GEOFENCE_M)]
MIN_TILT_DEG = 20.0
"""Least ``failsafe.max_tilt_deg``, deg: nominal flights tilt up to 13 deg (the test flights' 1 s figure-8: 12.9 deg;
the shipped 8 s one 4.7 deg, 6.9 at a roll target of -5 deg; a take-off 0.5 deg), and a floor off level and the
attitude noise add a few more. At 1e-12 deg the flight armed and stopped at once (an emergency stop latches real
Crazyflie modules until rebooted). It must also exceed the controller's lean with the roll target
(:func:`bound_issues`)."""
MAX_TILT_DEG = 90.0
"""Largest ``failsafe.max_tilt_deg``, deg: beyond 90 deg the rotors push the assembly toward the ground; a tilt
failsafe that waits longer (180: never) acts after the crash."""
MIN_TRACKING_ERROR_M = 0.2
"""Least ``failsafe.max_tracking_error_m``, m: three times the largest of a nominal dry run (6.6 cm in a 1 s landing,
3.8 cm in a 1 s take-off); at 1e-12 m the flight landed as it took off."""
MIN_LINK_LOSS = 0.05
"""Least ``failsafe.max_link_loss``: one lost command in the shortest loss window (0.5 s at 50 Hz: 25 commands) is
4 %, and a healthy radio link loses about 2 %; below it a single lost packet lands the flight."""
MIN_DISTURBANCE_MPS2 = 1.0
"""Least ``failsafe.max_disturbance_mps2``, m/s^2: nearly twice the largest a nominal flight's estimate holds for
``DISTURBANCE_HOLD_S`` (0.56 m/s^2 at a 1 s landing's touchdown, 0.46 in a 1 s take-off; dry run and simulated
Crazyflie and PX4 modules); at 1e-12 the flight stopped its motors 0.1 s after arming."""
MIN_BLIND_DESCENT_MPS = 0.2
"""Least ``failsafe.blind_descent_mps``, m/s: a blind landing's last 0.5 m (``flight.BLIND_SLOW_M``) then take 2.5 s,
and the longest stale bound (``failsafe.mocap_timeout_s``, 0.5 s) passes before it begins: 3.0 s after the last pose,
when the height's std reaches :data:`MIN_HEIGHT_SIGMA_M` (the toy V in the dry run: 0.10 m 2 s after the last pose,
0.245 m after 3 s, 0.30 m after 3.3 s). A landing begun at that height reaches the ground before its estimate is
too uncertain to land on; at 1e-12 m/s a mocap loss stopped the motors 0.55 m up. Checked with every floor at once
(this, :data:`MIN_HEIGHT_SIGMA_M`, :data:`MIN_POSITION_SIGMA_M`, a stale bound of 0.5 s): mocap lost in a hover at
0.5 m, the dry run landed blind."""
MIN_HEIGHT_SIGMA_M = 0.25
"""Least ``failsafe.max_height_sigma_m``, m: with :data:`MIN_BLIND_DESCENT_MPS`, see there; below it the height's
bound stops a blind landing before it can reach the ground from 0.5 m (at 1e-12: wherever mocap is lost)."""
MIN_POSITION_SIGMA_M = 0.6
"""Least ``failsafe.max_position_sigma_m``, m: the horizontal std when the height's passes its bound (0.58 m at 0.30
m, 3.3 s blind, measured as there): a lower bound stops a blind landing that the height's bound lets finish (at
0.5 m a blind landing from 1.6 m stopped its motors 0.12 m up)."""


@dataclass(frozen=True, config=_STRICT)
class FailsafeSection:
    """The flight's failsafes (:class:`~groundstation.runtime.flight.FailsafePolicy` holds the defaults and what
    each means)."""

    mocap_timeout_s: float = Field(FailsafePolicy.mocap_timeout_s, gt=0, le=MAX_REACTION_S)
    on_mocap_stale: Literal["land", "stop"] = FailsafePolicy.on_mocap_stale
    on_mocap_fault: Literal["land", "stop"] = FailsafePolicy.on_mocap_fault
    """A second publisher on the body's key (its samples are never used)."""
    max_tilt_deg: float = Field(FailsafePolicy.max_tilt_deg, ge=MIN_TILT_DEG, le=MAX_TILT_DEG)
    """deg, within :data:`MIN_TILT_DEG` and :data:`MAX_TILT_DEG`, above ``gains.max_tilt_deg`` plus the roll target
    (:func:`bound_issues`)."""
    geofence_lower: tuple[_FenceM, _FenceM, _FenceM] = FailsafePolicy.geofence_lower
    geofence_upper: tuple[_FenceM, _FenceM, _FenceM] = FailsafePolicy.geofence_upper
    """m, each coordinate within +-:data:`MAX_GEOFENCE_M`."""
    max_link_latency_s: float = Field(FailsafePolicy.max_link_latency_s, gt=0, le=MAX_REACTION_S)
    """A module's command round trip beyond this (median of its newest echoes, or of its newest TIMESYNC answers
    on MAVLink) is a degraded link, s."""
    link_stop_latency_s: float = Field(FailsafePolicy.link_stop_latency_s, gt=0, le=MAX_REACTION_S)
    """Beyond this round trip the motors stop whatever ``on_link_degraded`` says (too slow to land), s."""
    max_link_loss: float = Field(FailsafePolicy.max_link_loss, ge=MIN_LINK_LOSS, le=1)
    """A module whose link loses this fraction (commands not accepted on Crazyflie, TIMESYNC probes unanswered on
    MAVLink) is degraded (at least
    :data:`MIN_LINK_LOSS`)."""
    on_link_degraded: Literal["land", "stop"] = FailsafePolicy.on_link_degraded
    max_stall_s: float = Field(FailsafePolicy.max_stall_s, gt=0, le=MAX_REACTION_S)
    """A gap between control periods beyond this stops the motors (the modules have stopped theirs), s."""
    on_log_failure: Literal["land", "continue"] = FailsafePolicy.on_log_failure
    """The log writer failed (e.g. a full disk): land, or fly on unlogged."""
    max_position_sigma_m: float = Field(FailsafePolicy.max_position_sigma_m, ge=MIN_POSITION_SIGMA_M,
                                        le=MAX_GEOFENCE_M)
    """Flying blind on the estimate, the motors stop beyond this horizontal position std, m (at least
    :data:`MIN_POSITION_SIGMA_M`)..."""
    max_height_sigma_m: float = Field(FailsafePolicy.max_height_sigma_m, ge=MIN_HEIGHT_SIGMA_M,
                                      le=MAX_HEIGHT_SIGMA_M)
    """...or beyond this height std, m (:data:`MIN_HEIGHT_SIGMA_M` to :data:`MAX_HEIGHT_SIGMA_M`)."""
    blind_descent_mps: float = Field(FailsafePolicy.blind_descent_mps, ge=MIN_BLIND_DESCENT_MPS,
                                     le=MAX_BLIND_DESCENT_MPS)
    """A landing begun on stale mocap touches down at this speed, m/s (at most :data:`MAX_BLIND_DESCENT_MPS`:
    faster touches down too hard; at least :data:`MIN_BLIND_DESCENT_MPS`: slower, the estimate is too uncertain
    before it is down)."""
    max_tracking_error_m: float = Field(FailsafePolicy.max_tracking_error_m, ge=MIN_TRACKING_ERROR_M)
    """Airborne, the measured position farther than this from the reference lands the flight, m (at least
    :data:`MIN_TRACKING_ERROR_M`; below the geofence's diagonal: :func:`bound_issues`)."""
    max_disturbance_mps2: float = Field(FailsafePolicy.max_disturbance_mps2, ge=MIN_DISTURBANCE_MPS2, le=100)
    """The acceleration the model misses may not stay above this, m/s^2 (at least :data:`MIN_DISTURBANCE_MPS2`,
    at most 100: 10 g)."""


@dataclass(frozen=True, config=_STRICT)
class QualitySection:
    """How far a flight that flew its plan may degrade and still be nominal (``fly`` exit 0, else 3):
    :class:`~groundstation.runtime.flight.QualityBounds` holds the defaults, what each means and what was measured.
    A lab that publishes its flights tightens them."""

    attitude_error_p95_deg: float = Field(QualityBounds.attitude_error_p95_deg, gt=0, le=180)
    """deg."""
    max_attitude_error_deg: float = Field(QualityBounds.max_attitude_error_deg, gt=0, le=180)
    """deg."""
    max_saturation: float = Field(QualityBounds.max_saturation, gt=0, le=1)
    """Share of the airborne periods, fraction."""
    max_late_fraction: float = Field(QualityBounds.max_late_fraction, gt=0, le=1)
    """Share of the control periods, fraction."""


@dataclass(frozen=True, config=_STRICT)
class FlightConfig:
    assembly: str
    """Assembly file, relative to this config."""
    rate_hz: float = Field(250.0, ge=50, le=1000)
    """Control loop rate, Hz."""
    realtime_priority: int = Field(10, ge=0, le=99)
    """SCHED_FIFO priority of the control loop thread (0: normal scheduling). Needs CAP_SYS_NICE or an rtprio
    limit; if not permitted, the flight runs at normal priority and logs a warning. On by default: with two busy
    processes beside a Crazyflie flight on 2 cores, a normal-priority loop was held off the CPU for 20-50 ms some
    forty times in a flight and the V's pitch oscillated into an emergency stop (one flight in four); at 10, 0-4
    such stalls, 4 of 4 flights landed (2026-12-02)."""
    log_dir: str = "../../out/flights"
    """Where MCAP logs go, relative to this config."""
    allocation: Literal["clip", "bounded"] = "bounded"
    """How the controller's wrench becomes rotor inputs: ``bounded`` (the producible wrench nearest the request
    when rotors saturate; the paper's clipped inverse otherwise) or ``clip`` (the paper's §V, clipped always).
    Clipping changes the produced wrench's direction when rotors saturate: an operator landing begun at the
    figure-8's fastest point saturated the Crazyflie V's rotors for 0.5 s, and clipped commands rolled it past
    75 deg (its firmware and our model of it alike); bounded, it landed with under 0.2 deg of roll (2026-12-02)."""
    backend: BackendSection = SimSection()
    mocap: MocapSection = MocapSection()
    trajectory: TrajectorySection = TrajectorySection()
    gains: GainsSection = GainsSection()
    failsafe: FailsafeSection = FailsafeSection()
    quality: QualitySection = QualitySection()


def estimator_settings(cfg: FlightConfig) -> EstimatorSettings:
    """The estimator's view of the config's mocap and gyros (its other settings keep their defaults)."""
    m = cfg.mocap
    return EstimatorSettings(position_noise=max(m.position_noise, MIN_POSITION_NOISE),
                             attitude_noise=math.radians(max(m.attitude_noise_deg, MIN_ATTITUDE_NOISE_DEG)),
                             gyro_delay=cfg.backend.gyro_delay_s,
                             thrust_lag=cfg.backend.motor_time_constant if isinstance(cfg.backend, SimSection)
                             else cfg.backend.thrust_lag_s)


def mocap_mac_key(m: MocapSection, base: Path, src: str):
    """The mocap key of ``mocap.key_file`` (None: unauthenticated), a ConfigError naming the key if it is bad."""
    from groundstation.mocap.auth import load_key_file

    if m.key_file is None:
        return None
    try:
        return load_key_file(base / m.key_file)
    except GroundstationError as exc:
        raise ConfigError(str(exc), path=src, key="mocap.key_file") from None


def log_directory(cfg: FlightConfig, base: Path, src: str) -> Path:
    """``log_dir`` resolved against the config's directory; one it cannot resolve (a symlink loop) is a
    ConfigError naming the key."""
    try:
        return (base / cfg.log_dir).resolve()
    except (OSError, RuntimeError) as exc:  # a symlink loop is a RuntimeError on Python < 3.13
        raise ConfigError(f"log directory cannot be resolved: {exc}", path=src, key="log_dir") from None


def mocap_security(m: MocapSection, base: Path, src: str):
    """The Zenoh security of the mocap link (None: plain), its files resolved against ``base``; a missing file
    (or an access-control file that is not text) is a ConfigError naming the key."""
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
    try:
        acl = config.read_text(acl_path) if acl_path else None
    except ConfigError as exc:
        raise ConfigError(str(exc), path=src, key="mocap.access_control") from None
    t = m.tls
    return Security(root_ca=existing(t.root_ca, "mocap.tls.root_ca") if t else None,
                    certificate=existing(t.certificate, "mocap.tls.certificate") if t else None,
                    private_key=existing(t.private_key, "mocap.tls.private_key") if t else None,
                    mutual=t.mutual if t else True, access_control=acl)


def loop_rate_needed(natural_hz: float, zeta: float) -> float:
    """The least control-loop rate, Hz, that realises a loop of natural frequency ``natural_hz`` (Hz) and damping
    ratio ``zeta``: the rule is that sampling may take at most half the loop's phase margin.

    The geometric controller closes each axis as a PD loop on a double integrator (gains scaled by the mass and
    inertia, so the loop's natural frequency is the configured bandwidth ``w``): the open loop
    ``L(s) = (w^2 + 2 zeta w s) / s^2`` crosses over at ``w_c = w sqrt(2 zeta^2 + sqrt(4 zeta^4 + 1))`` with a
    phase margin ``PM = atan(2 zeta w_c / w)``. Run at a rate ``f`` it lags by :data:`LOOP_DELAY_PERIODS` periods
    (hold and transport), ``1.5 w_c / f`` rad at the crossover; keeping that within ``PM / 2`` needs
    ``f >= 3 w_c / PM``. Why half: at that bound the loop sampled with one period of delay goes unstable at 1.9 to
    2.0 times the bandwidth (same damping) for any damping from 0.05 to 20 (the tests check it against the exact
    discrete loop), so every loop keeps the same margin whatever its damping. For the
    defaults (4 Hz, zeta 0.9) this asks 110 Hz: the natural frequency stays at a 14th of the Nyquist rate, half
    the frequency (a 7th of Nyquist) at which the delayed sampled loop goes unstable. Very low damping asks more
    (its margin is small to begin with), very high damping too (its fast pole is at ``~2 zeta w``).
    """
    w = 2 * math.pi * natural_hz
    wc = w * math.sqrt(2 * zeta * zeta + math.hypot(2 * zeta * zeta, 1.0))
    pm = math.atan2(2 * zeta * wc, w)
    return 2 * LOOP_DELAY_PERIODS * wc / pm


def axis_coupling(inertia) -> list[float]:
    """The eigenvalues ``mu`` of ``J^-1 diag(J)`` for an inertia ``J`` (kg m^2, body frame): the attitude gains
    scale with ``diag(J)``, so a mode of the linearised attitude loop has natural frequency ``w sqrt(mu)`` and
    damping ``zeta sqrt(mu)`` (all 1 for principal axes; 0.84-1.23 for the shipped assemblies)."""
    import numpy as np

    j = np.asarray(inertia, dtype=float)
    return sorted(float(mu) for mu in np.linalg.eigvals(np.linalg.solve(j, np.diag(np.diag(j)))).real)


def bound_issues(cfg: FlightConfig, inertia, model=None) -> Iterator[tuple[str, str]]:
    """The bounds that depend on other keys or on the assembly (``inertia``: its inertia, kg m^2, body frame;
    ``model``: its :class:`~groundstation.control.model.ControlModel`, for the roll target's hover):
    ``(key, problem)`` for each key beyond its bound. The rules, and why:

    * ``gains.*_hz`` and ``*_zeta``: the loop rate realises them (:func:`loop_rate_needed`); the loop runs at
      ``rate_hz``, or at the simulator's ``backend.physics_hz`` if slower (the plant changes no faster); the
      attitude loop per mode of :func:`axis_coupling`;
    * ``backend.physics_hz``: at most :data:`MAX_PHYSICS_HZ`; ``backend.motor_time_constant``: below the attitude
      loop's time constant ``1 / (2 pi attitude_hz sqrt(mu_max))``, or the rotors cannot follow the loop
      (measured, the V at 4 Hz: flies with 1.5 times it, tips over at 2.5 times);
    * ``backend.link_timeout_s``: between :data:`MIN_STALL_PERIODS` periods and :data:`MAX_REACTION_S`;
      ``radio_capacity_hz`` at most 1000 (a Crazyradio carries 450-500 round trips a second: twice that would let
      the radio budget pass dongles that drop packets); ``pwm_min`` in 800-1400 and ``pwm_max`` in 1600-2200 us (PX4's
      own ranges of PWM_MAIN_MIN and PWM_MAIN_MAX); ``min_battery_v`` below a full battery (:data:`BATTERY_CELLS`);
      these belong to the backend sections (:mod:`groundstation.backends.section`) and are checked here until
      they have them;
    * ``mocap.latency_s``: with one sample interval (``1 / mocap.rate_hz``), below ``failsafe.mocap_timeout_s``:
      the newest pose of a working stream is that old, so a longer latency makes every pose stale on arrival;
    * ``mocap.position_noise``, ``attitude_noise_deg``: 3 standard deviations of the difference of two samples
      (``3 sqrt(2) sigma``) inside the subscriber's position and attitude gates, or genuine poses are rejected;
    * ``trajectory.roll_deg``: below ``failsafe.max_tilt_deg``, or the target itself trips the tilt failsafe; with
      the controller's lean limit (``gains.max_tilt_deg``: a shove, a reference far off) below it too, and
      ``failsafe.max_tilt_deg`` above that limit, or the failsafe stops an assembly doing as it is told; one the
      assembly hovers at (with ``model``: :func:`~groundstation.runtime.closed_loop.roll_hover_issue`);
    * ``failsafe.max_stall_s``: at least :data:`MIN_STALL_PERIODS` control periods;
      ``failsafe.max_link_latency_s``: at least that too, and below ``link_stop_latency_s`` (degraded, land,
      before too slow, stop);
    * ``failsafe.max_tracking_error_m``: below the geofence's diagonal; no two points inside the fence are
      farther apart, so a larger bound could only fire outside, after the geofence stopped the motors.
    """
    from groundstation.assembly.module import FULL_CELL_V

    period = 1.0 / cfg.rate_hz
    rate, rate_key = cfg.rate_hz, "rate_hz"
    physics_hz = getattr(cfg.backend, "physics_hz", None)
    if physics_hz is not None and physics_hz < rate:
        rate, rate_key = physics_hz, "backend.physics_hz"
    g = cfg.gains
    mus = axis_coupling(inertia)
    for loop, modes in (("position", [1.0]), ("attitude", mus)):
        hz, zeta = getattr(g, f"{loop}_hz"), getattr(g, f"{loop}_zeta")
        need = max(loop_rate_needed(hz * math.sqrt(mu), zeta * math.sqrt(mu)) for mu in modes)
        if need > rate:
            inertia_note = " with this assembly's inertia" if loop == "attitude" else ""
            yield (f"gains.{loop}_hz",
                   f"{hz:g} Hz at {loop}_zeta = {zeta:g}{inertia_note} needs a control loop of at least {need:.4g} Hz, "
                   f"the loop runs at {rate:g} Hz ({rate_key}): at that rate at most {hz * rate / need:.3g} Hz "
                   f"(sampling and a period of delay may take at most half the phase margin)")
    b = cfg.backend
    if physics_hz is not None and physics_hz > MAX_PHYSICS_HZ:
        yield "backend.physics_hz", f"{physics_hz:g} Hz is above {MAX_PHYSICS_HZ:g} Hz (a step costs ~0.13 ms)"
    tau = getattr(b, "motor_time_constant", None)
    attitude_tau = 1.0 / (2 * math.pi * g.attitude_hz * math.sqrt(mus[-1]))
    if tau is not None and tau > attitude_tau:
        yield ("backend.motor_time_constant", f"{tau:g} s is slower than the attitude loop ({attitude_tau:.3g} s "
                                              f"at gains.attitude_hz = {g.attitude_hz:g}): the rotors cannot follow it")
    timeout = getattr(b, "link_timeout_s", None)
    if timeout is not None and not MIN_STALL_PERIODS * period <= timeout <= MAX_REACTION_S:
        yield ("backend.link_timeout_s", f"{timeout:g} s is outside {MIN_STALL_PERIODS * period:g}.."
                                         f"{MAX_REACTION_S:g} s (two control periods: healthy modules would be "
                                         f"lost; longer: the assembly has fallen before the failsafe acts)")
    capacity = getattr(b, "radio_capacity_hz", None)
    if capacity is not None and capacity > 1000:
        yield "backend.radio_capacity_hz", f"{capacity:g} packets/s is above 1000 (a Crazyradio carries 450-500)"
    for key, lo, hi in (("pwm_min", 800, 1400), ("pwm_max", 1600, 2200)):
        value = getattr(b, key, None)
        if value is not None and not lo <= value <= hi:
            yield f"backend.{key}", f"{value} us is outside PX4's range {lo}..{hi} us"
    cells = BATTERY_CELLS.get(b.kind)
    if cells is not None and b.min_battery_v >= cells * FULL_CELL_V:
        yield ("backend.min_battery_v", f"{b.min_battery_v:g} V is not below a full battery of {cells} cell(s) "
                                        f"({cells * FULL_CELL_V:g} V): no module could fly")

    m, f, t = cfg.mocap, cfg.failsafe, cfg.trajectory
    oldest = m.latency_s + 1.0 / m.rate_hz
    if oldest >= f.mocap_timeout_s:
        yield ("mocap.latency_s", f"{m.latency_s:g} s plus a sample interval ({1.0 / m.rate_hz:g} s at mocap.rate_hz) "
                                  f"is not below failsafe.mocap_timeout_s = {f.mocap_timeout_s:g} s: every pose "
                                  f"would be stale")
    planned = t.takeoff_s + 2 * t.settle_s + t.duration + t.landing_s
    if planned > MAX_DURATION_S:  # each phase within the hour is not enough: five of them made a 5 h plan
        yield ("trajectory", f"the flight plan lasts {planned:g} s (take-off, settle, tracking, hold and landing), "
                             f"more than {MAX_DURATION_S:g} s: no battery of these modules lasts an hour")
    lean = cfg.gains.max_tilt_deg
    if abs(t.roll_deg) >= f.max_tilt_deg:
        yield ("trajectory.roll_deg", f"{t.roll_deg:g} deg is not below failsafe.max_tilt_deg = {f.max_tilt_deg:g} "
                                      f"deg: the target would trip the tilt failsafe")
    elif lean >= f.max_tilt_deg:
        yield ("failsafe.max_tilt_deg", f"{f.max_tilt_deg:g} deg is not above gains.max_tilt_deg = {lean:g} deg, "
                                        f"the lean the controller may ask (a shove, a reference far off): the "
                                        f"failsafe would stop an assembly doing as it is told")
    elif abs(t.roll_deg) + lean >= f.max_tilt_deg:
        yield ("trajectory.roll_deg", f"{t.roll_deg:g} deg with the controller's lean of up to gains.max_tilt_deg = "
                                      f"{lean:g} deg tilts the assembly {abs(t.roll_deg) + lean:g} deg, not below "
                                      f"failsafe.max_tilt_deg = {f.max_tilt_deg:g} deg")
    elif model is not None:
        from groundstation.runtime.closed_loop import roll_hover_issue

        if (issue := roll_hover_issue(model, t.roll_deg)) is not None:
            yield issue
    floor = MIN_STALL_PERIODS * period
    for key in ("max_stall_s", "max_link_latency_s"):
        if getattr(f, key) < floor:
            yield (f"failsafe.{key}", f"{getattr(f, key):g} s is shorter than two control periods ({floor:g} s at "
                                      f"rate_hz = {cfg.rate_hz:g}): it would fire in a healthy flight")
    if f.max_link_latency_s >= f.link_stop_latency_s:
        yield ("failsafe.max_link_latency_s", f"{f.max_link_latency_s:g} s is not below failsafe.link_stop_latency_s "
                                              f"= {f.link_stop_latency_s:g} s: a slow link would stop, never land")
    diagonal = math.dist(f.geofence_lower, f.geofence_upper)
    if f.max_tracking_error_m >= diagonal:
        yield ("failsafe.max_tracking_error_m", f"{f.max_tracking_error_m:g} m is not below the geofence's diagonal "
                                                f"({diagonal:.3g} m): it could never fire inside the fence")


def read_assembly(path: Path):
    """The assembly file at ``path``, read as text first (:func:`groundstation.config.read_json`: size-capped,
    no binary files), then validated like :func:`~groundstation.assembly.assembly_file.load_assembly`."""
    from groundstation.assembly.assembly_file import assembly_from_record

    return assembly_from_record(config.read_json(path), str(path))


def load_flight_config(path: str | Path) -> tuple[FlightConfig, Path]:
    """The validated config and the directory its relative paths start from. Every key within its bounds,
    those that depend on the assembly included (:func:`bound_issues`): the first key beyond one is a
    :class:`ConfigError` naming the file and the key."""
    p = Path(path)
    cfg, base = config.load(FlightConfig, p), p.resolve().parent
    try:
        assembly = read_assembly(base / cfg.assembly)
    except ConfigError as exc:
        raise ConfigError(str(exc), path=str(path), key="assembly") from None
    from groundstation.control.model import ControlModel

    for key, problem in bound_issues(cfg, assembly.inertia, ControlModel.from_assembly(assembly)):
        raise ConfigError(problem, path=str(path), key=key)
    return cfg, base
