"""An error-state Kalman filter of the assembly's rigid-body state: motion capture fused with the modules' gyros
and the commanded wrench, predicted to the control period's time.

Model (all noises isotropic, so each block's covariance is one small matrix shared by the three axes):

* Translation, per world axis: ``p' = v``, ``v' = a + d + w_a``, ``d' = w_d``. ``a = R F / m - g e3`` is the
  acceleration the commanded body force ``F`` (the allocation of the last command sent) gives the assembly's mass
  ``m`` (none with the motors off). ``d`` is the acceleration the model misses (mass and thrust-map errors,
  battery sag, motor lag, wind, the ground's reaction at take-off and touchdown): a random walk ``w_d``; ``w_a``
  white.
* Attitude: ``R' = R [g - b]x`` with the body rate ``g`` from the modules' gyros and their bias ``b`` (a random
  walk ``w_b``); the error ``R_true = R exp(theta)`` (body frame) grows with the gyro noise and the bias error.
  A gyro reading is ``gyro_delay`` old when it arrives (the IMU's filter, a state packet's trip, a telemetry
  interval): the gyros integrate the attitude at ``t - gyro_delay``, and the newest rate carries it the rest of
  the way to ``t``. Integrating late rates as if they were current would leave the attitude a rate times the delay
  behind: 4.5 deg at 300 deg/s and 15 ms, enough to make the attitude loop oscillate (measured on simulated PX4
  modules).
* Measurements: the mocap position and attitude at their capture time ``t_m`` (before now: mocap latency, transport,
  polling), with std ``position_noise`` and ``attitude_noise``.

A measurement is compared with the estimate *at its capture time* (a short history of predicted states), the
correction is made there and carried to now through the model's transition (the history after ``t_m`` moves with
it), so the output is the state at the control time, latency compensated. The gain uses the covariance now
(Larsen's approximation for delayed measurements; the difference over a few milliseconds is negligible).

Innovation health: a measurement farther from the estimate than ``gate_sigma`` standard deviations of its innovation
(and than a floor that covers what the model leaves out) is rejected and counted, never fused; a stream rejected for
``inconsistent_s`` on end is a fault (:meth:`RigidBodyFilter.fault`): a pose frozen while the gyros turn, a body
swapped for another, a forger's track. A rejected position multiplies the position's and velocity's covariance by
``rejection_inflation`` (a fading memory; the disturbance's by its square root: :func:`_inflated`): if the model,
not the pose, was wrong (a shove, a thrust map far off), the gate has opened to the poses again after three or four
samples, before the fault; only a pose the body could have reached inflates it (``max_model_accel``), so a pose a
metre away stays out, and after the fault (latched; unless it was the gyros': :meth:`RigidBodyFilter.gyros_lost`)
no pose is fused again. The attitude is not inflated: the gyros
predict it too well for a frozen pose to pass. Through an outage the covariance grows with the model's noises, so
the gate opens again by itself and the failsafe can act on the uncertainty.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from groundstation.assembly.module import GRAVITY
from groundstation.control.state import RigidState
from groundstation.estimation.measurement import PoseMeasurement
from groundstation.rotations import (
    Mat3,
    Vec3,
    mat3_from_rotvec,
    mat3_mul,
    mat3_orthonormal,
    mat3_tmul,
    mat3_to_rotvec,
    mat3_vec,
    matrix_to_rotvec,
)


@dataclass(frozen=True)
class EstimatorSettings:
    """The filter's noises, gates and delays (defaults: a lab mocap at 100-360 Hz, Crazyflie-class gyros)."""

    position_noise: float = 0.001
    """Mocap position std per axis, m."""
    attitude_noise: float = math.radians(0.2)
    """Mocap attitude std per axis, rad."""
    accel_noise: float = 0.02
    """Unmodelled acceleration, white, m/s^2/sqrt(Hz). The commanded wrench predicts the motion well, so this is
    small: on the toy figure-8 with 1 mm / 0.2 deg mocap noise, 0.5 (a filter that trusts the poses) passed the
    noise to the rotors as 0.092 u_max per period (RMS; attitude error p95 4.9 deg), 0.1 as 0.024 (2.1 deg),
    0.02 as 0.011 (1.1 deg), all with the same 2.1 mm position RMSE (``python -m benchmarks.estimator
    --flights``, 2026-12-02)."""
    disturbance_walk: float = 0.05
    """Random walk of the slowly varying acceleration the model misses (``d``), m/s^2/sqrt(s): it learns a 1 m/s^2
    thrust-map error in about a second."""
    gyro_noise: float = 0.005
    """Gyro rate noise, rad/s/sqrt(Hz): the sensor's (~2.5e-4 for a BMI088) plus what the model leaves out (module
    misalignment, the gyros' delay, taken as one control period of zero-order hold)."""
    gyro_bias_walk: float = 0.001
    """Random walk of the gyro bias, rad/s/sqrt(s)."""
    initial_velocity: float = 0.2
    """Std of the velocity at the first measurement, m/s (the assembly rests, or moves slowly, when mocap starts)."""
    initial_disturbance: float = 1.0
    """Std of ``d`` at the first measurement, m/s^2."""
    initial_bias: float = 0.02
    """Std of the gyro bias at the first measurement, rad/s."""
    gate_sigma: float = 6.0
    """A measurement whose innovation exceeds this many of its standard deviations is rejected."""
    position_gate_floor: float = 0.02
    """...unless it is within this distance of the estimate, m (a shove the model did not see: 2 m/s^2 over a
    sample interval and a half)."""
    rejection_inflation: float = 4.0
    """Factor on the position's and velocity's covariance per rejected position (see the module docstring)..."""
    max_model_accel: float = 3.0 * GRAVITY
    """...for a rejected pose the body could have reached: within ``position_gate_floor`` plus ``max_model_speed``
    t plus this acceleration's ``t^2 / 2`` of the estimate, ``t`` after the last pose fused (a push, a tether, a
    thrust map far off: the model, not the pose, may be wrong), m/s^2. A pose beyond that reach is no evidence
    against the model and inflates nothing: a body swapped for another 0.8 m away was fused after eight
    rejections before, ahead of the fault, and the V flown towards it tilted 60 deg."""
    max_model_speed: float = 2.0
    """The velocity error the estimate may carry into such a run of rejections, m/s."""
    attitude_gate_floor: float = math.radians(1.5)
    """...or this angle, rad, ..."""
    thrust_lag: float = 0.0
    """Time constant of the rotors' first-order lag behind the commanded thrust, s (the backend's: the simulator's
    ``motor_time_constant``, a Crazyflie's brushed motors ~20 ms). Left out, the disturbance takes the lag for the
    model's error: a 1 s take-off swung it -0.5..+0.3 m/s^2, and flown on blind from a take-off cut short, the
    estimate descended at 0.5 m/s while the body climbed to 2.9 m (hostile campaign); a thrust step's lag alone
    leaves the velocity ``dF lag / m`` off (0.17 m/s for the toy V's step from take-off to a blind landing)."""
    gyro_delay: float = 0.0
    """Age of a gyro reading when the estimator gets it, s (the backend's: :data:`groundstation.backend_kinds`)."""
    gyro_timing: float = 0.02
    """...plus the angle the body turns in this time, s: how far the gyros' and the poses' times may still disagree
    (``gyro_delay`` and the mocap's latency are configured, not measured; a link's delay varies). With 1 deg and
    10 ms, simulated Crazyflie modules saw 51 ms of rejected poses in a take-off (1.4 deg at ~40 deg/s)."""
    gyro_stale_s: float = 0.03
    """A gyro reading older than this is no longer news, s (its packets stopped: a radio gap, a starved link, a
    module gone; Crazyflie and PX4 modules stream at 100 Hz or faster): the attitude is then held, not turned on at
    the old rate, the body rate is unknown (zero to the controller) and the attitude's uncertainty grows by
    ``unseen_rate`` (so the next poses correct it). Integrating a 110 deg/s reading held through a 100 ms gap
    left the attitude 11 deg off, every later pose was rejected, and the assembly, flown on the phantom turn,
    flipped (real firmware in the loop)."""
    unseen_rate: float = 0.5
    """How fast the body may turn, unseen, while the gyros are stale (std per axis), rad/s: a flying assembly's
    rates, not a tumble's. It opens the attitude gate to the next poses (after 100 ms: 6 sigma = 12 deg) and, with
    the mocap gone too, is the attitude's uncertainty the flight bounds (15 deg: 0.5 s) and feeds the blind
    landing's position uncertainty (at 2 rad/s that passed the 0.5 m bound of the time 0.39 s after a peer died,
    ahead of the link timeout that names the lost modules)."""
    lost_rate_walk: float = 3.0
    """With no gyro usable (:meth:`RigidBodyFilter.predict` given NaN), the bias state becomes the body rate the
    poses show (the gyro read as zero, the rate is minus the "bias"): its random walk is then the body's angular
    acceleration, rad/s/sqrt(s). The attitude becomes a constant-rate tracker of the poses, whose rate has less lag
    than the poses' differences over ``POSE_RATE_WINDOW_S`` (flown on, those let the V's attitude loop swing to
    77 deg in a landing)."""
    inconsistent_s: float = 0.05
    """Measurements rejected over this long on end are a fault, s (five samples at 100 Hz)."""
    history_s: float = 0.15
    """How far back the estimate is kept for delayed measurements, s (above the mocap latency plus a late poll;
    older poses are dropped, counted as :attr:`RigidBodyFilter.late`)."""


