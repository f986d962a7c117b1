"""PyBullet simulation of an assembly, implementing the Backend protocol (paper §VI-A).

One rigid multibody per assembly: total mass, the assembly's inertia tensor (about the COM, set explicitly
rather than derived from the collision shapes), one box collision shape per module for ground contact. Rotor
thrusts ``c_f u`` along each rotor axis at each rotor position and drag torques ``(-1)^q c_m u`` sum, on a rigid
body, to exactly the wrench ``A u`` about the COM, so each physics step applies one force at the COM and one
torque (two calls instead of 4n; the n = 60 assembly has 240 rotors). Rotor inputs pass a first-order lag and
the ``[0, u_max]`` bounds. The measured state can carry Gaussian noise and a latency.

Time is advanced explicitly with :meth:`PyBulletBackend.advance_to` (lockstep: as fast as the CPU allows);
with ``realtime=True`` it is paced to the wall clock.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from groundstation.assembly.assembly import Assembly
from groundstation.backends.base import PreflightReport, Telemetry
from groundstation.control.state import RigidState
from groundstation.design.task import GRAVITY


@dataclass(frozen=True)
class SimConfig:
    physics_hz: float = 240.0
    """Physics step rate, Hz."""
    motor_time_constant: float = 0.02
    """First-order lag of every rotor input, s."""
    position_noise: float = 0.0
    """Std of measured position noise, m."""
    attitude_noise: float = 0.0
    """Std of measured attitude noise (rotation vector), rad."""
    latency: float = 0.0
    """Delay of the measured state, s."""
    realtime: bool = False
    """Pace the simulation to the wall clock."""
    gui: bool = False
    """Open PyBullet's GUI (needs a display)."""
    seed: int = 0


def _quat_to_matrix(q) -> np.ndarray:
    return np.array(pb.getMatrixFromQuaternion(q)).reshape(3, 3)


def _matrix_to_quat(r: np.ndarray) -> tuple[float, float, float, float]:
    """Quaternion [x, y, z, w] of a rotation matrix (Shepperd's method, robust for all angles)."""
    t = np.trace(r)
    if t > 0:
        s = 2.0 * np.sqrt(t + 1.0)
        w, x, y, z = 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
        q = np.zeros(4)
        q[i] = 0.25 * s
        q[j] = (r[j, i] + r[i, j]) / s
        q[k] = (r[k, i] + r[i, k]) / s
        q[3] = (r[k, j] - r[j, k]) / s
        x, y, z, w = q
    return (float(x), float(y), float(z), float(w))


