"""Geometric control on SE(3) (Lee et al.; paper §V), as pure functions over frozen data.

    F'_d = K_P e_p + K_D e_v + m a_d + m g e3,      e_p = p_d - p, e_v = v_d - v   (leaning at most max_tilt)
    tau_d = -K_R e_R - K_w e_w + w x J w,          e_R = 1/2 (R_d^T R - R^T R_d)^v, e_w = w - R^T R_d w_d
    W_d = [R^T F'_d; tau_d]                        (body frame)

Gains are given as bandwidths and damping ratios and scaled by the assembly's own mass and inertia
(K_P = m w_p^2, K_D = 2 zeta m w_p, K_R = diag(J) w_R^2, K_w = 2 zeta diag(J) w_R), so one gain set serves
assemblies of 2 and of 60 modules.

Assemblies that are not fully actuated cannot follow an arbitrary attitude target. For those, as the paper
does, the desired attitude is adapted to ``F'_d`` so the force becomes producible:

* one body force direction ``n`` missing (the two-module V: no force along the hinge axis): one Euler angle
  of the ZYX target is freed, pitch when ``n`` is closer to the body x axis and roll otherwise, and solved in
  closed form so that ``(R_d n) . F'_d = 0``; the other two (e.g. roll held at 0 or -5 degrees, and yaw) are
  tracked exactly;
* thrust along one body axis only (flat assemblies): the classic construction, that axis along ``F'_d``
  with the yaw target kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from groundstation.assembly.module import GRAVITY
from groundstation.control.model import ControlModel
from groundstation.control.state import RigidState, Setpoint
from groundstation.control.trajectory import euler_zyx, roll_pitch_yaw

E3 = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Gains:
    """Controller gains as bandwidths (Hz) and damping ratios."""

    position_hz: float = 0.8
    position_zeta: float = 1.0
    attitude_hz: float = 4.0
    attitude_zeta: float = 0.9
    max_tilt_deg: float = 30.0
    """The desired force leans at most this far from vertical, its vertical part kept (altitude first): a shove or
    a reference far off asks for a bounded lean, deg. Unbounded, a 1 m/s shove asked the V for a 45 deg lean and
    tipped it 52 deg. The README's figure-8 leans 4.3 deg."""


@dataclass(frozen=True, eq=False)
class ControlOutput:
    wrench: np.ndarray
    """(6,) desired body wrench [F; tau], N and N m."""
    force_world: np.ndarray
    """F'_d, world frame, N."""
    rotation_desired: np.ndarray
    """R_d actually tracked (after adaptation)."""
    attitude_error: np.ndarray
    """e_R, rad (small-angle)."""


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross costs ~50x more for a single pair, on the control hot path)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def vee(m: np.ndarray) -> np.ndarray:
    return np.array([m[2, 1], m[0, 2], m[1, 0]])


def _solve_angle(a: float, b: float, c: float) -> float:
    """Smallest |x| with a cos x + b sin x + c = 0 (or the x minimizing the residual when none exists)."""
    r = math.hypot(a, b)
    phi = math.atan2(b, a)
    if r < 1e-12:
        return 0.0
    k = min(1.0, max(-1.0, -c / r))
    cands = [phi + math.acos(k), phi - math.acos(k)]
    cands = [(x + math.pi) % (2 * math.pi) - math.pi for x in cands]
    return float(min(cands, key=abs))


def _frees_pitch(n: np.ndarray) -> bool:
    """A missing body force direction ``n`` closer to the body x axis than to y frees pitch (else roll)."""
    return abs(n[0]) >= abs(n[1])


def free_angles(model: ControlModel) -> tuple[str, ...]:
    """The ZYX angles ("roll", "pitch") that :func:`adapt_attitude` sets from the force instead of taking them from
    the target: the ones the assembly does not track (none when fully actuated)."""
    if model.actuation == "force-deficient-1":
        return ("pitch",) if _frees_pitch(model.null_force[0]) else ("roll",)
    if model.actuation == "force-deficient-2":
        return ("roll", "pitch")
    return ()