@dataclass(frozen=True, eq=False)
class Estimate:
    """The state at ``t`` with its uncertainty and the filter's health."""

    t: float
    """Pose-source clock, s."""
    state: RigidState
    position_sigma: float
    """Std per horizontal axis, m: the translation filter's, plus what an attitude error does to a body flown blind
    (the filter does not carry it: a tilt error theta accelerates the position error sideways by g theta, so
    ``tau`` s after the last pose fused the std grows by g sigma_theta tau^2 / 2)."""
    height_sigma: float
    """Std of the height, m: the translation filter's alone (a tilt error of theta changes the vertical thrust by
    a factor cos theta only: 1e-4 at the 0.8 deg of a 3 s blind landing)."""
    velocity_sigma: float
    """Std per axis, m/s."""
    attitude_sigma: float
    """Std per axis, rad."""
    gyro_bias: np.ndarray
    """(3,) estimated gyro bias, body frame, rad/s."""
    disturbance: np.ndarray
    """(3,) acceleration the model misses, world frame, m/s^2."""


LOST_ATTITUDE_SIGMA = 0.5
"""Std of the attitude when the gyros are lost, rad (:meth:`RigidBodyFilter._lose_gyros`): the next pose is taken
whole."""
LOST_ATTITUDE_GATE = math.radians(20.0)
"""With the gyros lost, a pose's attitude is rejected only this far (or its gate's sigmas) from the estimate's, rad:
the estimate is then the poses' own, turned at the rate they showed, and lags them when the body's turn changes (a
push in the take-off: 7.9 deg, every pose rejected, the attitude held, and the V rolled to 98-105 deg); a rigid body
mis-fit or flipped in the mocap is still refused."""
FORGET_S = 0.25
"""How far back :meth:`RigidBodyFilter.forget_since` reaches, s. A forger interleaving its samples with the genuine
ones is a fault within ~40 ms; one that sends a few a second takes up to a second (three conflicts within one:
:class:`groundstation.mocap.zenoh_link.SubscriberSettings`), and its older samples, each one among dozens of genuine
ones, have been outweighed by them. Reaching back that whole second took back 65-97 genuine poses with 2-3 forged
ones, and the blind landing, begun a second old from 1.6 m, ran out of certainty 0.4-0.5 m up (hostile campaign)."""
REGROW_STEP_S = 0.004
"""...and grows the covariance it restores in steps this long, s (a 250 Hz control period)."""
POSE_RATE_WINDOW_S = 0.05
"""Span of the poses :meth:`RigidBodyFilter.pose_rate` differentiates, s."""
_IDENTITY: Mat3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


