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

Innovation health: a measurement farther from the estimate than ``gate_sigma`` standard deviations of its
innovation (and than a floor that covers what the model leaves out) is rejected and counted, never fused; a stream
rejected for ``inconsistent_s`` on end is a fault (:meth:`RigidBodyFilter.fault`): a pose frozen while the gyros
turn, a body swapped for another, a forger's track. A rejected position multiplies the translation covariance by
``rejection_inflation`` (a fading memory): if the model, not the pose, was wrong (a shove, a thrust map far off),
the gate has opened to the poses again after three or four samples, before the fault; a pose metres away stays
out. The attitude is not inflated: the gyros predict it too well for a frozen pose to pass. Through an outage the
covariance grows with the model's noises, so the gate opens again by itself and the failsafe can act on the
uncertainty.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from groundstation.assembly.module import GRAVITY
from groundstation.control.state import RigidState
from groundstation.estimation.measurement import PoseMeasurement
from groundstation.rotations import matrix_to_rotvec, rotvec_to_matrix


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
    """Factor on the translation covariance per rejected position (see the module docstring)."""
    attitude_gate_floor: float = math.radians(1.5)
    """...or this angle, rad, ..."""
    gyro_delay: float = 0.0
    """Age of a gyro reading when the estimator gets it, s (the backend's: :data:`groundstation.backend_kinds`)."""
    gyro_timing: float = 0.02
    """...plus the angle the body turns in this time, s: how far the gyros' and the poses' times may still disagree
    (``gyro_delay`` and the mocap's latency are configured, not measured; a link's delay varies). With 1 deg and
    10 ms, simulated Crazyflie modules saw 51 ms of rejected poses in a take-off (1.4 deg at ~40 deg/s)."""
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
    """Std per axis, m: the translation filter's, plus what an attitude error does to a body flown blind (the
    filter does not carry it: a tilt error theta accelerates the position error by g theta, so ``tau`` s after
    the last pose fused the std grows by g sigma_theta tau^2 / 2)."""
    velocity_sigma: float
    """Std per axis, m/s."""
    attitude_sigma: float
    """Std per axis, rad."""
    gyro_bias: np.ndarray
    """(3,) estimated gyro bias, body frame, rad/s."""
    disturbance: np.ndarray
    """(3,) acceleration the model misses, world frame, m/s^2."""


POSE_RATE_WINDOW_S = 0.05
"""Span of the poses :meth:`RigidBodyFilter.pose_rate` differentiates, s."""
_ZERO = np.zeros(3)
_ZERO.setflags(write=False)
_GRAVITY_VECTOR = np.array([0.0, 0.0, GRAVITY])
_THREE_HALVES = 1.5 * np.eye(3)


def _orthonormal(r: np.ndarray) -> np.ndarray:
    """One Newton step back to a rotation (rounding drifts products of many small rotations off it)."""
    return r @ (_THREE_HALVES - 0.5 * r.T @ r)


