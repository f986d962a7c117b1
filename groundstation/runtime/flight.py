"""The flight: states, failsafes, control and logging of one period, run by the fixed-rate loop.

States and transitions (each logged as an event)::

    preflight -> takeoff -> settle -> track -> hold -> landing -> done
    preflight --(a module refuses to arm, the operator asks to land or stop before arming)--> aborted
         any airborne state --(operator land, mocap stale or link degraded with policy "land", the assembly
                               not following its reference, a module fault the other modules can fly
                               through: the faulty ones isolated; a module's gyro disagreeing with the
                               others')--> landing
         any state --(operator stop, NaN/inf, geofence, tilt, link loss, mocap stale or link degraded with
                      "stop", a module fault the others cannot fly through, flying blind: the estimate's
                      uncertainty (position, height, an attitude nothing observes) beyond its bound)--> emergency
                      (done if the blind landing's reference is below the ground by then)

The state comes from the estimator (:mod:`groundstation.estimation`): mocap fused with the modules' gyros and the
commanded wrench, at the period's time. Through a mocap outage it flies on the estimate (a blind landing) while
the position's and the height's uncertainties stay within ``max_position_sigma_m`` and ``max_height_sigma_m`` (and
the attitude's within :data:`MAX_UNSEEN_ATTITUDE_SIGMA`).

``landing`` descends from where the reference is to below the ground and ends in ``done``: motors off and the
modules disarmed (they can fly again). ``emergency`` sends the backend's emergency stop in the same period it is
entered (real modules latch it until rebooted). ``aborted``: nothing spun; the modules are disarmed. Every failure
path ends in one of these.
"""

from __future__ import annotations

import contextlib
import math
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Literal, Protocol

import numpy as np

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.module import GRAVITY
from groundstation.backends.base import Backend, SimulatedBackend, Telemetry
from groundstation.control.allocation import allocate, allocate_bounded
from groundstation.control.geometric import Gains, control, delay_limited, reference_attitude
from groundstation.control.model import ControlModel
from groundstation.control.phase import Phase
from groundstation.control.state import RigidState, Setpoint
from groundstation.control.trajectory import (
    LANDING_DEPTH,
    MAX_LANDING_MPS,
    Descent,
    FlightPlan,
    Landing,
    roll_pitch_yaw,
)
from groundstation.errors import ArmingError
from groundstation.estimation.filter import EstimatorSettings, RigidBodyFilter
from groundstation.estimation.gyro_check import GyroAgreement
from groundstation.estimation.gyro_torque import TorqueAgreement
from groundstation.estimation.measurement import PoseMeasurement
from groundstation.loop_activity import LoopActivity
from groundstation.rotations import matrix_to_rotvec
from groundstation.runtime.loop import (
    Clock,
    LoopStats,
    collect_young,
    collector_paused,
    run_fixed_rate,
)
from groundstation.runtime.metrics import FlightMetrics, FlightSummary

MAX_BLIND_DESCENT_MPS = 0.6
"""The fastest touchdown a blind landing may plan (``failsafe.blind_descent_mps``; planned landings:
:data:`~groundstation.control.trajectory.MAX_LANDING_MPS`), m/s. Its estimate may be ``max_height_sigma_m`` (0.3
m) and more off: one that high still slows from :data:`BLIND_CRUISE_MPS` before the ground only with this much
margin. Measured from 1 m in the dry run: 0.54 m/s at 0.5, 0.59 at 0.6 (a quintic descent at 1 m/s on average,
as blind landings flew before: 1.58 m/s)."""
GYROS_DISPUTED_RAD = math.radians(1.0)
"""A pose's attitude this far from the estimate's (fused or rejected for it) is the poses and the gyros disagreeing
enough to ask the torque commanded which is wrong (:class:`TorqueAgreement`), rad: three times the largest of a
nominal dry run (0.33 deg), under the estimator's gate (1.5 deg and more with the rate), which a sign-flipped set of
gyros passed 80 ms after the flip, the V tilting 20 deg by then (at 1 deg: 40 ms)..."""
MAX_UNSEEN_ATTITUDE_SIGMA = math.radians(15.0)
"""Flying blind with no gyro either (nothing observes the attitude, held with no torque on it: its uncertainty grows
at ``EstimatorSettings.unseen_rate``), the motors stop once the attitude's std passes this, rad: ~0.5 s after the
last pose. A level landing is not level beyond it; the horizontal position's bound, 1 m, came 0.75 s after."""
DISPUTED_LANDING_M = 0.1
"""A landing whose poses and gyros disagree there (:data:`GYROS_DISPUTED_RAD`, a frame within
:data:`CONTACT_MARGIN_M` of the ground) ends with the motors off if the estimate is this close above the ground, m:
a drop of at most this..."""
DISPUTED_POSES = 3
"""...once this many poses in a row disagree: the first pose after a blind landing's outage disagrees with the
estimate that drifted (1.1 deg), and is fused; gyros gone wrong keep every pose off."""
CONTACT_MARGIN_M = 0.03
"""...and if no module's frame is within this of the ground, m (the estimate's height error at a touchdown, and a
frame's legs and bumpers, which its box leaves out)."""
DISPUTE_FRESH_S = 0.1
"""...if that pose was captured this recently, s: once the poses are no longer compared (a fault latched on them, a
copied id, an outage) nothing disputes the gyros, and a landing flown on them alone must keep them."""
GC_INTERVAL_S = 1.0
"""The loop collects Python's young garbage generations about this often, between periods, s."""
SUSTAINED_S = 0.1
"""A link's round trip counts as its own (the bandwidths held cut for it, the motors stopped beyond the stop bound)
once it has lasted this long, s: the modules' own command watchdogs' time (the Crazyflie app's 100 ms, PX4's
COM_OF_LOSS_T); a stall's burst of late answers is shorter."""


MOMENT_HELD = 2.0
"""A loop delay beyond the bound for a moment (shorter than :data:`SUSTAINED_S`) holds the bandwidths cut for at
most this many times the bound (a quarter of each bandwidth)."""


class Sustained:
    """The least of a value over the last ``span_s``: what it has been at least all that time (NaN until the values
    span it)."""

    def __init__(self, span_s: float) -> None:
        self.span_s = span_s
        self._values: deque[tuple[float, float]] = deque()

    def add(self, t: float, value: float) -> float:
        """Add ``value`` at ``t`` (s, increasing); the least over the last ``span_s``."""
        self._values.append((t, value))
        while len(self._values) > 1 and self._values[1][0] <= t - self.span_s:
            self._values.popleft()
        if self._values[0][0] > t - self.span_s:
            return math.nan
        return min(v for _, v in self._values)


CUT_SAID_AGAIN = 1.1
"""A bandwidth cut for a loop delay this many times the last one said is said again (the gains flown deepen with
the square of the delay: the log's figures are the ones flown, within about 20 %)."""
RATE_WINDOW_S = 1.0
"""The status line's loop rate is the number of periods run over this long, s."""


class PoseSource(Protocol):
    """Where the flight's pose measurements come from (Zenoh mocap, a simulator's sensor model)."""

    def now(self) -> float:
        """The clock the measurements are timed on, s."""
        ...

    def measurements(self) -> list[PoseMeasurement]:
        """The poses taken since the last call, in capture order."""
        ...

    def fault(self) -> str: ...

    def untrusted_since(self) -> float | None:
        """Since when (capture time, s) the measurements may be forged under the source's own id; None: never."""
        ...

    def integrity(self) -> MocapIntegrity: ...

    def keep_up(self) -> None:
        """Take what has arrived, for the next :meth:`measurements`, and keep the stream's own exchanges going (a
        keyed stream's challenges) while the flight waits on something else; safe beside :meth:`measurements` on
        another thread."""
        ...