def _step(p: Vec3, v: Vec3, a: Vec3, dt: float) -> tuple[Vec3, Vec3]:
    """Position and velocity ``dt`` s on, at the constant acceleration ``a``."""
    h = 0.5 * dt * dt
    (px, py, pz), (vx, vy, vz), (ax, ay, az) = p, v, a
    return ((px + vx * dt + ax * h, py + vy * dt + ay * h, pz + vz * dt + az * h),
            (vx + ax * dt, vy + ay * dt, vz + az * dt))


def _inflated(pt: list[float], k: float) -> list[float]:
    """The translation covariance ``pt`` after a rejection: ``S P S`` with ``S = diag(sqrt k, sqrt k, k^(1/4))``
    (still a covariance), the position's and velocity's variances times ``k``, the disturbance's only times
    ``sqrt k``. What a rejection makes room for is a shove (a velocity the model did not see) more than a new
    steady push. Inflated by ``k`` too, the disturbance took up a 3 m/s shove that stopped dead (the estimate blind
    after the fault ran 24 m in 2 s); not inflated at all, it learnt an assembly tied down under twice its weight
    too slowly (the estimate 6 cm off for seconds)."""
    pp, pv, pd, vv, vd, dd = pt
    r = math.sqrt(k)
    q = math.sqrt(r)
    return [pp * k, pv * k, pd * r * q, vv * k, vd * r * q, dd * r]


def _corrected(p: Vec3, v: Vec3, d: Vec3, cp: Vec3, cv: Vec3, cd: Vec3, tau: float) -> tuple[Vec3, Vec3, Vec3]:
    """Position, velocity and disturbance with the correction ``(cp, cv, cd)`` made ``tau`` s before them, carried
    through the model."""
    h = 0.5 * tau * tau
    (px, py, pz), (vx, vy, vz), (dx, dy, dz) = p, v, d
    (cpx, cpy, cpz), (cvx, cvy, cvz), (cdx, cdy, cdz) = cp, cv, cd
    return ((px + cpx + cvx * tau + cdx * h, py + cpy + cvy * tau + cdy * h, pz + cpz + cvz * tau + cdz * h),
            (vx + cvx + cdx * tau, vy + cvy + cdy * tau, vz + cvz + cdz * tau),
            (dx + cdx, dy + cdy, dz + cdz))