class RigidBodyFilter:
    """See the module docstring. Call :meth:`predict` once per control period (it sets the time and the inputs),
    :meth:`correct` with every measurement in capture order, read :meth:`state`, and tell it the command sent
    (:meth:`command`)."""

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
        self._gyro: np.ndarray | None = None
        self._force: np.ndarray | None = None
        self._p = np.zeros(3)
        self._v = np.zeros(3)
        self._d = np.zeros(3)
        self._r = np.eye(3)
        """Attitude at the estimate's time."""
        self._r_gyro = np.eye(3)
        """Attitude ``gyro_delay`` earlier: where the gyros have got to."""
        self._b = np.zeros(3)
        self._pt = [0.0] * 6
        """Translation covariance per axis: pp, pv, pd, vv, vd, dd."""
        self._pa = [0.0] * 3
        """Attitude covariance per axis: theta-theta, theta-bias, bias-bias."""
        self.ground_z: float | None = None
        """Height of the resting assembly's COM, m: when set (:meth:`set_ground`), the estimate stays above it."""
        self._history: deque[list] = deque()
        """[t, p, v, d, R, a] of past estimates, oldest first; ``a``: the acceleration of the step that ended
        there."""
        self._a = np.zeros(3)
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
        """Capture time of the newest fused measurement, s."""
        self._last_pose: PoseMeasurement | None = None
        """The measurement before (to tell a frozen stream)."""
        self._fused_poses: deque[PoseMeasurement] = deque()
        """The fused measurements of the last ``POSE_RATE_WINDOW_S`` (:meth:`pose_rate`)."""
        self._rejecting_since: float | None = None
        """Capture time of the first measurement of the current run of rejections."""
        self._fault = ""
        self.innovation_position = _ZERO
        """The newest measurement's position less the estimate's at its capture time, m, world frame."""
        self.innovation_attitude = _ZERO
        """...and its attitude relative to the estimate's, rotation vector, rad, body frame."""

    # -- inputs -----------------------------------------------------------------------------------------------------
    def predict(self, t: float, gyro: np.ndarray | None) -> None:
        """Advance the estimate to ``t`` (s), turning it at ``gyro``, the body rate the modules report now (rad/s,
        body frame: the newest reading is the best one for the time since the last call; None: none streamed,
        the attitude is held between measurements), under the last :meth:`command`."""
        # A reading that is not a rate (a module's NaN) is no reading: the attitude is held, the mocap corrects it.
        self._gyro = None if gyro is None or len(gyro) != 3 or not all(map(math.isfinite, gyro)) \
            else np.asarray(gyro, float)
        if self.initialized and self._t is not None and t > self._t:
            self._propagate(t - self._t)
            self._t = t
            self._remember()
        elif self._t is None or t > self._t:
            self._t = t

    def set_ground(self, z: float) -> None:
        """From now on the estimate stays above ``z``, the resting COM height, m. For flying blind: with mocap the
        poses say where the ground is; without, a landing estimate that sank through it would ask for the thrust
        that stops its descent and lift the landed assembly off again (measured: 24 cm up, then dropped)."""
        self.ground_z = z

    def command(self, force: np.ndarray | None) -> None:
        """The body force of the command just sent, N, body frame (the allocation's force rows times the rotor
        inputs; None: motors off); it acts until the next call."""
        self._force = None if force is None else np.asarray(force, float)

    def _propagate(self, dt: float) -> None:
        # New arrays, never changed in place: the history and the states handed out share them.
        # motors off (no force): resting (the ground holds it) or carried
        a = self._d if self._force is None else self._r @ (self._force / self.mass) - _GRAVITY_VECTOR + self._d
        self._a = a
        h = 0.5 * dt * dt
        self._p = self._p + self._v * dt + a * h
        self._v = self._v + a * dt
        if self.ground_z is not None and self._p[2] < self.ground_z:  # the ground holds it
            self._p = np.array([self._p[0], self._p[1], self.ground_z])
            self._v = np.array([self._v[0], self._v[1], max(float(self._v[2]), 0.0)])
        if self._gyro is not None:
            rate = self._gyro - self._b
            self._r_gyro = self._r_gyro @ rotvec_to_matrix(rate * dt)
            delay = self.settings.gyro_delay
            self._r = self._r_gyro @ rotvec_to_matrix(rate * delay) if delay > 0.0 else self._r_gyro
        pp, pv, pd, vv, vd, dd = self._pt
        r00, r01, r02 = pp + dt * pv + h * pd, pv + dt * vv + h * vd, pd + dt * vd + h * dd
        r11, r12 = vv + dt * vd, vd + dt * dd
        qa = self._qa
        self._pt = [r00 + dt * r01 + h * r02 + qa * dt ** 3 / 3.0, r01 + dt * r02 + qa * h, r02,
                    r11 + dt * r12 + qa * dt, r12, dd + self._qd * dt]
        tt, tb, bb = self._pa
        self._pa = [tt - 2.0 * dt * tb + dt * dt * bb + self._qg * dt, tb - dt * bb, bb + self._qb * dt]

    def _remember(self) -> None:
        hist = self._history
        hist.append([self._t, self._p, self._v, self._d, self._r, self._a])
        while len(hist) > 2 and hist[1][0] < self._t - self.settings.history_s:
            hist.popleft()

    # -- measurements -----------------------------------------------------------------------------------------------
    def correct(self, m: PoseMeasurement) -> bool:
        """Fuse one measurement (True), or reject it (False: counted, :attr:`last_rejection` says why). The first
        one starts the estimate."""
        if not (math.isfinite(m.t) and all(map(math.isfinite, m.position)) and np.isfinite(m.rotation).all()):
            return self._reject(m.t, "not finite")
        if not self.initialized:
            self._start(m)
            return True
        last, self._last_pose = self._last_pose, m
        if last is not None and m.t > last.t and np.array_equal(m.position, last.position) \
                and np.array_equal(m.rotation, last.rotation):
            # A camera system measures with noise: the same pose twice to the last bit, newly timed, is a stream
            # that froze (a lost body held, a stuck bridge), whatever the body does meanwhile.
            return self._reject(m.t, "the same pose again, to the last bit: a frozen stream")
        at = self._at(m.t)
        if at is None:  # older than anything the estimate remembers: news of no use, not a wrong pose
            self.late += 1
            return False
        hist = self._history
        tm, p_m, v_m, d_m, r_m, _ = hist[at]
        a = hist[at + 1][5] if at + 1 < len(hist) else self._a  # what the estimate's step from there assumed
        tau = m.t - tm
        p_m, v_m = p_m + v_m * tau + a * (0.5 * tau * tau), v_m + a * tau  # the estimate at the capture time
        s = self.settings
        dp = m.position - p_m
        s_p = self._pt[0] + self._rp
        miss = float(math.sqrt(dp @ dp))
        self.innovation_position, self.innovation_attitude = dp, _ZERO
        if miss > max(s.gate_sigma * math.sqrt(s_p), s.position_gate_floor):
            self._pt = [c * s.rejection_inflation for c in self._pt]
            return self._reject(m.t, f"position {miss * 100:.1f} cm off the estimate")
        if self._gyro is not None and m.t > tm:
            r_m = r_m @ rotvec_to_matrix((self._gyro - self._b) * (m.t - tm))
        dth = matrix_to_rotvec(r_m.T @ m.rotation)
        s_a = self._pa[0] + self._ra
        off = float(math.sqrt(dth @ dth))
        rate = float(math.sqrt(self._gyro @ self._gyro)) if self._gyro is not None else 0.0
        self.innovation_attitude = dth
        if off > max(s.gate_sigma * math.sqrt(s_a), s.attitude_gate_floor + rate * s.gyro_timing):
            return self._reject(m.t, f"attitude {math.degrees(off):.1f} deg off the gyros' prediction")
        cp, cv, cd, ct = self._fuse(m.t, dp, s_p, dth, s_a)
        if m.t > tm:
            # The corrected estimate at the capture time joins the history: the next pose captured before the next
            # entry is compared with it, not with the uncorrected one before (after a pause between periods, a
            # burst of poses all fell between two entries and each was compared with the same stale estimate).
            hist.insert(at + 1, [m.t, p_m + cp, v_m + cv, d_m + cd, r_m @ rotvec_to_matrix(ct), a])
        self._rejecting_since = None
        self.fused += 1
        self.last_fused_t = max(self.last_fused_t, m.t)
        self._keep_fused(m)
        return True

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

    def _start(self, m: PoseMeasurement) -> None:
        s = self.settings
        self._p, self._v, self._d = np.array(m.position, float), np.zeros(3), np.zeros(3)
        self._r, self._b = np.array(m.rotation, float), np.zeros(3)
        self._r_gyro = self._r.copy()
        self._pt = [self._rp, 0.0, 0.0, s.initial_velocity ** 2, 0.0, s.initial_disturbance ** 2]
        self._pa = [self._ra, 0.0, s.initial_bias ** 2]
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
        self._fused_poses.clear()
        self._keep_fused(m)

    def _at(self, t: float) -> int | None:
        """Index of the newest history entry at or before ``t`` (None: ``t`` is older than the history)."""
        hist = self._history
        for i in range(len(hist) - 1, -1, -1):
            if hist[i][0] <= t:
                return i
        return None

    def _fuse(self, tm: float, dp: np.ndarray, s_p: float, dth: np.ndarray, s_a: float) -> tuple:
        """Correct the estimate (now, and the history after ``tm``) by the innovations at ``tm``; returns the
        correction there (position, velocity, disturbance, attitude rotation vector)."""
        pp, pv, pd, vv, vd, dd = self._pt
        kp, kv, kd = pp / s_p, pv / s_p, pd / s_p
        cp, cv, cd = kp * dp, kv * dp, kd * dp
        tt, tb, bb = self._pa
        kt, kb = tt / s_a, tb / s_a
        ct, cb = kt * dth, kb * dth
        # The correction made at tm, carried along every estimate since. The attitude's is one rotation for all:
        # what the bias correction adds over the few ms of history is below 1e-6 rad (and the rotation costs).
        dr = rotvec_to_matrix(ct - cb * max(self._t - tm, 0.0))
        for entry in reversed(self._history):
            tau = entry[0] - tm
            if tau < 0.0:
                break
            entry[1] = entry[1] + cp + cv * tau + cd * (0.5 * tau * tau)
            entry[2] = entry[2] + cv + cd * tau
            entry[3] = entry[3] + cd
            entry[4] = entry[4] @ dr
        tau = max(self._t - tm, 0.0)
        self._p = self._p + cp + cv * tau + cd * (0.5 * tau * tau)
        self._v = self._v + cv + cd * tau
        self._d = self._d + cd
        self._r_gyro = _orthonormal(self._r_gyro @ dr)
        self._r = _orthonormal(self._r @ dr)
        self._b = self._b + cb
        self._pt = [pp - pp * kp, pv - pv * kp, pd - pd * kp, vv - pv * kv, vd - pd * kv, dd - pd * kd]
        self._pa = [tt - tt * kt, tb - tb * kt, bb - tb * kb]
        return cp, cv, cd, ct

    def _reject(self, t: float, why: str) -> bool:
        self.rejected += 1
        self.last_rejection = why
        if self._rejecting_since is None:
            self._rejecting_since = t
        elif t - self._rejecting_since >= self.settings.inconsistent_s and not self._fault:
            self._fault = (f"every pose rejected for {(t - self._rejecting_since) * 1e3:.0f} ms (last: {why}): "
                           f"frozen, swapped, forged or broken")
        return False

    # -- outputs ----------------------------------------------------------------------------------------------------
    def fault(self) -> str:
        """Why the measurements cannot be trusted ("" while they can); latched."""
        return self._fault

    def age(self, now: float) -> float:
        """Time since the capture of the newest fused measurement, s (inf before the first)."""
        return now - self.last_fused_t

    def state(self) -> RigidState | None:
        """The state at the latest :meth:`predict` time (None before the first measurement); the body rate is the
        gyros' less their bias."""
        if not self.initialized:
            return None
        omega = self._gyro - self._b if self._gyro is not None else np.zeros(3)
        return RigidState(self._p, self._v, self._r, omega)  # never changed in place: shared

    def estimate(self) -> Estimate | None:
        state = self.state()
        if state is None:
            return None
        pp, _, _, vv, _, _ = self._pt
        sigma_theta = math.sqrt(self._pa[0])
        blind = max(0.0, self._t - self.last_fused_t)
        return Estimate(self._t, state, math.sqrt(pp) + 0.5 * GRAVITY * sigma_theta * blind * blind, math.sqrt(vv),
                        sigma_theta, self._b, self._d)