@contextlib.contextmanager
def poses_kept_up(pose: PoseSource, period: float):
    """``pose`` kept up (:meth:`PoseSource.keep_up`) every ``period`` s on a thread of its own while the block runs
    (the modules' preflight and arming, which block for a second or more with hardware backends): a keyed stream's
    samples must echo a challenge sent at most ``fresh_s`` before they are found, and with no poll meanwhile none
    did. Every keyed flight with modules took off on a pose 1.04 s old and began a blind landing from the ground in
    its first period (hostile campaign 29)."""
    stop = threading.Event()
    failed: list[BaseException] = []

    def keep_up() -> None:
        try:
            while not stop.wait(period):
                pose.keep_up()
        except Exception as exc:  # noqa: BLE001 - raised in the caller's thread, after the block
            failed.append(exc)

    thread = threading.Thread(target=keep_up, name="poses-kept-up", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
    if failed:  # the stream went unread: not something to take off on
        raise failed[0]


@dataclass(frozen=True)
class MocapIntegrity:
    """Counters of the pose stream since the start."""

    rejected: int = 0
    """Samples of the body's source the estimate did not use (out of sequence, jumps, outside the gates)."""
    malformed: int = 0
    """Samples that did not decode."""
    foreign: int = 0
    """Samples from a publisher other than the body's source."""
    why: str = ""
    """Why the newest rejected sample was rejected."""
    missed: int = 0
    """Samples the source sent that never arrived (gaps in its sequence)."""

    def logged(self) -> dict[str, int]:
        """The counts the log keeps in every period's record and as preflight passed (``/flight/start``), so that a
        replayed window has its own."""
        return {"rejected": self.rejected, "malformed": self.malformed, "missed": self.missed}


class PhysicsPoseSource:
    """A simulated backend's motion capture (its rate, noise and latency), on its simulated clock."""

    def __init__(self, backend: SimulatedBackend) -> None:
        self._backend = backend

    def now(self) -> float:
        return self._backend.time

    def measurements(self) -> list[PoseMeasurement]:
        return self._backend.mocap_samples()

    def fault(self) -> str:
        return ""

    def untrusted_since(self) -> float | None:
        return None

    def integrity(self) -> MocapIntegrity:
        return MocapIntegrity()

    def keep_up(self) -> None:
        """Nothing to keep up: the samples are made when asked for."""


@dataclass(frozen=True)
class FailsafePolicy:
    mocap_timeout_s: float = 0.25
    """A pose older than this is stale, s."""
    on_mocap_stale: Literal["land", "stop"] = "land"
    on_mocap_fault: Literal["land", "stop"] = "land"
    """A second publisher on the body's key: its samples are never used, so the flight can land on the source's."""
    max_tilt_deg: float = 75.0
    """Angle between body z and world z beyond which the motors stop, deg."""
    geofence_lower: tuple[float, float, float] = (-3.5, -3.5, -0.2)
    geofence_upper: tuple[float, float, float] = (3.5, 3.5, 3.5)
    """Box the measured position must stay in, world frame, m."""
    max_link_latency_s: float = 0.014
    """A module whose command round trip exceeds this degrades the link (``on_link_degraded``), s. Measured at
    250 Hz with the two-module assembly (the round trip steps by one 4 ms poll period): loopback 4 ms, one
    module per emulated Crazyradio 8 ms (at most 12 ms); through a delaying relay, 2 ms of added one-way delay
    (8 ms) flies as without, 5 ms (16 ms) triples the attitude error, 10 ms (24 ms) flips it."""
    link_stop_latency_s: float = 0.050
    """Beyond this round trip the motors stop whatever the policy: too slow to land on, s. Between the two bounds
    the flight lands with its attitude bandwidth cut to the delay (:func:`~groundstation.control.geometric.
    delay_limited`): measured in SITL, landings at round trips of 19-47 ms touched down tilting at most 1-22 deg;
    the 20 ms this was before dropped the V from 0.9 m for one Crazyflie link slowed 8-9 ms each way."""
    max_link_loss: float = 0.1
    """A module whose link loses this fraction degrades it: commands not accepted (lost or reordered) on Crazyflie,
    TIMESYNC probes unanswered on MAVLink (taken each way)."""
    on_link_degraded: Literal["land", "stop"] = "land"
    max_stall_s: float = 0.1
    """A gap between control periods longer than this stops the motors: real modules have stopped theirs by then
    (the Crazyflie app after 100 ms without a command, PX4 after COM_OF_LOSS_T), s. Shorter stalls of more than
    five periods are logged as warnings."""
    on_log_failure: Literal["land", "continue"] = "land"
    """The log writer failed (a full disk): land, or fly on unlogged."""
    max_position_sigma_m: float = 1.0
    """Flying on the estimate alone (mocap stale, or its poses rejected), the motors stop once the horizontal
    position's standard deviation (per axis) passes this, m, or the height's passes ``max_height_sigma_m``: until
    then the flight lands blind, level, at ``blind_descent_mps``. Sideways it is the attitude's uncertainty that
    grows it (g sigma_theta tau^2 / 2: 0.5 m after 3.4 s blind), and stopping there drops the assembly where it is,
    while a landing that goes on moves it only by its velocity's error: at 0.5 m (the bound before) a blind
    landing from 1.6 m stopped its motors 0.12 m up, its height's std 0.16 m."""
    max_height_sigma_m: float = 0.3
    """...the height's std bound, m (at most :data:`MAX_HEIGHT_SIGMA_M`). Either bound passed once the blind
    landing's reference is below the ground ends the landing as its clock would."""
    blind_descent_mps: float = 0.5
    """A landing begun because mocap went stale descends at this speed over its last :data:`BLIND_SLOW_M` and
    through the ground, m/s (faster above: :data:`BLIND_CRUISE_MPS`); touchdowns measured 0.54-0.72 m/s from 1-2 m.
    At most :data:`MAX_BLIND_DESCENT_MPS`."""
    max_tracking_error_m: float = 0.5
    """Airborne, the measured position farther than this from the reference lands the flight: the assembly is not
    following its commands (held down, too heavy for its modules, an assembly file that is not the one flying).
    Without it such a flight runs its whole plan with the rotors at their bound. Flights that track have errors of
    a few cm (README, Fig. 9), m."""
    max_disturbance_mps2: float = 0.3 * GRAVITY
    """The acceleration the estimator finds the model missing (its disturbance) may not stay above this for
    ``DISTURBANCE_HOLD_S``, m/s^2: the assembly does not move as its thrust says. Tied down, or ``mocap.body``
    names another body (a decoy at rest: the real assembly climbed to 12 m while the flight "landed" the decoy;
    with this bound the motors stop at 0.57 m on the tests' 1 s take-off, 0.86 m at 0.5 g). Within
    ``NEAR_GROUND_M`` of the ground (by the estimate) the motors stop; higher up (a snag) it lands. A thrust map
    20 % off is 0.2 g; a 2 g shove of 0.1 s left 0.17 g."""


OPERATOR_LAND = "operator land"
"""The reason of a landing the operator asked for (a key or a signal, named in brackets: "operator land (SIGTERM)")."""


def operator_landing(reason: str) -> bool:
    """Whether ``reason`` is a landing the operator asked for (a nominal end, like the plan's own)."""
    return reason == OPERATOR_LAND or reason.startswith(OPERATOR_LAND + " (")


@dataclass
class Requests:
    """Operator requests, set from signal handlers or a key reader thread."""

    land: threading.Event = field(default_factory=threading.Event)
    stop: threading.Event = field(default_factory=threading.Event)
    source: str = ""
    """What made the last request when it was not a key: the signal's name ("SIGTERM"), named in the reason."""

    def why(self, what: str) -> str:
        """``what`` the operator asked for, with its source: "operator stop (SIGTERM)"."""
        return f"{what} ({self.source})" if self.source else what

    def abort_reason(self, when: str, armed: bool = False) -> str:
        """The reason of a flight the operator ended ``when`` ("in preflight") before anything spun (``armed``:
        the modules armed meanwhile, and were disarmed)."""
        source = f" ({self.source})" if self.source else ""
        return f"stopped by the operator {when}{source}: " + ("disarmed before take-off" if armed else "never armed")


@dataclass(frozen=True)
class QualityBounds:
    """How far a flight that flew its plan (or landed when the operator asked) may degrade and still count as a
    nominal flight (``fly`` exit 0). Beyond any bound it is *degraded*: named in its summary and log, ``fly`` exits
    3. The failsafes act on what is unsafe now (tilt, geofence, tracking error, stalls); these judge what the
    flight's own figures (:class:`~groundstation.runtime.metrics.FlightFigures`) say afterwards. Measured with the
    toy figure-8 dry run (README) on a 2-core machine running three test suites besides."""

    attitude_error_p95_deg: float = 15.0
    """95th percentile of the angle between the attitude and the controller's target over settle, track and hold
    (``orientation_error_p95_deg``), deg. Measured: 3.1-3.3 deg at roll 0 and -5 deg; 7.8-8.7 deg with
    ``--duration 1`` (the figure-8 entered and left within a second; PyBullet and simulated PX4 modules alike); the
    attitude gains cut to 1.8 Hz: 31 deg."""
    max_attitude_error_deg: float = 45.0
    """Largest such angle (``max_orientation_error_deg``), deg. Measured: 5.4-5.9 deg; 19-23 deg with
    ``--duration 1``; 38 deg at 1.8 Hz attitude gains; the tilt failsafe stops the motors at 75 deg from level."""
    max_saturation: float = 0.5
    """Largest share of the airborne periods in which one of a module's rotors sat at a bound
    (``saturation_fraction``, per module), fraction. Measured: 0.003 at roll 0 deg, 0.21-0.25 on module 1 at -5 deg;
    beyond half the time the controller has no margin left."""
    max_late_fraction: float = 0.25
    """Share of the control periods that overran their deadline (``loop.overruns / loop.periods``), fraction.
    Measured: 0 idle (README), 0.04-0.12 under the load above; beyond a quarter the loop does not hold its rate."""


def degradation(summary: FlightSummary, bounds: QualityBounds) -> tuple[str, ...]:
    """What in ``summary`` is beyond ``bounds``, one phrase each (empty: within them; a figure that was never
    measured, NaN, is not judged)."""
    out = []
    p95 = summary.orientation_error_p95_deg
    if p95 > bounds.attitude_error_p95_deg:
        out.append(f"attitude error p95 {p95:.1f} deg > {bounds.attitude_error_p95_deg:g} deg")
    att = summary.max_orientation_error_deg
    if att > bounds.max_attitude_error_deg:
        out.append(f"max attitude error {att:.1f} deg > {bounds.max_attitude_error_deg:g} deg")
    for i, share in enumerate(summary.saturation_fraction):
        if share > bounds.max_saturation:
            out.append(f"module {i} rotors at a bound {share:.0%} of the airborne time > {bounds.max_saturation:.0%}")
    loop = summary.loop
    if loop is not None and loop.periods and loop.overruns / loop.periods > bounds.max_late_fraction:
        out.append(f"{loop.overruns} of {loop.periods} control periods late ({loop.overruns / loop.periods:.0%} > "
                   f"{bounds.max_late_fraction:.0%})")
    return tuple(out)


@dataclass(frozen=True)
class Status:
    """What the operator's status line shows, once per period."""

    t: float
    """Flight time, s."""
    phase: Phase
    mocap_age: float
    """s"""
    worst_motor: float
    """Largest rotor command as a fraction of u_max."""
    battery_v: float | None
    """Lowest module battery, V (None when the backend does not report it)."""
    overruns: int
    """Late periods so far."""
    rate_hz: float | None = None
    """Loop rate measured over the last second, Hz (None during the first second)."""
    mocap: MocapIntegrity = MocapIntegrity()
    """The pose stream's counters."""
    planned_s: float | None = None
    """Flight time the plan takes, take-off to landing, s (None: not said)."""
    position_error_m: float | None = None
    """Distance of the position flown from the reference, m (None: not said)."""


@dataclass
class Recording:
    """Every period's state, for plots of a short simulated flight (``simulate --plot``); a flight flown with
    ``fly`` keeps none (its log has everything, and :attr:`Flight.metrics` the figures)."""

    t: list = field(default_factory=list)
    position: list = field(default_factory=list)
    rotation: list = field(default_factory=list)
    position_ref: list = field(default_factory=list)
    rotation_desired: list = field(default_factory=list)
    roll_target: list = field(default_factory=list)
    motors: list = field(default_factory=list)
    phase: list = field(default_factory=list)


DISTURBANCE_HOLD_S = 0.1
"""How long the disturbance must stay beyond ``max_disturbance_mps2`` (a shove's lasts a tenth of a second), s."""
LANDED_HEIGHT_M = 0.15
"""At the end of a landing the estimate must be this close above the ground it took off from to count as landed, m
(a landing aims 2-15 cm below it; the estimate of a blind one is held at it)."""
DISTURBANCE_LANDING_S = 0.6
"""A landing begun (or under way) while the disturbance is beyond its bound stops the motors once it has lasted this
long, s."""
NEAR_GROUND_M = 0.3
"""An estimate this close above the ground has nothing to land from, m."""
GROUND_CONTACT_M = 0.02
"""An estimate this close above the ground it took off from (or below it) may touch it, m: in a landing the gyros'
disagreement is not judged there (:meth:`GyroAgreement.rate`). Before and in the take-off it is: at rest nothing
kicks the body rate, and a gyro that reads wrong must be found before the assembly leaves the ground."""
TURN_RATE_MAX_GAP_S = 0.05
"""The reference's turn rate is taken over the step from the previous period when no longer than this, s."""
BLIND_LANDING_DEPTH = 0.15
"""A blind landing (on the estimate alone) aims this far below the ground, m: the estimate may be several cm off
after seconds without mocap (measured in the dry run: 5-8 cm high after 2 s), and aiming low lands it anyway."""
BLIND_CRUISE_MPS = 1.0
"""A blind landing descends at up to this speed while higher than :data:`BLIND_SLOW_M` above the ground, m/s: the
estimate's uncertainty grows with the time flown blind (its height's to the 2.5th power), so the time up high is
what a blind landing can spare. It then slows to ``failsafe.blind_descent_mps`` and touches down at that."""
BLIND_SLOW_M = 0.5
"""...m (see :data:`MAX_HEIGHT_SIGMA_M`)."""
BLIND_ACCEL_MPS2 = 1.5
"""...changing its descent speed at this, m/s^2 (the thrust 15 % above or below the weight; no tilt)..."""
BLIND_PRESS_MPS2 = 0.5
"""...and past the ground speeding up at this, m/s^2 (the thrust 5 % below the weight: ten times the disturbance
a nominal flight's estimate carries), on to twice its height's std below it: a body still above the ground by that
touches down at 0.9 m/s."""
MAX_HEIGHT_SIGMA_M = BLIND_SLOW_M / 1.5
"""The largest ``failsafe.max_height_sigma_m``, m: a blind estimate 1.5 of its std too high still slows before the
ground; beyond, it may meet the ground at :data:`BLIND_CRUISE_MPS`."""
PRESS_HEIGHT_M = 0.05
"""A landing whose estimate is this close above the ground (or below it) and whose newest pose is older than
:data:`PRESS_STALE_S` (or blind) never pushes up (:meth:`Flight._pressed`), m..."""
PRESS_STALE_S = 0.05
"""...s: five samples at 100 Hz; the touchdown may have come unseen."""
MODEL_DISTURBANCE_NOTED = 0.1
"""Going blind in the take-off, the disturbance set aside is named when it exceeds this on an axis, m/s^2."""
UNSTEADY_DISTURBANCE = 0.5
"""A disturbance that spanned more than this on an axis over the last :data:`STEADY_WINDOW_S` is no steady force
(a push, a wind, a payload) but the estimator absorbing poses it could not follow, m/s^2: a blind landing begun on
poses the estimator disowned flies on the model instead (:meth:`Flight._begin_landing`)."""
STEADY_WINDOW_S = 1.0
"""...s."""
HOLD_MARGIN = 1.2
"""Modules left after a module fault land the assembly only if they can hold this many times its weight."""

GYROLESS_ATTITUDE_SHARE = 0.5
"""Share of ``gains.attitude_hz`` flown while no gyro is usable (the landing on the poses' attitude)."""


class Flight:
    """One flight of one assembly; :meth:`run` flies it on a clock and returns what happened."""

    def __init__(self, assembly: Assembly, plan: FlightPlan, backend: Backend, pose: PoseSource, *,
                 gains: Gains | None = None, allocation: Literal["clip", "bounded"] = "clip",
                 policy: FailsafePolicy | None = None, log=None, requests: Requests | None = None,
                 before_period: Callable[[float], None] | None = None, truth=None, on_status=None,
                 activity: LoopActivity | None = None, record: bool = False,
                 to_log_time: Callable[[float], float] | None = None,
                 estimator: RigidBodyFilter | None = None) -> None:
        self.assembly, self.plan, self.backend, self.pose = assembly, plan, backend, pose
        self.gains = gains or Gains()
        self._gains_without_gyros = replace(self.gains, attitude_hz=self.gains.attitude_hz * GYROLESS_ATTITUDE_SHARE)
        """With no gyro usable, the rate is the poses' (:class:`~groundstation.estimation.filter.EstimatorSettings`
        ``lost_rate_walk``): late by a sample or two, which the attitude loop at full bandwidth turned into an 8 Hz
        swing that flipped the V."""
        self.model = ControlModel.from_assembly(assembly)
        self.alloc = allocate if allocation == "clip" else allocate_bounded
        self.estimator = estimator or RigidBodyFilter(EstimatorSettings(), self.model.mass)
        """The flight's only source of state (``estimator``: one that has already followed the poses, in preflight;
        by default a new one with the default settings)."""
        self.gyros = GyroAgreement()
        """The modules' gyros judged against each other (a failed IMU lands the flight)."""
        self.torque = TorqueAgreement(self.model.inertia)
        """The gyros against the torque commanded: the referee when they and the poses disagree."""
        self.policy = policy or FailsafePolicy()
        self.log = log
        self.requests = requests or Requests()
        self.before_period = before_period  # called with t first thing every period (advance a simulator)
        self.activity = activity  # marks each period busy for the log writer and other background threads
        self.truth = truth  # optional callable returning the true state (simulation), recorded for metrics
        self.on_status = on_status
        self._rate_window = (0.0, 0)
        """(loop time s, periods run) at the start of the current rate window."""
        self._rate_hz: float | None = None
        self._said_cut_delay_s = 0.0
        """The delay of the last cut the log was told of, s."""
        self._sustained_delay = Sustained(SUSTAINED_S)
        """The loop delay (the links' mean round trip and a period) over the last :data:`SUSTAINED_S`."""
        self._sustained_round_trip = Sustained(SUSTAINED_S)
        """The slowest module's round trip over the last :data:`SUSTAINED_S`."""
        self._cut_delay_s: float | None = None
        """The longest loop delay beyond the bound that the gains have been cut for (:func:`delay_limited`): one
        sustained for :data:`SUSTAINED_S`, or a moment's up to :data:`MOMENT_HELD` times the bound, s; None while no
        link was slow. Held for the rest of the flight: a round trip
        that wobbles back under the bound, or goes unmeasured (NaN) while a relay's answers change, is not a faster
        link. Recut at each period from the newest round trip, a relay answering the probes and holding the rest
        10 ms each way (measured 16-18 ms against its 20) swung the landing 25 deg at 4 Hz (38 deg on a loaded
        machine); held at the worst, 19-23 deg. A stall's burst (an 80 ms stall read 55 ms for a few periods) is
        not sustained: held whole, it would have cut the rest of the flight to a tenth (:data:`MOMENT_HELD`)."""
        self.phase = Phase.PREFLIGHT
        self.reason = ""
        self.metrics = FlightMetrics(assembly.n)
        """Running figures of the flight (bounded memory)."""
        self.recording = Recording() if record else None
        self.events: list[tuple[float, str, str]] = []
        """(flight time s, level, text) of every transition and failsafe."""
        self.periods = 0
        """Control periods flown (the ones that computed a command)."""
        self._landing: tuple[float, Landing, bool] | None = None
        """(start s, reference, blind) of a landing under way."""
        self._t_prev: float | None = None
        self._stall_warn = 0.02
        """A gap between periods beyond this is a stall worth a warning, s (five periods)."""
        self.stalls = 0
        self._log_failure_seen = False
        self._last_u = np.zeros(4 * assembly.n)
        offset = time.time() - time.monotonic()
        self._to_log = to_log_time or (lambda mono: mono + offset)
        """Monotonic time -> log time (s since the epoch): one clock for every record of the flight's log."""
        self._lo = np.array(self.policy.geofence_lower)
        self._hi = np.array(self.policy.geofence_upper)
        self._cos_tilt = np.cos(np.radians(self.policy.max_tilt_deg))
        self._stats: LoopStats | None = None
        self._failed_modules: set[int] = set()
        """Modules whose firmware stopped flying them (their rotors are out of the allocation)."""
        self._disturbed_since: float | None = None
        self._disturbances: deque[tuple[float, tuple[float, float, float]]] = deque()
        """(estimate time s, disturbance m/s^2) of the periods of the last :data:`STEADY_WINDOW_S`."""
        """Flight time since which the disturbance has been beyond ``max_disturbance_mps2``, s."""
        self._reference_attitude: tuple[float, object, np.ndarray] | None = None
        """(flight time s, its reference, the attitude target of the reference alone) of the previous period."""
        self._mocap_fault_named = ""
        """The kind of mocap fault last seen (its text without the counts)."""
        self._link_named: set[str] = set()
        """The kinds of degraded link (their text without figures) already said."""
        self._gyro_fault_named = False
        self._gyros_lost_at: float | None = None
        """Since when no gyro has been usable (as :attr:`GyroAgreement.lost_since` said last period), s."""
        self._height = 0.0
        """The estimate's height above the ground it took off from, last period, m (on it before the first)."""
        self._poses_untrusted = False
        """No pose is fused any more: the stream carried two sequences under one source id (a copied id)."""
        self._forgotten = 0
        """Poses taken back when the stream turned untrusted, not yet named in an event."""
        self._rejected_before_arming = 0
        """Samples rejected before the first period (preflight's): a stale stream's reason names only later ones."""
        self._attitude_seen_t = -math.inf
        """Capture time of the newest pose whose attitude the estimator compared, s."""
        self._disputes = 0
        """Poses in a row, to the newest compared, whose attitude was more than :data:`GYROS_DISPUTED_RAD` off."""
        self._disputed_on_the_ground = 0.0
        """How far a fresh pose's attitude was from the gyros' this period, rad, with a module's frame near the
        ground (where the torque cannot referee them); 0 otherwise."""

    # -- transitions ----------------------------------------------------------------------------------------------
    def _log_time(self, t: float) -> float:
        """Log time of flight time ``t`` (loop time since the first period)."""
        st = self._stats
        return self._to_log(st.t0 + t) if st is not None and st.t0 is not None else self._to_log(time.monotonic())

    def _event(self, t: float, level: str, text: str) -> None:
        self.events.append((t, level, text))
        if self.log is not None:
            self.log.event(level, text, self._log_time(t))

    def _set_phase(self, t: float, phase: Phase, why: str = "") -> None:
        if phase != self.phase:
            self._event(t, "warning" if phase in (Phase.EMERGENCY, Phase.ABORTED) else "info",
                        f"{self.phase} -> {phase}" + (f": {why}" if why else ""))
            self.phase = phase

    def _estimate(self, telemetry: Telemetry) -> tuple[RigidState | None, float]:
        """The estimator brought to now with the gyros and every new measurement: the state (None before the first
        measurement) and the age of the newest measurement fused, s."""
        est = self.estimator
        now = self.pose.now()
        gyro = telemetry.gyro if telemetry.gyro.size == 3 else None
        age = telemetry.gyro_age_s
        if gyro is not None and len(telemetry.module_gyros):
            gyro, age = self.gyros.rate(now, telemetry.module_gyros, gyro, lambda: est.pose_rate(now),
                                        telemetry.module_gyro_ages_s, age, est.settings.gyro_stale_s,
                                        touching=self.phase == Phase.LANDING and self._height < GROUND_CONTACT_M)
            lost = self.gyros.lost_since
            if lost is not None and self._gyros_lost_at is None:  # found now: once (est.gyros_lost)
                est.gyros_lost(lost)
            self._gyros_lost_at = lost
        est.predict(now, gyro, age)
        self.torque.add(now, gyro)
        poses = self.pose.measurements()  # drained even when untrusted: they must not pile up
        since = self.pose.untrusted_since()
        if since is not None and not self._poses_untrusted:
            # Two sequences under one source id: without a key nothing tells the forged samples from the genuine
            # ones, so none is fused from then on, and what those since the first conflict taught the estimate is
            # taken back (landing on "the stream's own rate", a forger dragging the pose down held the estimate on
            # the ground 0.5 m up: "landed", motors off; blind, but with what it had learnt, 0.6 m up).
            self._poses_untrusted = True
            self._forgotten = est.forget_since(since)
        for m in () if self._poses_untrusted else poses:
            est.correct(m)
        self._referee_gyros(now)
        state = est.state()
        if state is not None:
            self._height = float(state.position[2]) - float(self.plan.ground[2])
        self._disturbances.append((now, est.disturbance_vector))
        while self._disturbances[0][0] < now - STEADY_WINDOW_S:
            self._disturbances.popleft()
        return state, est.age(now)

    def _referee_gyros(self, now: float) -> None:
        """Count the poses in a row whose attitude is off the gyros' and, while they disagree clear of the ground, ask
        the commanded torque which is wrong (:class:`TorqueAgreement`); near the ground the landing decides
        (:data:`DISPUTED_LANDING_M`)."""
        est = self.estimator
        seen, disagreement = est.attitude_seen
        if seen > self._attitude_seen_t:  # a pose compared since the last period: one more in a run, or none
            self._attitude_seen_t = seen
            self._disputes = self._disputes + 1 if disagreement > GYROS_DISPUTED_RAD else 0
        disputed = self._disputes > 0 and now - seen <= DISPUTE_FRESH_S and self.gyros.lost_since is None
        clear = disputed and self._clear_of_the_ground(est.state())
        self._disputed_on_the_ground = disagreement if disputed and not clear else 0.0
        if clear and (why := self.torque.against()):
            # The poses turn one way, the gyros another: a frozen or forged stream, or every gyro wrong alike (a
            # sign flipped: the attitude loop then feeds the turn, and the V tipped past 75 deg 0.2 s after it
            # began, the poses rejected as "off the gyros' prediction"). The torque commanded tells which.
            # Condemned from before the poses were first rejected for it: that fault was the gyros' (est.gyros_lost).
            conflict = est.attitude_conflict_since
            self.gyros.condemn(min(conflict or math.inf, now - self.torque.settings.window_s),
                               f"every module's gyro turns against the commanded torque ({why}): a sign or axes "
                               f"wrong; no body rate, the attitude from the poses alone")

    def _clear_of_the_ground(self, state: RigidState | None) -> bool:
        """Every module corner more than ``CONTACT_MARGIN_M`` above the ground the flight took off from, by the
        estimate: the ground's contact torques, which no command explains, and the kick the gyros read there, which
        100 Hz poses miss, are not the gyros' fault (at touchdowns the torque referee condemned good gyros: simulated
        Crazyflie modules, slopes -0.31 and -0.43; a V shoved in its take-off, -3.5, rolled over on the ground)."""
        if state is None:
            return False
        height = float(state.position[2]) - float(self.plan.ground[2])
        return self.assembly.clearance(height, state.rotation) > CONTACT_MARGIN_M

    def integrity(self) -> MocapIntegrity:
        """The pose stream's counters, the estimator's rejections included."""
        src, est = self.pose.integrity(), self.estimator
        return MocapIntegrity(src.rejected + est.rejected, src.malformed, src.foreign,
                              est.last_rejection if est.rejected and est.last_rejection else src.why, src.missed)

    def _emergency(self, t: float, why: str) -> None:
        self.backend.emergency_stop()
        self.estimator.command(None)
        self.torque.command(None)
        self._last_u = np.zeros_like(self._last_u)
        self.reason = why
        self._set_phase(t, Phase.EMERGENCY, why)
        self._log_motors_off(t)  # in the final phase: a log that ends here ends in it

    def _begin_landing(self, t: float, state: RigidState, why: str, blind: bool = False,
                       disowned: bool = False) -> None:
        """Land in the plan's landing time, or, ``blind`` (on the estimate alone; ``disowned``: because the
        estimator rejected every pose), as :class:`Descent` has it; the
        landing reference goes on from the current one (position, velocity, acceleration: the controller's output
        does not jump; a blind landing's vertical acceleration steps, which changes the collective thrust alone)
        unless the assembly is farther from it than ``max_tracking_error_m``, then from the ``state`` (where and
        how it moves). A landing already under way goes on from its own reference (a blind one stays blind)."""
        was_blind = False
        if self._landing is not None:
            t_land, landing, was_blind = self._landing
            ref, blind = landing(t - t_land), blind or was_blind
        else:
            ref = self.plan(t)
        if self.phase == Phase.LANDING:  # ours or the plan's: no change of phase to log it
            self._event(t, "warning", f"{why}: the landing goes on" + (" blind" if blind else ""))
        if np.linalg.norm(state.position - ref.position) > self.policy.max_tracking_error_m:
            ref = Setpoint(state.position, state.velocity, np.zeros(3), ref.rotation)
        start = tuple(tuple(map(float, x)) for x in (ref.position, ref.velocity, ref.acceleration))
        ground = float(self.plan.ground[2])
        if blind and not was_blind:
            span = np.ptp([d for _, d in self._disturbances], axis=0) if self._disturbances else np.zeros(3)
            if self.phase == Phase.TAKEOFF:
                self._fly_on_the_model(t, "in the take-off")
            elif disowned and span.max() > UNSTEADY_DISTURBANCE:
                # Learnt from poses the estimator could not follow (mocap 60 ms late from its first sample, no key):
                # flown on, -0.61 m/s^2 had the estimate descend while the body climbed from 1.1 to 2 m, and the
                # motors stopped there, "landed blind" (hostile campaign 28).
                self._fly_on_the_model(t, f"the poses disowned, the disturbance unsteady (it spanned "
                                          f"{span.max():.1f} m/s^2 in the last {STEADY_WINDOW_S:g} s)")
        if blind:
            landing = Landing.blind(*start, Descent(start[0][2], start[1][2], ground, BLIND_CRUISE_MPS,
                                                    self.policy.blind_descent_mps, BLIND_SLOW_M,
                                                    BLIND_LANDING_DEPTH, BLIND_ACCEL_MPS2, BLIND_PRESS_MPS2,
                                                    start[2][2]))
        else:
            z = ground - LANDING_DEPTH
            height, sinking = float(ref.position[2]) - z, -float(ref.velocity[2])
            duration = max(self.plan.landing_s, height / MAX_LANDING_MPS)  # never faster than the plan's landing
            if sinking > 0.0 and height > 0.0:
                # Descending fast near the ground: the quintic to rest would pass below it (and come back up) if it
                # carried that speed over more than 2.5 x the height.
                duration = min(duration, max(0.3, 2.5 * height / sinking))
            landing = Landing(*start, z, duration)
        self._landing = (t, landing, blind)
        self.reason = self.reason or why
        self._set_phase(t, Phase.LANDING, why)

    def _blind_landing_done(self, t: float) -> bool:
        """A blind landing ends once its reference is twice its height's std (at most ``max_height_sigma_m``'s)
        below the ground's depth: it touches down on the way there at ``blind_descent_mps``, wherever the ground
        really is within that."""
        sigma = self.estimator.estimate().height_sigma
        sigma = min(sigma, self.policy.max_height_sigma_m) if math.isfinite(sigma) else self.policy.max_height_sigma_m
        end = float(self.plan.ground[2]) - BLIND_LANDING_DEPTH - 2.0 * sigma
        return float(self._landing_reference(t).position[2]) <= end

    def _fly_on_the_model(self, t: float, when: str) -> None:
        """Going blind in the take-off (or on disowned poses, the disturbance unsteady: :data:`UNSTEADY_DISTURBANCE`;
        ``when`` says which): the estimator flies on from now on the model's own acceleration (no
        disturbance, :meth:`RigidBodyFilter.set_disturbance`): a take-off's disturbance is mostly the rotors' lag
        behind the command (-0.5..+0.3 m/s^2 in a 1 s take-off before the lag was modelled; -0.19 since), and
        flown on blind from 0.3 s into one, -0.48 m/s^2 had the estimate descend at 0.5 m/s while the body climbed
        to 2.9 m. Elsewhere the disturbance is kept: a push acting when the poses stop goes on acting (taken back to
        the last pose fused, a push's disturbance made the estimate jump 26 cm, and the V climbed to 8 m)."""
        d = self.estimator.disturbance_vector
        if max(abs(x) for x in d) > MODEL_DISTURBANCE_NOTED:
            self._event(t, "info", f"flying blind on the model, not on the disturbance learnt "
                                   f"({np.round(d, 2).tolist()} m/s^2): {when}")
        self.estimator.set_disturbance((0.0, 0.0, 0.0))

    # -- one period -----------------------------------------------------------------------------------------------
    def _stalled(self, t: float) -> bool:
        """Name a stall of the loop (the gap since the previous period); True if it is too long to fly on."""
        gap = t - self._t_prev if self._t_prev is not None else 0.0
        self._t_prev = t
        if gap <= self._stall_warn:
            return False
        self.stalls += 1
        sim = " (the simulator ran on open-loop over it)" if self.truth is not None else ""
        if gap > self.policy.max_stall_s:
            self._emergency(t, f"loop stalled {gap * 1e3:.0f} ms > {self.policy.max_stall_s * 1e3:g} ms: the "
                               f"modules have stopped their motors by now{sim}")
            return True
        self._event(t, "warning", f"loop stalled {gap * 1e3:.0f} ms{sim}")
        return False

    def step(self, k: int, t: float) -> bool:
        if self.phase.final:
            return False
        if self._stalled(t):
            return False
        if self.before_period is not None:
            self.before_period(t)
        if k == 0:
            self._set_phase(t, Phase.TAKEOFF, "armed")
            self._rejected_before_arming = self.integrity().rejected
        if self.requests.stop.is_set():
            self._emergency(t, self.requests.why("operator stop"))
            return False
        telemetry = self.backend.telemetry()
        est = self.estimator
        state, age = self._estimate(telemetry)
        if any(telemetry.module_faults):
            if not self._on_module_fault(t, state, telemetry):
                return False
            telemetry = self.backend.telemetry()  # the faulty modules, isolated, no longer count for the link
        if not telemetry.link_ok:
            named = "; ".join(f"module {i} {why}" for i, why in enumerate(telemetry.module_faults) if why)
            self._emergency(t, "backend link lost" + (f": {named}" if named else ""))
            return False
        degraded, severe = self._link_degraded(t, telemetry)
        if degraded:
            if severe or self.policy.on_link_degraded == "stop":
                self._emergency(t, degraded)
                return False
            # In a landing (the plan's or ours), each kind named once and the landing goes on as it is: a link
            # re-routed there was never said, and re-planned at each new note, a relay swapping back and forth
            # lengthened it each time.
            kind = re.sub(r"\d+(\.\d+)?", "#", degraded)  # its figures change every period
            if state is not None and self.phase.airborne:
                self._begin_landing(t, state, degraded)
                self._link_named.add(kind)
            elif self.phase == Phase.LANDING and kind not in self._link_named:
                self._event(t, "warning", f"{degraded}: the landing goes on")
                self.reason = self.reason or degraded
                self._link_named.add(kind)
        fault = self.pose.fault() or est.fault()
        if fault:
            why = f"mocap fault: {fault}"
            if self.policy.on_mocap_fault == "stop" or state is None:
                self._emergency(t, why)
                return False
            kind = fault.split(" (")[0]  # its counts in brackets change every period
            if self._forgotten:
                self._event(t, "warning", f"{self._forgotten} poses fused since the first sequence conflict taken "
                                          f"back; no pose is fused from now on")
                self._forgotten = 0
            if self.phase.airborne or (self.phase == Phase.LANDING and kind != self._mocap_fault_named):
                # The estimator's fault: every pose rejected, so landing on the estimate. A landing under way (the
                # plan's, or on stale poses) goes on, blind if need be, named once per kind of fault.
                self._begin_landing(t, state, why, blind=bool(est.fault()) or self._poses_untrusted,
                                    disowned=bool(est.fault()))
            self._mocap_fault_named = kind
        if self._disputed_on_the_ground and self._disputes >= DISPUTED_POSES and self.phase == Phase.LANDING and \
                self._height < DISPUTED_LANDING_M:
            # The torque cannot referee where the ground may push (contact torques), and flown on gyros gone wrong
            # there (a sign flipped 0.1 s before touchdown) the V rolled over on the ground, motors running, to
            # 75-78 deg. Here the landing is as good as done: motors off.
            self._event(t, "warning", f"the poses and the gyros disagree by "
                                      f"{math.degrees(self._disputed_on_the_ground):.1f} deg {self._height * 100:.0f} "
                                      f"cm above the ground: the landing ends here, motors off")
            self._finish(t)
            return False
        if self.gyros.fault and not self._gyro_fault_named and state is not None and \
                (self.phase.airborne or self.phase == Phase.LANDING):
            self._gyro_fault_named = True  # a landing under way (the plan's too) goes on, the fault named once
            self._begin_landing(t, state, f"gyro fault: {self.gyros.fault}")
        if state is not None and not (np.all(np.isfinite(state.position)) and np.all(np.isfinite(state.rotation))):
            self._emergency(t, "non-finite state")
            return False
        if state is None or age > self.policy.mocap_timeout_s:
            why = f"mocap stale ({age * 1e3:.0f} ms)"
            integrity = self.integrity()
            if (rejected := integrity.rejected - self._rejected_before_arming) > 0:
                # In flight only: a preflight's rejection quoted here read as the cause ("sequence jumps 83 ahead"
                # for a stream that had simply stopped: campaign 25).
                why += f"; {rejected} samples rejected in flight, last: {integrity.why}"
            if self.policy.on_mocap_stale == "stop" or state is None:
                self._emergency(t, why)
                return False
            if self._landing is None or not self._landing[2]:  # not yet landing blind (the plan's landing too)
                self._begin_landing(t, state, why + ": landing blind on the estimate", blind=True)
            e = est.estimate()
            below = self._landing_reference(t).position[2] < float(self.plan.ground[2])
            for sigma, bound, which in ((e.height_sigma, self.policy.max_height_sigma_m, "height"),
                                        (e.position_sigma, self.policy.max_position_sigma_m, "position"),
                                        (e.attitude_sigma, MAX_UNSEEN_ATTITUDE_SIGMA, "attitude")):
                if sigma <= bound or (which == "height" and below and math.isfinite(sigma)):  # on to the end
                    continue
                if which == "attitude":
                    why = (f"{why}, nothing observes the attitude: its uncertainty {math.degrees(sigma):.0f} deg > "
                           f"{math.degrees(bound):.0f} deg")
                else:
                    why = f"{why}: the {which} estimate's uncertainty {sigma:.2f} m > {bound:g} m"
                if below:
                    # The descent is done but for its margin below the ground: the end the clock would give.
                    self._event(t, "warning", f"{why}, the landing's reference below the ground: it ends here")
                    self._landed_or_not(t, state)
                else:
                    self._emergency(t, why)
                return False
        # A blind landing's estimate goes on below the ground (its descent does: the ground is where the body stops)
        low = state.position < self._lo
        if self._landing is not None and self._landing[2]:
            low[2] = False
        if np.any(low) or np.any(state.position > self._hi):
            self._emergency(t, f"left the geofence at {np.round(state.position, 2).tolist()}")
            return False
        if state.rotation[2, 2] < self._cos_tilt:
            self._emergency(t, f"tilt beyond {self.policy.max_tilt_deg:g} deg")
            return False
        unmoved = self._unmoved_by_thrust(t)
        if unmoved:
            # Near the ground there is nothing to land from. Higher up, a landing; if the landing does not end it
            # (its poses still disown the thrust: another body is measured), the motors stop: landing by the
            # clock on poses of another body "landed" a decoy while the assembly climbed to 10 m.
            if state.position[2] - float(self.plan.ground[2]) < NEAR_GROUND_M or (
                    self.phase == Phase.LANDING and t - self._disturbed_since > DISTURBANCE_LANDING_S):
                self._emergency(t, unmoved)
                return False
            if self.phase.airborne:
                self._begin_landing(t, state, unmoved)
        if self.requests.land.is_set() and self.phase.airborne:
            self._begin_landing(t, state, self.requests.why(OPERATOR_LAND))
        if self.log is not None and self.log.error is not None and not self._log_failure_seen:
            self._log_failure_seen = True
            why = f"log writer failed: {self.log.error}"
            self.events.append((t, "error", why))
            if self.policy.on_log_failure == "land" and self.phase.airborne:
                self._begin_landing(t, state, why)
        if self._landing is not None:
            t_land, landing, blind = self._landing
            if t - t_land >= landing.duration and (not blind or self._blind_landing_done(t)):
                self._landed_or_not(t, state)
                return False
            reference = self._landing_reference
            sp = reference(t)
        else:
            phase = self.plan.phase_at(t)
            if phase == Phase.DONE:
                self._landed_or_not(t, state)
                return False
            self._set_phase(t, phase)
            reference = self.plan
            sp = reference(t)
            error = float(np.linalg.norm(state.position - sp.position))
            if error > self.policy.max_tracking_error_m:
                self._begin_landing(t, state, f"not following the reference: {error:.2f} m from it > "
                                                       f"{self.policy.max_tracking_error_m:g} m")
        sp = replace(sp, omega=self._turn_rate(t, sp, "plan" if reference is self.plan else self._landing[0]))
        gains = self.gains if self.gyros.lost_since is None else self._gains_without_gyros
        lat = telemetry.link_latency_s
        period = self._stats.period
        bound = self.policy.max_link_latency_s + period
        # The modules' mean round trip: every module's rotors act on each axis, so one late module of two delays
        # half the loop (one Crazyflie link of two slowed 20 ms each way: cut on its own round trip the V tilted
        # 16 deg in a 3 s landing, on the mean 1 deg).
        delay = float(np.nanmean(lat)) + period if lat.size and np.any(np.isfinite(lat)) else math.nan
        if math.isfinite(delay):
            # Held: the delay sustained for SUSTAINED_S, or a moment's up to twice the bound (a load's blip read
            # 18 ms and began a landing uncut, on which the link's 25 % loss then tilted the V 45 deg; a stall's
            # burst of 55 ms held whole cut the gains to a tenth).
            held = max(self._sustained_delay.add(t, delay), min(delay, MOMENT_HELD * bound))
            if held > bound and (self._cut_delay_s is None or held > self._cut_delay_s):
                if self._cut_delay_s is None or held > self._said_cut_delay_s * CUT_SAID_AGAIN:
                    cut = delay_limited(gains, held, bound)
                    self._event(t, "warning", f"attitude and position bandwidths cut to {cut.attitude_hz:.2f} and "
                                              f"{cut.position_hz:.2f} Hz for the links' mean round trip "
                                              f"{(held - period) * 1e3:.0f} ms")
                    self._said_cut_delay_s = held
                self._cut_delay_s = held
        # Cut for the longest of the delay held (:attr:`_cut_delay_s`) and this period's: a round trip that wobbles
        # back under the bound or goes unmeasured keeps the cut, a stall's burst cuts only while it lasts.
        flown = max(self._cut_delay_s or 0.0, delay if math.isfinite(delay) else 0.0)
        gains = delay_limited(gains, flown, bound)
        out = control(state, sp, self.model, gains)
        if self.phase == Phase.LANDING and self._height < PRESS_HEIGHT_M and \
                (self._landing is not None and self._landing[2] or age > PRESS_STALE_S):
            out = self._pressed(out, state)
        if est.attitude_unobserved:
            # Neither gyros nor poses: an attitude error the controller sees cannot shrink (the estimate is held),
            # and its torque, held on, turned the V over in 0.4 s. No torque: the body keeps the turn it has.
            out = replace(out, wrench=np.concatenate([out.wrench[:3], np.zeros(3)]))
        u = self.alloc(out.wrench, self.model)
        if not np.all(np.isfinite(u)):
            self._emergency(t, "non-finite motor command")
            return False
        self.backend.send(u)
        wrench = self.model.allocation @ u
        est.command(wrench[:3])
        self.torque.command(wrench[3:])
        self._last_u = u
        self._record(t, state, sp, out, u, age, telemetry)
        return True

    def _pressed(self, out, state: RigidState):
        """``out`` with its collective thrust at most the weight less ``BLIND_PRESS_MPS2``'s worth: a landing whose
        estimate is at the ground without fresh poses never pushes up. Landed unseen (the poses lost in the last 0.3
        s of a 1 s landing), the estimate went on down and the controller braked it: the thrust lifted the landed V
        and the motors stopped 0.24-0.29 m up, "landed blind"."""
        force = state.rotation @ out.wrench[:3]
        cap = self.model.mass * (GRAVITY - BLIND_PRESS_MPS2)
        if force[2] <= cap:
            return out
        return replace(out, wrench=np.concatenate([out.wrench[:3] * (cap / force[2]), out.wrench[3:]]))

    def _unmoved_by_thrust(self, t: float) -> str:
        """Why the assembly does not move as its thrust says ("" while it does): the estimator's disturbance beyond
        ``max_disturbance_mps2`` for ``DISTURBANCE_HOLD_S`` with the motors running."""
        d = self.estimator.disturbance
        if not (self.phase.airborne or self.phase == Phase.LANDING) or d <= self.policy.max_disturbance_mps2:
            self._disturbed_since = None
            return ""
        self._disturbed_since = t if self._disturbed_since is None else self._disturbed_since
        if t - self._disturbed_since < DISTURBANCE_HOLD_S:
            return ""
        return (f"the assembly does not move as its thrust says ({d:.1f} m/s^2 unexplained for "
                f"{(t - self._disturbed_since) * 1e3:.0f} ms): tied down, pushed (a cable, a strong wind), or "
                f"mocap.body names another body")

    def _turn_rate(self, t: float, sp: Setpoint, source) -> np.ndarray:
        """The body rate at which the reference's attitude target turns (:func:`reference_attitude`), rad/s: from
        the previous period's to this one's; zero in the first period of a reference (``source``: the plan, or the
        landing's start) or after a gap of more than ``TURN_RATE_MAX_GAP_S``."""
        r = reference_attitude(sp, self.model)
        before, self._reference_attitude = self._reference_attitude, (t, source, r)
        if before is None or before[1] != source or not 0.0 < t - before[0] <= TURN_RATE_MAX_GAP_S:
            return np.zeros(3)
        return matrix_to_rotvec(before[2].T @ r) / (t - before[0])

    def _landing_reference(self, t: float) -> Setpoint:
        """The landing's reference at ``t``: level, the plan's yaw."""
        t_land, landing, _ = self._landing
        sp = landing(t - t_land)
        return Setpoint(sp.position, sp.velocity, sp.acceleration, _level(self.plan(t).rotation))

    def _on_module_fault(self, t: float, state: RigidState | None, telemetry) -> bool:
        """React to modules whose firmware stopped flying them (or that went silent): land on the others if their
        rotors alone hold the assembly's weight with a margin at its attitude and the backend can stop the faulty
        ones, else stop. False when the motors were stopped."""
        new = {i: why for i, why in enumerate(telemetry.module_faults) if why and i not in self._failed_modules}
        if not new:
            return True
        self._failed_modules.update(new)
        names = "; ".join(f"module {i} {why}" for i, why in sorted(new.items()))
        rest = self.model.without_modules(sorted(self._failed_modules))
        in_air = self.phase.airborne or self.phase == Phase.LANDING
        holds = state is not None and bool(np.all(np.isfinite(state.rotation))) and rest.can_hold(np.concatenate([
            state.rotation.T @ np.array([0.0, 0.0, HOLD_MARGIN * self.model.mass * GRAVITY]), np.zeros(3)]))
        if not (in_air and holds and self.backend.isolate(sorted(new))):
            self._emergency(t, f"{names}: the other modules cannot hold the assembly")
            return False
        self.model = rest
        self._begin_landing(t, state, f"{names}: landing on the other modules")  # from here, on the rest
        return True

    def _link_degraded(self, t: float, telemetry) -> tuple[str, bool]:
        """Why the modules' links are too slow or lossy to fly on ("" if fine or not measured), and whether they
        are too slow even to land on: beyond ``link_stop_latency_s`` for :data:`SUSTAINED_S`, the modules' own
        command watchdogs' time (an 80 ms stall of a PX4 link read 55 ms for a few periods, and stopped the motors
        0.93-0.95 m up, 3 of 4: hostile campaign 34; it lands now)."""
        p = self.policy
        lat, loss = telemetry.link_latency_s, telemetry.link_loss
        slowest = float(np.nanmax(lat, initial=0.0)) if lat.size and np.any(np.isfinite(lat)) else math.nan
        slow = slowest > p.max_link_latency_s
        i = int(np.nanargmax(lat)) if slow else 0
        held = self._sustained_round_trip.add(t, slowest) if math.isfinite(slowest) else math.nan
        if held > p.link_stop_latency_s:
            # Checked before a re-route's note, which would otherwise stand for the link for the rest of the flight:
            # a link too slow to land on stops the motors whatever else it did.
            return f"link degraded: module {i} round trip {lat[i] * 1e3:.0f} ms > " \
                   f"{p.link_stop_latency_s * 1e3:g} ms for {SUSTAINED_S * 1e3:.0f} ms", True
        if telemetry.rerouted:
            return f"link degraded: {telemetry.rerouted}", False
        if slow:
            return f"link degraded: module {i} round trip {lat[i] * 1e3:.0f} ms > {p.max_link_latency_s * 1e3:g} ms", \
                False
        if loss.size and np.nanmax(loss, initial=0.0) > p.max_link_loss:
            i = int(np.nanargmax(loss))
            return f"link degraded: module {i} loses {loss[i]:.0%} of its packets > {p.max_link_loss:.0%}", False
        return "", False

    def _log_motors_off(self, t: float) -> None:
        if self.log is not None:
            # The command is zero (the stop); "applied" is what the backend reports now, which for real modules can
            # lag by one reply (their state packets are already on the way).
            applied = self.backend.telemetry().motors.reshape(-1, 4) / self.model.u_max
            modules = [{"command_frac_umax": np.zeros(4), "applied_frac_umax": a} for a in applied]
            self.log.record("/control", {"t_s": t, "phase": self.phase, "modules": modules, "motors_off": True},
                            self._log_time(t))

    def _landed_or_not(self, t: float, state: RigidState) -> None:
        """The landing's time is up: landed (:meth:`_finish`) if the estimate is on the ground, else the motors stop
        and the log says where it was (a landing on the poses of another body ended 1 m up by the estimate, and
        was reported as landed)."""
        height = float(state.position[2] - self.plan.ground[2])
        if not height <= LANDED_HEIGHT_M:
            self._emergency(t, f"the landing's time ran out {height:.2f} m above the ground (by the estimate): "
                               f"motors off")
        elif self._landing is not None and self._landing[2]:
            if self.estimator.age(self.pose.now()) <= self.policy.mocap_timeout_s:
                # Poses came back during the blind descent: the touchdown was seen ("std 0.00 m" said otherwise).
                self._finish(t, "landed (a blind landing, the poses back by the touchdown)")
            else:
                # On the estimate alone: where the ground is is known to its height's std, not to a pose's mm.
                self._finish(t, f"landed blind (the height's std {self.estimator.estimate().height_sigma:.2f} m)")
        else:
            self._finish(t)

    def _finish(self, t: float, how: str = "landed") -> None:
        self.backend.disarm()  # landed: motors off, disarmed (an emergency stop would need a reboot)
        self.estimator.command(None)
        self.torque.command(None)
        self._last_u = np.zeros_like(self._last_u)
        self._set_phase(t, Phase.DONE, how)
        self._log_motors_off(t)  # in the final phase: a log that ends here ends in it

    def _record(self, t, state, sp, out, u, age, telemetry) -> None:
        truth = self.truth() if self.truth is not None else None
        flown = truth or state
        roll_target, _, yaw_target = roll_pitch_yaw(sp.rotation)
        fractions = u.reshape(-1, 4) / self.model.u_max
        worst = float(fractions.max())
        self.periods += 1
        self.metrics.add(t, self.phase, flown.position, sp.position, flown.rotation, out.rotation_desired,
                         roll_target, yaw_target, fractions, age)
        r = self.recording
        if r is not None:
            r.t.append(t)
            r.position.append(flown.position)
            r.rotation.append(flown.rotation)
            r.position_ref.append(sp.position)
            r.rotation_desired.append(out.rotation_desired)
            r.roll_target.append(roll_target)
            r.motors.append(u)
            r.phase.append(self.phase)
        # The period's start error and the previous period's compute time (this one's is not over): what the log
        # keeps, so that a replay's timing figures are the flight's.
        st = self._stats
        timing = {"start_error_s": st.start_error[-1], "compute_s": st.compute[-1] if st.compute else 0.0,
                  "overruns": st.overruns} if st is not None and st.start_error else {}
        if timing:
            self.metrics.add_timing(timing["start_error_s"], timing["compute_s"])
        if self.log is not None:
            tw = self._log_time(t)
            self.log.pose("/state/pose", state.position, state.rotation, tw)
            # One record per period (fewer, larger messages keep the feeder's share of the GIL small); the arrays
            # are fresh each period, so no copies are needed, and the writer process converts them (rotation
            # matrices become a quaternion and roll/pitch/yaw there, off the control thread).
            record = {"t_s": t, "phase": self.phase,
                      "state": {"position_m": state.position, "velocity_mps": state.velocity,
                                "rotation": state.rotation, "omega_radps": state.omega},
                      "setpoint": {"position_m": sp.position, "velocity_mps": sp.velocity,
                                   "acceleration_mps2": sp.acceleration, "rotation": sp.rotation,
                                   "omega_radps": sp.omega},
                      "position_error_m": flown.position - sp.position,
                      "attitude_target": {"rotation": out.rotation_desired},
                      "roll_target_deg": np.degrees(roll_target), "yaw_target_deg": np.degrees(yaw_target),
                      "wrench": {"force_n": out.wrench[:3], "torque_nm": out.wrench[3:]},
                      "modules": [{"command_frac_umax": f} for f in fractions],
                      "command_max_frac_umax": worst, "command_min_frac_umax": fractions.min(),
                      "mocap_age_s": age, "loop": timing, "mocap": self.pose.integrity().logged()}
            est = self.estimator
            e = est.estimate()
            if e is not None:
                record["estimate"] = {"position_sigma_m": e.position_sigma, "height_sigma_m": e.height_sigma,
                                      "velocity_sigma_mps": e.velocity_sigma,
                                      "attitude_sigma_deg": np.degrees(e.attitude_sigma),
                                      "gyro_bias_radps": e.gyro_bias, "disturbance_mps2": e.disturbance,
                                      "innovation_position_m": est.innovation_position,
                                      "innovation_attitude_deg": np.degrees(est.innovation_attitude),
                                      "fused": est.fused, "rejected": est.rejected, "late": est.late}
            if truth is not None:
                record["truth"] = {"position_m": truth.position, "rotation": truth.rotation}
            self.log.record("/control", record, tw)
            if self.periods % 25 == 1:  # telemetry at a tenth of the loop rate (250 Hz -> 10 Hz)
                self.log.record("/backend/telemetry", _telemetry_record(t, telemetry), tw)
        if self.on_status is not None:
            battery = float(telemetry.battery_v.min()) if telemetry.battery_v.size else None
            st = self._stats
            t_w, n_w = self._rate_window
            if t - t_w >= RATE_WINDOW_S:  # periods actually run, not the configured rate
                self._rate_hz, self._rate_window = (self.periods - n_w) / (t - t_w), (t, self.periods)
            self.on_status(Status(t, self.phase, age, worst, battery, st.overruns if st is not None else 0,
                                  self._rate_hz, self.integrity(), self.plan.duration,
                                  math.dist(flown.position, sp.position)))

    # -- run --------------------------------------------------------------------------------------------------------
    def run(self, clock: Clock, rate_hz: float, realtime: bool = False) -> LoopStats:
        """Fly on ``clock`` at ``rate_hz``; the motors are off when this returns, whatever happened.

        ``realtime`` only records that the caller runs this thread under real-time scheduling."""
        self._stats = LoopStats(1.0 / rate_hz, realtime=realtime)
        self._stall_warn = 5.0 / rate_hz
        step = self.step
        activity = self.activity
        if activity is not None:
            def step(k: int, t: float) -> bool:  # background threads wait while a period computes (GIL)
                activity.begin()
                try:
                    return self.step(k, t)
                except BaseException:
                    activity.end()
                    raise
        every = max(1, int(rate_hz * GC_INTERVAL_S))
        pending = [0]

        def between(time_left: float) -> None:
            """Idle time of a period: young-generation GC once a second, then the background threads' turn."""
            t0 = time.perf_counter()
            pending[0] += 1
            if pending[0] >= every and collect_young(time_left):
                pending[0] = 0
            if activity is not None:
                activity.end(time_left - (time.perf_counter() - t0))

        try:
            # Arming is a round trip with the hardware backends (every module must confirm): done before the
            # first period so that wait is not a late period. So is reading what queued meanwhile (a second of
            # MAVLink telemetry, 64 mocap samples): the first period then parses one period's worth.
            if self.requests.stop.is_set() or self.requests.land.is_set():  # asked before anything spun
                self.reason = self.requests.abort_reason("before arming")
                self._set_phase(0.0, Phase.ABORTED, self.reason)
                return self._stats
            self._estimate(self.backend.telemetry())  # the gyros judged before anything is armed
            if self.gyros.fault:  # a failed IMU on the ground is no reason to take off (NaN: at once; frozen, 40 ms)
                self.reason = f"gyro fault before take-off: {self.gyros.fault}"
                self._set_phase(0.0, Phase.ABORTED, self.reason)
                return self._stats
            try:
                with poses_kept_up(self.pose, 1.0 / rate_hz):
                    self.backend.arm()
            except ArmingError as exc:
                self.backend.disarm()
                self.reason = str(exc)
                self._set_phase(0.0, Phase.ABORTED, f"arming failed: {exc}")
                return self._stats
            if self.requests.stop.is_set() or self.requests.land.is_set():
                # Asked while arming (over a second with PX4 modules): nothing has spun, so a disarm, not the
                # emergency stop the first period would give (on PX4 a termination that latches until a reboot).
                self.backend.disarm()
                self.reason = self.requests.abort_reason("while arming", armed=True)
                self._set_phase(0.0, Phase.ABORTED, self.reason)
                return self._stats
            self._estimate(self.backend.telemetry())
            with collector_paused():
                stats = run_fixed_rate(step, rate_hz, clock, stats=self._stats, between=between)
        except BaseException as exc:
            self._emergency(self._t_last(), "interrupted (KeyboardInterrupt)" if isinstance(exc, KeyboardInterrupt)
                            else f"the control loop crashed: {type(exc).__name__}: {exc}")
            raise
        finally:
            if activity is not None:
                activity.end()  # no more periods: background threads may work freely
            if not self.phase.final:
                self._emergency(self._t_last(), "loop ended")
            if self.log is not None and self._stats.t0 is not None:  # the loop ran (to its end, or it crashed)
                self.log.record("/loop/timing", asdict(self._stats.summary()), self._log_time(self._t_last()))
        return stats

    @property
    def stats(self) -> LoopStats | None:
        """The loop's timing so far (None before :meth:`run`)."""
        return self._stats

    def _t_last(self) -> float:
        """Flight time of the last period that computed a command (0 before the first)."""
        t = self.metrics.t_last
        return 0.0 if t != t else t


def _level(rotation: np.ndarray) -> np.ndarray:
    """Keep only the yaw of an attitude target (landing levels the assembly)."""
    yaw = roll_pitch_yaw(rotation)[2]
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _telemetry_record(t: float, telemetry: Telemetry) -> dict:
    """The ``/backend/telemetry`` record (:data:`groundstation.flightlog.schemas.TELEMETRY`): per-module values in
    one object per module, so that a module's unmeasured round trip (NaN) is the one member the writer leaves out,
    where an array of every module's would go whole; what the backend does not report (an empty array) is not
    written."""
    modules = [{"rotor_speed_sq_rad2_s2": m} for m in telemetry.motors.reshape(-1, 4)]
    for key, values in (("battery_v", telemetry.battery_v), ("link_latency_s", telemetry.link_latency_s),
                        ("link_loss_frac", telemetry.link_loss)):
        # One value per module; an empty array (not reported) adds none, and a short one must not raise in the loop.
        for module, v in zip(modules, values, strict=False):
            module[key] = v
    record = {"t_s": t, "link_ok": telemetry.link_ok, "modules": modules}
    if telemetry.gyro.size:
        record["gyro_radps"] = telemetry.gyro
    return record