def adapt_attitude(target: np.ndarray, force_world: np.ndarray, model: ControlModel) -> np.ndarray:
    """Desired attitude for an under-actuated assembly (see module docstring); ``target`` when fully actuated."""
    if model.actuation == "force-deficient-1":
        n = model.null_force[0]
        roll, pitch, yaw = roll_pitch_yaw(target)
        rz = euler_zyx(0.0, 0.0, yaw)
        f = rz.T @ force_world
        if _frees_pitch(n):  # free pitch, hold roll: (R_y(theta) R_x(roll) n) . f = 0
            m = euler_zyx(roll, 0.0, 0.0) @ n
            a = m[0] * f[0] + m[2] * f[2]
            b = m[2] * f[0] - m[0] * f[2]
            theta = _solve_angle(a, b, m[1] * f[1])
            return euler_zyx(roll, theta, yaw)
        # free roll, hold pitch: (R_y(pitch) R_x(phi) n) . f = 0, i.e. (R_x(phi) n) . g = 0 with g = R_y^T f
        g = euler_zyx(0.0, pitch, 0.0).T @ f
        a = n[1] * g[1] + n[2] * g[2]
        b = n[1] * g[2] - n[2] * g[1]
        phi = _solve_angle(a, b, n[0] * g[0])
        return euler_zyx(phi, pitch, yaw)
    if model.actuation == "force-deficient-2":
        # The producible force is along d = n0 x n1 (body); align R_d d with F'_d, keep the yaw target.
        d = np.cross(model.null_force[0], model.null_force[1])
        d = d / np.linalg.norm(d) * (1.0 if d @ (model.allocation[:3].sum(axis=1)) >= 0 else -1.0)
        b3 = force_world / max(np.linalg.norm(force_world), 1e-9)
        yaw = roll_pitch_yaw(target)[2]
        b1c = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        b2 = np.cross(b3, b1c)
        b2 /= max(np.linalg.norm(b2), 1e-9)
        rc = np.column_stack([np.cross(b2, b3), b2, b3])
        return rc @ _rotation_between(d, E3)
    return target


def reference_attitude(sp: Setpoint, model: ControlModel) -> np.ndarray:
    """The attitude the controller targets while ``sp`` is followed exactly: :func:`adapt_attitude` of the
    reference's own force (``m a_d + m g e3``). Its rate is fed forward (the flight differentiates it from one
    period to the next): the V's freed pitch follows the force, swinging +-4.3 deg at up to 0.12 rad/s on the
    README's figure-8, and not fed forward, the attitude loop lagged it by ``2 zeta w / w_R`` (0.5 deg: the dry
    run's orientation error p95 was 1.0 deg with it, 0.74 without). The feedback part of the force (noise) is left
    out: its rate would chatter."""
    m = model.mass
    return adapt_attitude(sp.rotation, m * sp.acceleration + (m * GRAVITY) * E3, model)


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector a to unit vector b."""
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def _lean_limited(force: np.ndarray, max_tilt: float) -> np.ndarray:
    """``force`` with its horizontal part shortened to lean at most ``max_tilt`` rad from vertical, its vertical part
    kept (none when the force points down: level)."""
    horizontal = math.hypot(force[0], force[1])
    most = math.tan(max_tilt) * max(float(force[2]), 0.0)
    if horizontal <= most:
        return force
    k = most / horizontal
    return np.array([force[0] * k, force[1] * k, force[2]])


def delay_limited(gains: Gains, delay_s: float, bound_s: float) -> Gains:
    """``gains`` for a loop delayed ``delay_s`` (the modules' round trip and a period), when they were meant for at
    most ``bound_s``: beyond it the attitude and position bandwidths are both cut by the square of the ratio, so the
    attitude loop stays the faster of the two (cut alone, it fell below the position loop at a 37 ms round trip).
    Holding the phase the attitude loop loses at its crossover (bandwidth times delay) to its value at the bound, a
    proportional cut, was not enough where the bound itself is marginal. Measured in SITL, landings (3 s) on links
    slowed in flight, max tilt: PX4 modules, 8 ms each way 66 deg uncut, 38 deg with a proportional cut of the
    attitude loop, 8 deg squared, 14 deg squared on both loops; 12 ms each way tipped past 75 deg uncut, 1-3 deg cut
    (either way); 22 ms each way 22 deg with the attitude loop cut, 4 deg with both. A delay that is not finite
    leaves the gains: the flight stops on it (``link_stop_latency_s``) before it flies a period on them."""
    if not delay_s > bound_s or not math.isfinite(delay_s):
        return gains
    k = (bound_s / delay_s) ** 2
    return replace(gains, attitude_hz=gains.attitude_hz * k, position_hz=gains.position_hz * k)


def control(state: RigidState, sp: Setpoint, model: ControlModel, gains: Gains) -> ControlOutput:
    """One step of the geometric controller: desired body wrench for the current state and setpoint."""
    m = model.mass
    wp = 2 * np.pi * gains.position_hz
    wr = 2 * np.pi * gains.attitude_hz
    jd = np.diag(model.inertia)
    force = _lean_limited((m * wp * wp) * (sp.position - state.position) + (2 * gains.position_zeta * m * wp) * (
        sp.velocity - state.velocity) + m * sp.acceleration + m * GRAVITY * E3, math.radians(gains.max_tilt_deg))
    r = state.rotation
    rd = adapt_attitude(sp.rotation, force, model)
    e_r = 0.5 * vee(rd.T @ r - r.T @ rd)
    e_w = state.omega - r.T @ rd @ sp.omega
    w = state.omega
    tau = -(jd * wr * wr) * e_r - (2 * gains.attitude_zeta * wr * jd) * e_w + cross(w, model.inertia @ w)
    return ControlOutput(np.concatenate([r.T @ force, tau]), force, rd, e_r)