def resting_height(assembly: Assembly) -> float:
    """COM height at which the lowest module corner touches the ground (body frame level), m."""
    hx, hy, hz = assembly.params.frame_half_extents
    corners = np.array([[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    lowest = min(float(np.min((p + corners @ r.T)[:, 2]))
                 for p, r in zip(assembly.module_positions, assembly.module_rotations, strict=True))
    return -lowest


class PyBulletBackend:
    """Physics simulation of one assembly behind the Backend protocol."""

    def __init__(self, assembly: Assembly, config: SimConfig | None = None,
                 start_position: tuple[float, float, float] | None = None) -> None:
        self.assembly = assembly
        self.config = config or SimConfig()
        self._rng = np.random.default_rng(self.config.seed)
        ground = (0.0, 0.0, resting_height(assembly))
        self.start_position = np.array(start_position if start_position is not None else ground, dtype=float)
        self._client: int | None = None
        self._body = -1
        self._u_cmd = np.zeros(4 * assembly.n)
        self._u = np.zeros(4 * assembly.n)
        self._armed = False
        self._t = 0.0
        self._dt = 1.0 / self.config.physics_hz
        tau = self.config.motor_time_constant
        self._lag = 1.0 - np.exp(-self._dt / tau) if tau > 0 else 1.0  # fraction of the step response per step
        self._history: deque[tuple[float, RigidState]] = deque()
        self._wall0 = 0.0
        self._r_if = np.eye(3)
        self._state = RigidState()

    # -- Backend protocol ---------------------------------------------------------------------------------------
    def connect(self) -> None:
        if self._client is not None:
            return
        self._client = pb.connect(pb.GUI if self.config.gui else pb.DIRECT)
        c = self._client
        pb.setGravity(0, 0, -GRAVITY, physicsClientId=c)
        pb.setTimeStep(self._dt, physicsClientId=c)
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=c)
        pb.createMultiBody(0, plane, physicsClientId=c)
        a = self.assembly
        n = a.n
        quats = [_matrix_to_quat(r) for r in a.module_rotations]
        col = pb.createCollisionShapeArray([pb.GEOM_BOX] * n, halfExtents=[a.params.frame_half_extents] * n,
                                           collisionFramePositions=a.module_positions.tolist(),
                                           collisionFrameOrientations=quats, physicsClientId=c)
        vis = -1
        if self.config.gui:
            vis = pb.createVisualShapeArray([pb.GEOM_BOX] * n, halfExtents=[a.params.frame_half_extents] * n,
                                            visualFramePositions=a.module_positions.tolist(),
                                            visualFrameOrientations=quats, physicsClientId=c)
        # Principal axes of the inertia tensor: Bullet wants a diagonal inertia in a rotated inertial frame.
        lam, vecs = np.linalg.eigh(a.inertia)
        if np.linalg.det(vecs) < 0:
            vecs[:, 0] = -vecs[:, 0]
        self._r_if = vecs
        self._body = pb.createMultiBody(a.mass, col, vis, basePosition=self.start_position.tolist(),
                                        baseOrientation=[0, 0, 0, 1], baseInertialFramePosition=[0, 0, 0],
                                        baseInertialFrameOrientation=_matrix_to_quat(vecs), physicsClientId=c)
        pb.changeDynamics(self._body, -1, localInertiaDiagonal=lam.tolist(), linearDamping=0.0,
                          angularDamping=0.0, physicsClientId=c)
        self._t = 0.0
        self._wall0 = time.perf_counter()
        self._history.clear()
        self._record()

    def preflight(self) -> PreflightReport:
        issues = []
        if self._client is None:
            issues.append("not connected")
        return PreflightReport(not issues, tuple(issues))

    def arm(self) -> None:
        self._armed = True

    def send(self, u: np.ndarray) -> None:
        """Command rotor inputs (4n,), rad^2/s^2; bounded to [0, u_max]; ignored unless armed."""
        u = np.asarray(u, dtype=float)
        if u.shape != self._u_cmd.shape:
            raise ValueError(f"expected {self._u_cmd.shape[0]} rotor inputs, got {u.shape}")
        if not self._armed:
            self._u_cmd = np.zeros_like(u)
            return
        # NaN commands a stopped rotor; bounds are enforced here, at the backend's edge, whatever the caller did.
        self._u_cmd = np.clip(np.where(np.isfinite(u), u, 0.0), 0.0, self.assembly.params.u_max)

    def telemetry(self) -> Telemetry:
        return Telemetry(stamp=self._t, link_ok=self._client is not None, motors=self._u.copy())

    def emergency_stop(self) -> None:
        self._armed = False
        self._u_cmd[:] = 0.0
        self._u[:] = 0.0

    def close(self) -> None:
        if self._client is not None:
            pb.disconnect(physicsClientId=self._client)
            self._client = None

    def __enter__(self) -> PyBulletBackend:
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.emergency_stop()
        self.close()

    # -- simulation ---------------------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated time, s."""
        return self._t

    def advance_to(self, t: float) -> None:
        """Step physics until simulated time reaches ``t`` (whole physics steps)."""
        c = self._client
        a_mat = self.assembly.allocation
        while self._t + 0.5 * self._dt <= t:
            self._u += self._lag * (self._u_cmd - self._u)
            w = a_mat @ self._u
            r = self._state.rotation
            pb.applyExternalForce(self._body, -1, (r @ w[:3]).tolist(), self._state.position.tolist(), pb.WORLD_FRAME,
                                  physicsClientId=c)
            pb.applyExternalTorque(self._body, -1, (r @ w[3:]).tolist(), pb.WORLD_FRAME, physicsClientId=c)
            pb.stepSimulation(physicsClientId=c)
            self._t += self._dt
            self._record()
            if self.config.realtime:
                lag = self._t - (time.perf_counter() - self._wall0)
                if lag > 0:
                    time.sleep(lag)

    def true_state(self) -> RigidState:
        """The physics state now, without noise or latency."""
        return self._state

    def _query_state(self) -> RigidState:
        c = self._client
        pos, q = pb.getBasePositionAndOrientation(self._body, physicsClientId=c)
        vel, omega_w = pb.getBaseVelocity(self._body, physicsClientId=c)
        r = _quat_to_matrix(q) @ self._r_if.T
        return RigidState(np.array(pos), np.array(vel), r, r.T @ np.array(omega_w))

    def measured_state(self) -> RigidState:
        """The state as a sensor would report it: delayed by ``latency`` and with noise."""
        target = self._t - self.config.latency
        while len(self._history) > 1 and self._history[1][0] <= target + 1e-12:
            self._history.popleft()
        s = self._history[0][1]
        cfg = self.config
        if cfg.position_noise == 0 and cfg.attitude_noise == 0:
            return s
        dr = _rotvec_to_matrix(self._rng.normal(0, cfg.attitude_noise, 3))
        return RigidState(s.position + self._rng.normal(0, cfg.position_noise, 3), s.velocity, s.rotation @ dr,
                          s.omega)

    def _record(self) -> None:
        self._state = self._query_state()
        self._history.append((self._t, self._state))
        horizon = self.config.latency + 2 * self._dt
        while self._history and self._history[0][0] < self._t - horizon - 1e-12:
            self._history.popleft()


def _rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    th = np.linalg.norm(v)
    if th < 1e-12:
        return np.eye(3)
    k = v / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * kx + (1 - np.cos(th)) * kx @ kx