class RigidBodyFilter:
    """See the module docstring. Call :meth:`predict` once per control period (it sets the time and the inputs),
    :meth:`correct` with every measurement in capture order, read :meth:`state`, and tell it the command sent
    (:meth:`command`).

    The state is kept in Python floats (3-tuples, :data:`~groundstation.rotations.Mat3`), not numpy arrays: the
    work of a period is a few dozen operations on single 3-vectors and rotations, where numpy's overhead per call,
    not the arithmetic, was the cost (``python -m benchmarks.estimator``, 2026-12-02: 139 us a period in numpy,
    54 us in floats). Arrays are made only for the outputs."""

    def __init__(self, settings: EstimatorSettings, mass: float) -> None:
        self.settings = settings
        self.mass = mass
        """kg"""
        s = settings
        self._qa, self._qd = s.accel_noise ** 2, s.disturbance_walk ** 2
        self._qg, self._qb = s.gyro_noise ** 2, s.gyro_bias_walk ** 2
        self._rp, self._ra = s.position_noise ** 2, s.attitude_noise ** 2
        self._t: float | None = None
        """Time of the estimate, s (the latest predict or the first measurement)."""
        self._gyro: Vec3 | None = None
        """The body rate the gyros give now (None: no reading, or a stale one), rad/s, body frame."""
        self._specific_force: Vec3 | None = None
        self._applied_force: Vec3 | None = None
        """The specific force the rotors give (``thrust_lag`` behind the commanded), body frame, m/s^2."""
        """The commanded body force over the mass, m/s^2, body frame (None: motors off)."""
        self._p: Vec3 = (0.0, 0.0, 0.0)
        self._v: Vec3 = (0.0, 0.0, 0.0)
        self._d: Vec3 = (0.0, 0.0, 0.0)
        self._r: Mat3 = _IDENTITY
        """Attitude at the estimate's time."""
        self._r_gyro: Mat3 = _IDENTITY
        """Attitude ``gyro_delay`` earlier: where the gyros have got to."""
        self._b: Vec3 = (0.0, 0.0, 0.0)
        self._lost: tuple[Vec3, float] | None = None
        """While no gyro is usable: (the bias before, when the last usable reading arrived, s); None otherwise."""
        self._pt = [0.0] * 6
        """Translation covariance per axis: pp, pv, pd, vv, vd, dd."""
        self._pa = [0.0] * 3
        self._pa_fused: tuple[float, float, float] | None = None
        """The attitude covariance as the newest pose left it, while the gyros have been integrated since (None
        once they went stale or were lost: :meth:`estimate` then bounds the tilt's share coarsely)."""
        """Attitude covariance per axis: theta-theta, theta-bias, bias-bias."""
        self._history: deque[list] = deque()
        """[t, p, v, d, R, a] of past estimates, oldest first; ``a``: the acceleration of the step that ended
        there."""
        self._a: Vec3 = (0.0, 0.0, 0.0)
        """The acceleration of the latest step, world frame, m/s^2."""
        self.initialized = False
        self.fused = 0
        """Measurements fused."""
        self.rejected = 0
        """Measurements rejected by the innovation gates."""
        self.late = 0
        """Measurements captured before the oldest estimate kept (``history_s``), dropped unused."""
        self.last_rejection = ""
        self.last_fused_t = -math.inf
        self._fused_arrival = -math.inf
        """The estimate's time when the newest fused measurement was fused (its arrival, within a period), s."""
        """Capture time of the newest fused measurement, s."""
        self._last_pose: tuple[float, list[float], list[float]] | None = None
        """(t, position, rotation's entries) of the measurement before (to tell a frozen stream)."""
        self._corrections: deque[tuple[float, Vec3, Vec3, Vec3, list[float], float, float]] = deque()
        """(capture time, position, velocity and disturbance correction there, the translation covariance before
        it, the estimate's time then, the capture time of the measurement fused before) of the measurements fused
        in the last ``FORGET_S``, oldest first: what :meth:`forget_since` takes back."""
        self.forgotten = 0
        """Measurements fused and later taken back (:meth:`forget_since`)."""
        self._fused_poses: deque[PoseMeasurement] = deque()
        """The fused measurements of the last ``POSE_RATE_WINDOW_S`` (:meth:`pose_rate`)."""
        self._rejecting_since: float | None = None
        """Capture time of the first measurement of the current run of rejections."""
        self._attitude_only = False
        """The run of rejections since ``_rejecting_since`` was for the attitude alone (its positions agreed)."""
        self._pt_plain: list[float] | None = None
        """While rejections inflate the translation covariance (since the last fused measurement): the covariance
        as it would be without them, propagated alike. A fault restores it; dividing by the factor instead also
        divided the process noise added since (the covariance 5-23 % low)."""
        self._fault = ""
        self._innovation_position: Vec3 = (0.0, 0.0, 0.0)
        self._innovation_attitude: Vec3 = (0.0, 0.0, 0.0)
        self._attitude_seen: tuple[float, float] = (-math.inf, 0.0)
        """(capture time s, angle rad) of the newest pose whose attitude was compared with the estimate's."""
        self._state: RigidState | None = None
        """The state handed out since the estimate last changed: the flight reads it twice a period (to control, to
        log), and its arrays cost microseconds."""

    # -- inputs -----------------------------------------------------------------------------------------------------
    def predict(self, t: float, gyro: np.ndarray | None, gyro_age: float = 0.0) -> None:
        """Advance the estimate to ``t`` (s), turning it at ``gyro``, the body rate the modules report now (rad/s,
        body frame: the newest reading is the best one for the time since the last call; None: none streamed,
        the attitude is held between measurements; NaN: no gyro usable, ``gyro_age`` since the last usable one,
        and the rate is learnt from the poses: ``lost_rate_walk``), under the last :meth:`command`. ``gyro_age``:
        how long ago the reading arrived, s (beyond ``gyro_stale_s`` it is stale)."""
        self._state = None
        g = None if gyro is None else np.asarray(gyro, float).tolist()
        # A reading that is not a rate (NaN: no gyro usable, :class:`GyroAgreement`) puts the filter in its
        # gyros-lost mode, below.
        unseen = gyro_age - self.settings.gyro_stale_s if g is not None else 0.0
        usable = g is not None and len(g) == 3 and all(map(math.isfinite, g))
        g = tuple(g) if usable else None
        if unseen != unseen:  # an age that is not a number: as old as can be
            unseen = math.inf
        lost = gyro is not None and not usable and unseen < math.inf
        if lost != (self._lost is not None):
            self._lose_gyros(t - gyro_age) if lost else self._regain_gyros()
        if lost:
            # The gyro reads zero: the rate is minus the "bias", which the poses estimate (``lost_rate_walk``). But
            # only while they come: ``gyro_stale_s`` after the last one fused *arrived* (its capture time would
            # count the mocap's latency: at 30 ms every period was "unobserved"), the attitude is held (turned on
            # at the rate last learnt, a 200 ms gap spun the V over) and its uncertainty grows, so the next pose
            # sets it.
            unseen = t - max(self._fused_arrival, self._lost[1]) - self.settings.gyro_stale_s
            g = (0.0, 0.0, 0.0)
        self._gyro = None if unseen > 0.0 else g  # never heard (an infinite age): none streamed
        if self.initialized and self._t is not None and t > self._t:
            if 0.0 < unseen < math.inf:
                self._unseen_turn(max(unseen - (t - self._t), 0.0), unseen)
            self._propagate(t - self._t)
            self._t = t
            self._remember()
        elif self._t is None or t > self._t:
            self._t = t

    def _lose_gyros(self, last_usable: float) -> None:
        """No gyro usable from now (the last usable reading arrived at ``last_usable``, s): the bias state carries
        minus the body rate, starting from the poses' (or zero), free to follow it."""
        rate = self._pose_rate() or (0.0, 0.0, 0.0)  # not the last reading's: a frozen one is what failed
        self._lost = (self._b, last_usable)
        self._b = (-rate[0], -rate[1], -rate[2])
        self._qb = self.settings.lost_rate_walk ** 2
        # The attitude: what the failed readings made of it is unknown (stuck at 5 rad/s for the 40 ms it takes to
        # see a freeze, it turned 11 deg away, beyond the gate, and the V flipped): the next pose sets it.
        tt, _, bb = self._pa
        self._pa = [max(tt, LOST_ATTITUDE_SIGMA ** 2), 0.0, max(bb, self.settings.unseen_rate ** 2)]

    def _regain_gyros(self) -> None:
        """A usable reading again: the bias is the one the gyros had."""
        s = self.settings
        self._b, self._lost = self._lost[0], None
        self._qb = s.gyro_bias_walk ** 2
        self._pa = [self._pa[0], 0.0, s.initial_bias ** 2]

    def command(self, force: np.ndarray | None) -> None:
        """The body force of the command just sent, N, body frame (the allocation's force rows times the rotor
        inputs; None: motors off); it acts until the next call."""
        if force is None:
            self._specific_force = self._applied_force = None
        else:
            fx, fy, fz = np.asarray(force, float).tolist()
            m = self.mass
            self._specific_force = (fx / m, fy / m, fz / m)
            if self._applied_force is None:
                self._applied_force = self._specific_force

    def _propagate(self, dt: float) -> None:
        dx, dy, dz = d = self._d
        if self._specific_force is None:  # motors off: resting (the ground holds it) or carried
            a = d
        else:
            lag = self.settings.thrust_lag
            if lag > 0.0 and dt > 0.0:
                # The rotors reach the commanded thrust as a first-order lag: over the step, its mean (the velocity
                # exact) and, at its end, where it got to.
                k = 1.0 - math.exp(-dt / lag)
                m = k * lag / dt
                (cx, cy, cz), (fx, fy, fz) = self._specific_force, self._applied_force
                self._applied_force = (fx + k * (cx - fx), fy + k * (cy - fy), fz + k * (cz - fz))
                force = (cx - m * (cx - fx), cy - m * (cy - fy), cz - m * (cz - fz))
            else:
                force = self._applied_force = self._specific_force
            ax, ay, az = mat3_vec(self._r, force)
            a = (ax + dx, ay + dy, az - GRAVITY + dz)
        self._a = a
        self._p, self._v = _step(self._p, self._v, a, dt)
        rate = self._rate()
        if rate is not None:
            wx, wy, wz = rate
            self._r_gyro = mat3_mul(self._r_gyro, mat3_from_rotvec(wx * dt, wy * dt, wz * dt))
            delay = self.settings.gyro_delay
            self._r = mat3_mul(self._r_gyro, mat3_from_rotvec(wx * delay, wy * delay, wz * delay)) if delay > 0.0 \
                else self._r_gyro
        self._pt = self._grown(self._pt, dt)
        if self._pt_plain is not None:
            self._pt_plain = self._grown(self._pt_plain, dt)
        tt, tb, bb = self._pa
        if rate is None:  # the attitude held, not turned at the rate less the bias: no coupling to the bias
            self._pa = [tt + self._qg * dt, tb, bb + self._qb * dt]
        else:
            self._pa = [tt - 2.0 * dt * tb + dt * dt * bb + self._qg * dt, tb - dt * bb, bb + self._qb * dt]

    def _grown(self, pt: list[float], dt: float) -> list[float]:
        """The translation covariance ``pt`` (per axis: position, velocity, disturbance; upper triangle) after
        ``dt`` s: carried by the motion, plus the process noise of the step."""
        pp, pv, pd, vv, vd, dd = pt
        h = 0.5 * dt * dt
        r00, r01, r02 = pp + dt * pv + h * pd, pv + dt * vv + h * vd, pd + dt * vd + h * dd
        r11, r12 = vv + dt * vd, vd + dt * dd
        qa = self._qa
        return [r00 + dt * r01 + h * r02 + qa * dt ** 3 / 3.0, r01 + dt * r02 + qa * h, r02,
                r11 + dt * r12 + qa * dt, r12, dd + self._qd * dt]

    def _unseen_turn(self, tau0: float, tau1: float) -> None:
        """Grow the attitude variance for a step from ``tau0`` to ``tau1`` s past ``gyro_stale_s`` on a stale
        reading: the body may have turned at ``unseen_rate`` throughout, so the std grows with the stale time."""
        self._pa[0] += self.settings.unseen_rate ** 2 * (tau1 * tau1 - tau0 * tau0)
        self._pa_fused = None

    def _rate(self) -> Vec3 | None:
        """The body rate: the gyros' less their bias, rad/s (None: no reading)."""
        if self._gyro is None:
            return None
        (gx, gy, gz), (bx, by, bz) = self._gyro, self._b
        return gx - bx, gy - by, gz - bz

    def _remember(self) -> None:
        hist = self._history
        hist.append([self._t, self._p, self._v, self._d, self._r, self._a])
        while len(hist) > 2 and hist[1][0] < self._t - self.settings.history_s:
            hist.popleft()

    # -- measurements -----------------------------------------------------------------------------------------------
    def correct(self, m: PoseMeasurement) -> bool:
        """Fuse one measurement (True), or reject it (False: counted, :attr:`last_rejection` says why). The first
        one starts the estimate."""
        position = np.asarray(m.position, float).tolist()
        rotation = np.asarray(m.rotation, float).ravel().tolist()
        if not (math.isfinite(m.t) and all(map(math.isfinite, position)) and all(map(math.isfinite, rotation))):
            return self._reject(m.t, "not finite", attitude=False)
        if not self.initialized:
            self._start(m, position, rotation)
            return True
        if self._fault:
            # The stream was judged untrustworthy (latched): the flight lands on the estimate alone. Judged on, the
            # inflation that lets a shoved estimate catch up with its poses would open the gate, rejection after
            # rejection, to the very track the fault is about (a body swapped for one moving 0.8 m off was fused
            # after eight samples, and the V, flown towards it, tilted 60 deg).
            self.rejected += 1
            return False
        last, self._last_pose = self._last_pose, (m.t, position, rotation)
        if last is not None and m.t > last[0] and position == last[1] and rotation == last[2]:
            # A camera system measures with noise: the same pose twice to the last bit, newly timed, is a stream
            # that froze (a lost body held, a stuck bridge), whatever the body does meanwhile.
            return self._reject(m.t, "the same pose again, to the last bit: a frozen stream", attitude=False)
        at = self._at(m.t)
        if at is None:  # older than anything the estimate remembers: news of no use, not a wrong pose
            self.late += 1
            return False
        hist = self._history
        tm, p_m, v_m, d_m, r_m, _ = hist[at]
        a = hist[at + 1][5] if at + 1 < len(hist) else self._a  # what the estimate's step from there assumed
        p_m, v_m = _step(p_m, v_m, a, m.t - tm)  # the estimate at the capture time
        s = self.settings
        dp = (position[0] - p_m[0], position[1] - p_m[1], position[2] - p_m[2])
        s_p = self._pt[0] + self._rp
        miss = math.sqrt(dp[0] * dp[0] + dp[1] * dp[1] + dp[2] * dp[2])
        self._innovation_position, self._innovation_attitude = dp, (0.0, 0.0, 0.0)
        if miss > max(s.gate_sigma * math.sqrt(s_p), s.position_gate_floor):
            blind = m.t - self.last_fused_t
            if miss <= s.position_gate_floor + (s.max_model_speed + 0.5 * s.max_model_accel * blind) * blind:
                if self._pt_plain is None:
                    self._pt_plain = list(self._pt)
                self._pt = _inflated(self._pt, s.rejection_inflation)
            return self._reject(m.t, f"position {miss * 100:.1f} cm off the estimate", attitude=False)
        turning = self._rate()
        if turning is not None and m.t > tm:
            tau = m.t - tm
            r_m = mat3_mul(r_m, mat3_from_rotvec(turning[0] * tau, turning[1] * tau, turning[2] * tau))
        dth = mat3_to_rotvec(mat3_tmul(r_m, rotation))
        s_a = self._pa[0] + self._ra
        off = math.sqrt(dth[0] * dth[0] + dth[1] * dth[1] + dth[2] * dth[2])
        gyro = self._gyro
        rate = math.sqrt(gyro[0] * gyro[0] + gyro[1] * gyro[1] + gyro[2] * gyro[2]) if gyro is not None else 0.0
        self._innovation_attitude = dth
        self._attitude_seen = (m.t, off)
        floor = s.attitude_gate_floor + rate * s.gyro_timing if self._lost is None else LOST_ATTITUDE_GATE
        if off > max(s.gate_sigma * math.sqrt(s_a), floor):
            return self._reject(m.t, f"attitude {math.degrees(off):.1f} deg off the gyros' prediction")
        pt_before = self._pt_plain or self._pt
        cp, cv, cd, ct = self._fuse(m.t, dp, s_p, dth, s_a)
        corrections = self._corrections
        corrections.append((m.t, cp, cv, cd, pt_before, self._t, self.last_fused_t))
        while corrections[0][0] < m.t - FORGET_S:
            corrections.popleft()
        if m.t > tm:
            # The corrected estimate at the capture time joins the history: the next pose captured before the next
            # entry is compared with it, not with the uncorrected one before (after a pause between periods, a
            # burst of poses all fell between two entries and each was compared with the same stale estimate).
            hist.insert(at + 1, [m.t, *_corrected(p_m, v_m, d_m, cp, cv, cd, 0.0),
                                 mat3_mul(r_m, mat3_from_rotvec(*ct)), a])
        self._rejecting_since = None
        self._pt_plain = None
        self.fused += 1
        self.last_fused_t = max(self.last_fused_t, m.t)
        self._pa_fused = tuple(self._pa)
        self._fused_arrival = self._t
        self._keep_fused(m)
        return True

    def set_disturbance(self, d: Vec3) -> None:
        """The disturbance is ``d`` from now on (world, m/s^2): the position and velocity go on from where they are
        (no jump for the controller to chase)."""
        self._d = tuple(d)
        self._state = None

    @property
    def disturbance_vector(self) -> Vec3:
        """The acceleration the model misses, world, m/s^2."""
        return self._d

    def forget_since(self, t: float) -> int:
        """Take back the translation corrections of every measurement captured at or after ``t`` (s, at most
        ``FORGET_S`` ago), as if they had never come: the position, velocity and disturbance lose exactly what
        each added (the model is linear in them: a correction at ``t_m`` is carried to ``tau`` later as ``_corrected``
        says), the covariance is the one before the first of them, grown since, and the estimate's age counts from
        the measurement before. For poses that turn out to be a forger's (:meth:`PoseSubscriber.untrusted_since`):
        a copied source id dragging the pose down at 0.5 m/s taught the estimate a 0.4 m/s^2 sink in the 40 ms
        before the conflicts were a fault, and the blind landing after it stopped the motors 0.6 m up (a 2.2 m/s
        touchdown). The attitude's corrections stay: the gyros bound them, and a forger's pose was no more than
        the gate's 1.5 deg off. Returns how many were taken back; call it, then fuse no more of the stream."""
        undone = [c for c in self._corrections if c[0] >= t]
        if not undone or self._t is None:
            return 0
        for tm, cp, cv, cd, *_ in undone:
            back = ((-cp[0], -cp[1], -cp[2]), (-cv[0], -cv[1], -cv[2]), (-cd[0], -cd[1], -cd[2]))
            for entry in self._history:
                if entry[0] >= tm:
                    entry[1], entry[2], entry[3] = _corrected(entry[1], entry[2], entry[3], *back, entry[0] - tm)
            self._p, self._v, self._d = _corrected(self._p, self._v, self._d, *back, self._t - tm)
        _, _, _, _, pt, t_fused, before = undone[0]
        # Grown in steps of a control period, as the estimate was: in one step the disturbance's walk does not reach
        # the position's variance (1 % low after 60 ms).
        steps = max(1, math.ceil((self._t - t_fused) / REGROW_STEP_S))
        for _ in range(steps):
            pt = self._grown(pt, (self._t - t_fused) / steps)
        self._pt = pt
        self._pt_plain = None
        self.last_fused_t = before
        self._pa_fused = None  # the attitude's covariance then is not kept
        self._corrections.clear()
        self._fused_poses = deque(m for m in self._fused_poses if m.t < t)
        self._state = None
        self.forgotten += len(undone)
        return len(undone)

    def _keep_fused(self, m: PoseMeasurement) -> None:
        poses = self._fused_poses
        poses.append(m)
        while len(poses) > 2 and poses[1].t <= m.t - POSE_RATE_WINDOW_S:
            poses.popleft()

    def pose_rate(self, now: float) -> np.ndarray | None:
        """The body rate the fused poses alone show (rad/s, body frame): the rotation between the oldest and the
        newest of the last ``POSE_RATE_WINDOW_S`` over their time apart (None without two, or when the newest is
        older than twice that at ``now``, s: through an outage it says nothing). Noisy (0.2 deg of mocap noise:
        ~6 deg/s) and late, but independent of the gyros: the referee when two of them disagree."""
        poses = self._fused_poses
        if len(poses) < 2 or poses[-1].t <= poses[0].t or poses[-1].t < now - 2.0 * POSE_RATE_WINDOW_S:
            return None
        return matrix_to_rotvec(poses[0].rotation.T @ poses[-1].rotation) / (poses[-1].t - poses[0].t)

    def _pose_rate(self) -> Vec3 | None:
        rate = self.pose_rate(self._t) if self._t is not None else None
        return None if rate is None else tuple(rate.tolist())

    def _start(self, m: PoseMeasurement, position: list[float], rotation: list[float]) -> None:
        s = self.settings
        self._p, self._v, self._d = tuple(position), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        self._r = self._r_gyro = tuple(rotation)
        self._b = (0.0, 0.0, 0.0)
        self._pt = [self._rp, 0.0, 0.0, s.initial_velocity ** 2, 0.0, s.initial_disturbance ** 2]
        self._pa = [self._ra, 0.0, s.initial_bias ** 2]
        self._state = None
        now = self._t
        self._t = m.t
        self.initialized = True
        self._history.clear()
        self._remember()
        if now is not None and now > m.t:
            self._propagate(now - m.t)
            self._t = now
            self._remember()
        self.fused += 1
        self.last_fused_t = m.t
        self._pa_fused = tuple(self._pa)
        self._corrections.clear()
        self._fused_poses.clear()
        self._keep_fused(m)

    def _at(self, t: float) -> int | None:
        """Index of the newest history entry at or before ``t`` (None: ``t`` is older than the history)."""
        hist = self._history
        for i in range(len(hist) - 1, -1, -1):
            if hist[i][0] <= t:
                return i
        return None

    def _fuse(self, tm: float, dp: Vec3, s_p: float, dth: Vec3, s_a: float) -> tuple[Vec3, Vec3, Vec3, Vec3]:
        """Correct the estimate (now, and the history after ``tm``) by the innovations at ``tm``; returns the
        correction there (position, velocity, disturbance, attitude rotation vector)."""
        pp, pv, pd, vv, vd, dd = self._pt
        kp, kv, kd = pp / s_p, pv / s_p, pd / s_p
        dx, dy, dz = dp
        cp, cv, cd = (kp * dx, kp * dy, kp * dz), (kv * dx, kv * dy, kv * dz), (kd * dx, kd * dy, kd * dz)
        tt, tb, bb = self._pa
        kt, kb = tt / s_a, tb / s_a
        ex, ey, ez = dth
        ct, cb = (kt * ex, kt * ey, kt * ez), (kb * ex, kb * ey, kb * ez)
        # The correction made at tm, carried along every estimate since. The attitude's is one rotation for all:
        # what the bias correction adds over the few ms of history is below 1e-6 rad (and the rotation costs).
        # Not with the gyros lost: the "bias" is then the rate, corrected by up to 2 rad/s a pose, which over 20 ms
        # of latency is a degree or two.
        now = max(self._t - tm, 0.0)
        dr = mat3_from_rotvec(ct[0] - cb[0] * now, ct[1] - cb[1] * now, ct[2] - cb[2] * now)
        each = self._lost is not None
        for entry in reversed(self._history):
            tau = entry[0] - tm
            if tau < 0.0:
                break
            entry[1], entry[2], entry[3] = _corrected(entry[1], entry[2], entry[3], cp, cv, cd, tau)
            entry[4] = mat3_mul(entry[4], mat3_from_rotvec(ct[0] - cb[0] * tau, ct[1] - cb[1] * tau,
                                                           ct[2] - cb[2] * tau) if each else dr)
        self._p, self._v, self._d = _corrected(self._p, self._v, self._d, cp, cv, cd, now)
        self._r_gyro = mat3_orthonormal(mat3_mul(self._r_gyro, dr))
        self._r = mat3_orthonormal(mat3_mul(self._r, dr))
        self._b = (self._b[0] + cb[0], self._b[1] + cb[1], self._b[2] + cb[2])
        self._pt = [pp - pp * kp, pv - pv * kp, pd - pd * kp, vv - pv * kv, vd - pd * kv, dd - pd * kd]
        self._pa = [tt - tt * kt, tb - tb * kt, bb - tb * kb]
        self._state = None
        return cp, cv, cd, ct

    def _reject(self, t: float, why: str, attitude: bool = True) -> bool:
        """Count a rejected measurement (``attitude``: rejected for its attitude alone) and latch the fault of a
        run of them."""
        self.rejected += 1
        self.last_rejection = why
        if self._rejecting_since is None:
            self._rejecting_since, self._attitude_only = t, attitude
        else:
            self._attitude_only = self._attitude_only and attitude
        if t - self._rejecting_since >= self.settings.inconsistent_s and not self._fault:
            self._fault = (f"every pose rejected for {(t - self._rejecting_since) * 1e3:.0f} ms (last: {why}): "
                           f"frozen, swapped, forged or broken")
            # The poses were wrong, not the model: the inflation that made room for a model error goes. Kept, it
            # inflated the disturbance's variance too, and a blind landing's position uncertainty passed its 0.5 m
            # bound 0.36 s after a swapped body's fault (motors off at 0.5 m).
            if self._pt_plain is not None:
                self._pt, self._pt_plain = self._pt_plain, None
        return False

    @property
    def attitude_unobserved(self) -> bool:
        """No gyro is usable and no pose has been fused for more than ``gyro_stale_s`` (by when it arrived):
        nothing observes the attitude (it is held, its uncertainty growing)."""
        return self._lost is not None and self._gyro is None

    @property
    def attitude_seen(self) -> tuple[float, float]:
        """(capture time s, angle rad): how far the attitude of the newest pose compared with the estimate's was
        from it, fused or rejected for it (a stream no longer compared, after a fault or a copied id, leaves it
        ageing: -inf before the first)."""
        return self._attitude_seen

    @property
    def attitude_conflict_since(self) -> float | None:
        """Capture time of the first of a run of poses rejected for their attitude alone, going on now (their
        positions agreed: the poses and the gyros disagree on how the body turns), s; None without one."""
        return self._rejecting_since if self._attitude_only else None

    def gyros_lost(self, since: float) -> None:
        """No gyro has been usable since ``since`` (s; every one failed alike: :class:`GyroAgreement`); call it
        once, when that is found. A fault latched on poses rejected for their attitude alone from then on was the
        gyros' doing (stuck, they held or turned the estimate away from the poses): it is taken back, and the
        attitude's uncertainty lets the poses in. A fault of a run that began before, or rejected positions too,
        stays (called every period, a rigid body mis-fit 60 deg off was taken back six times and fused)."""
        if self._fault and self._attitude_only and self._rejecting_since is not None and \
                self._rejecting_since >= since:
            self._fault, self._rejecting_since = "", None

    # -- outputs ----------------------------------------------------------------------------------------------------
    @property
    def innovation_position(self) -> np.ndarray:
        """The newest measurement's position less the estimate's at its capture time, m, world frame."""
        return np.array(self._innovation_position)

    @property
    def innovation_attitude(self) -> np.ndarray:
        """...and its attitude relative to the estimate's, rotation vector, rad, body frame."""
        return np.array(self._innovation_attitude)

    def fault(self) -> str:
        """Why the measurements cannot be trusted ("" while they can); latched (:meth:`gyros_lost` alone takes
        one back)."""
        return self._fault

    def age(self, now: float) -> float:
        """Time since the capture of the newest fused measurement, s (inf before the first)."""
        return now - self.last_fused_t

    def state(self) -> RigidState | None:
        """The state at the latest :meth:`predict` time (None before the first measurement); the body rate is the
        gyros' less their bias (with the gyros lost: minus the "bias", the rate learnt from the poses, which the
        logged ``gyro_bias_radps`` then is too)."""
        if self._state is None and self.initialized:
            # Without a fresh gyro reading the poses' own rate (noisy, late, but not a made-up zero that would
            # step the attitude loop's damping at every gap), else none.
            omega = self._rate() or self._pose_rate() or (0.0, 0.0, 0.0)
            # One array for the four, handed out as views of its rows (numpy's cost is per call, not per element).
            rows = np.array(self._p + self._v + omega + self._r).reshape(6, 3)
            self._state = RigidState(rows[0], rows[1], rows[3:], rows[2])
        return self._state  # never changed in place: shared

    @property
    def disturbance(self) -> float:
        """Magnitude of the acceleration the model misses, m/s^2 (cheap: read every period)."""
        return math.hypot(*self._d)

    def estimate(self) -> Estimate | None:
        state = self.state()
        if state is None:
            return None
        pp, _, _, vv, _, _ = self._pt
        sigma_theta = math.sqrt(self._pa[0])
        blind = max(0.0, self._t - self.last_fused_t)
        return Estimate(self._t, state, math.sqrt(pp) + self._tilt_drift(blind, sigma_theta), math.sqrt(pp),
                        math.sqrt(vv), sigma_theta, np.array(self._b), np.array(self._d))

    def _tilt_drift(self, tau: float, sigma_theta: float) -> float:
        """Std of the horizontal position error an attitude error makes flown blind for ``tau`` s, m: it accelerates
        the body sideways by g theta. With the gyros integrated throughout, theta(tau) = theta0 - b0 tau + w(tau)
        (the angle and bias errors the last pose left, the gyros' noise), twice integrated: g^2 (tt tau^4 / 4 -
        tb tau^5 / 6 + bb tau^6 / 36 + q_g tau^5 / 20 + q_b tau^7 / 252). Otherwise (gyros stale or lost) the
        attitude's std now, as if it had been so since the last pose: g sigma_theta tau^2 / 2, which from 0.3 s into
        a take-off (the bias barely learnt) said 1 m after 2.6 s blind while the body had drifted 3.5 cm."""
        if self._pa_fused is None or self._lost is not None:
            return 0.5 * GRAVITY * sigma_theta * tau * tau
        tt, tb, bb = self._pa_fused
        t2 = tau * tau
        var = t2 * t2 * (tt / 4.0 - tb * tau / 6.0 + bb * t2 / 36.0 + self._qg * tau / 20.0
                         + self._qb * t2 * tau / 252.0)
        return GRAVITY * math.sqrt(max(var, 0.0))
