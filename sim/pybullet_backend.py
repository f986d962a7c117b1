"""PyBullet simulation of an assembly, implementing the Backend protocol (paper §VI-A).

One rigid multibody per assembly: total mass, the assembly's inertia tensor (about the COM, set explicitly
rather than derived from the collision shapes), one box collision shape per module for ground contact. Rotor
thrusts ``c_f u`` along each rotor axis at each rotor position and drag torques ``(-1)^q c_m u`` sum, on a rigid
body, to exactly the wrench ``A u`` about the COM, so each physics step applies one force at the COM and one
torque (two calls instead of 4n; the n = 60 assembly has 240 rotors). Rotor inputs pass a first-order lag and
the ``[0, u_max]`` bounds. Sensors as real ones are: motion capture at its own rate with noise and a latency
(:class:`~sim.mocap_sensor.MocapSensor`), gyros with noise, a constant bias and a delay.

Time is advanced explicitly with :meth:`PyBulletBackend.advance_to` (lockstep: as fast as the CPU allows);
with ``realtime=True`` it is paced to the wall clock.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from sim.quiet import quiet_stderr

with quiet_stderr():  # pybullet prints its build date on stderr at import: noise in front of operators
    import pybullet as pb

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.module import GRAVITY
from groundstation.backends.base import BackendBase, PreflightReport, Telemetry, applied_command
from groundstation.backends.section import SIM_GYRO_DELAY, SIM_MOTOR_TIME_CONSTANT, SIM_PHYSICS_HZ
from groundstation.control.state import RigidState
from groundstation.estimation.measurement import PoseMeasurement
from groundstation.rotations import matrix_to_quat, quat_to_matrix
from sim.mocap_sensor import MocapSensor


@dataclass(frozen=True)
class SimConfig:
    physics_hz: float = SIM_PHYSICS_HZ
    """Physics step rate, Hz."""
    motor_time_constant: float = SIM_MOTOR_TIME_CONSTANT
    """First-order lag of every rotor input, s."""
    mocap_rate_hz: float = 100.0
    """Motion capture samples per second of simulated time (:meth:`PyBulletBackend.mocap_samples`), Hz; 0: none
    (the ``fly`` dry run's virtual mocap measures instead)."""
    position_noise: float = 0.0
    """Std of the mocap position noise per axis, m."""
    attitude_noise: float = 0.0
    """Std of the mocap attitude noise (rotation vector, per axis), rad."""
    latency: float = 0.0
    """Mocap latency from capture to delivery, s."""
    gyro_noise: float = 0.005
    """Std of the gyro rate in the telemetry, per reading, rad/s (a BMI088 at 250 Hz: ~0.004)."""
    gyro_bias: float = 0.005
    """Std of each gyro axis' constant bias (drawn once from ``seed``), rad/s (a BMI088 after calibration at
    rest: a few mrad/s)."""
    gyro_delay: float = SIM_GYRO_DELAY
    """Age of the gyro rate in the telemetry, s (a Crazyflie's rides on the state packet that echoes a command:
    one link round trip, ~4 ms)."""
    realtime: bool = False
    """Pace the simulation to the wall clock."""
    gui: bool = False
    """Open PyBullet's GUI (needs a display)."""
    seed: int = 0


GYRO_FULL_SCALE = math.radians(2000.0)
"""A Crazyflie's BMI088 gyro range, rad/s (what a failed one reads stuck at)."""


class PyBulletBackend(BackendBase):
    """Physics simulation of one assembly behind the Backend protocol."""

    def __init__(self, assembly: Assembly, config: SimConfig | None = None,
                 start_position: tuple[float, float, float] | None = None, observers=()) -> None:
        self.assembly = assembly
        self.config = config or SimConfig()
        self._rng = np.random.default_rng(self.config.seed)
        c = self.config
        self._gyro_bias = self._rng.normal(0.0, c.gyro_bias, 3)
        self._mocap = MocapSensor(c.mocap_rate_hz, c.position_noise, c.attitude_noise, c.latency, self._rng)
        self._mocap_out: list[PoseMeasurement] = []
        ground = (0.0, 0.0, assembly.resting_height)
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
        self.observers = list(observers)
        """Callables ``(t, true_state)`` run after every physics step (e.g. a virtual mocap)."""
        self.link_ok = True
        """Set False to inject a link loss (the flight must stop the motors)."""
        self.failed_gyro: int | None = None
        """Set to a module's index to inject a failed IMU: its gyro reads full scale about the module's x axis."""
        self.stuck_gyros: float | None = None
        """Every gyro reads this rate about each body axis, rad/s, unchanging (NaN: not a number)."""
        self.flipped_gyros = False
        """Every gyro reads the body rate with its sign flipped (each agreeing with the others)."""
        self.push: tuple[float, float, float] | None = None
        """A force on the body's centre, world frame, N (fault injection: a shove, a gust)."""
        self._tie: int | None = None

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
        quats = [matrix_to_quat(r) for r in a.module_rotations]
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
                                        baseInertialFrameOrientation=matrix_to_quat(vecs), physicsClientId=c)
        pb.changeDynamics(self._body, -1, localInertiaDiagonal=lam.tolist(), linearDamping=0.0,
                          angularDamping=0.0, physicsClientId=c)
        self._t = 0.0
        self._tie = None
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
        self._u_cmd = applied_command(u, self._u_cmd.size, self._armed, self.assembly.params.u_max)

    def telemetry(self) -> Telemetry:
        gyro = self.gyro_readings(1)[0]
        rates = np.tile(gyro, (self.assembly.n, 1))  # one rigid body: every module measures its rate
        if self.failed_gyro is not None:
            rates[self.failed_gyro] = self.assembly.module_rotations[self.failed_gyro] @ (GYRO_FULL_SCALE, 0.0, 0.0)
            gyro = rates.mean(axis=0)
        if self.stuck_gyros is not None:
            rates[:] = self.stuck_gyros
            gyro = rates.mean(axis=0)
        if self.flipped_gyros:
            rates, gyro = -rates, -gyro
        return Telemetry(stamp=self._t, link_ok=self._client is not None and self.link_ok, motors=self._u.copy(),
                         gyro=gyro, module_gyros=rates)

    @property
    def rotor_inputs(self) -> np.ndarray:
        """The rotor inputs the physics applies now (after the motor lag), (4n,) rad^2/s^2; a view: do not keep."""
        return self._u

    def gyro_readings(self, count: int) -> np.ndarray:
        """``count`` gyros' readings of the body rate now, (count, 3) rad/s in the body frame: the rate
        ``gyro_delay`` s ago, the bias, and noise of each gyro's own."""
        return self._delayed(self.config.gyro_delay).omega + self._gyro_bias + self._rng.normal(
            0.0, self.config.gyro_noise, (count, 3))

    def disarm(self) -> None:
        """Zero command, disarmed: the rotors spin down through their lag."""
        self._armed = False
        self._u_cmd[:] = 0.0

    def emergency_stop(self) -> None:
        """Rotors stopped at once."""
        self._armed = False
        self._u_cmd[:] = 0.0
        self._u[:] = 0.0

    def close(self) -> None:
        if self._client is not None:
            pb.disconnect(physicsClientId=self._client)
            self._client = None


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
            if self.push is not None:
                pb.applyExternalForce(self._body, -1, list(self.push), self._state.position.tolist(), pb.WORLD_FRAME,
                                      physicsClientId=c)
            pb.stepSimulation(physicsClientId=c)
            self._t += self._dt
            self._record()
            self._mocap_out += self._mocap.observe(self._t, self._state)
            for observe in self.observers:
                observe(self._t, self._state)
            if self.config.realtime:
                lag = self._t - (time.perf_counter() - self._wall0)
                if lag > 0:
                    time.sleep(lag)

    def tie_down(self) -> None:
        """Fix the body to the world where it is now, as a forgotten tie-down would (a fault drill): physics goes on,
        the rotors push against the constraint."""
        if self._tie is None:
            c = self._client
            pos, q = pb.getBasePositionAndOrientation(self._body, physicsClientId=c)
            self._tie = pb.createConstraint(self._body, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0], [0, 0, 0], pos,
                                            childFrameOrientation=q, physicsClientId=c)
            pb.changeConstraint(self._tie, maxForce=1e4, physicsClientId=c)

    def true_state(self) -> RigidState:
        """The physics state now, without noise or latency."""
        return self._state

    def _query_state(self) -> RigidState:
        c = self._client
        pos, q = pb.getBasePositionAndOrientation(self._body, physicsClientId=c)
        vel, omega_w = pb.getBaseVelocity(self._body, physicsClientId=c)
        r = quat_to_matrix(q) @ self._r_if.T
        return RigidState(np.array(pos), np.array(vel), r, r.T @ np.array(omega_w))

    def mocap_samples(self) -> list[PoseMeasurement]:
        """The motion capture's samples delivered since the last call (times: capture, simulated s)."""
        out, self._mocap_out = self._mocap_out, []
        return out

    def _delayed(self, age: float) -> RigidState:
        """The physics state ``age`` s ago (the oldest kept, if older)."""
        target = self._t - age
        for t, state in reversed(self._history):
            if t <= target + 1e-12:
                return state
        return self._history[0][1]

    def _record(self) -> None:
        self._state = self._query_state()
        self._history.append((self._t, self._state))
        horizon = self.config.gyro_delay + 2 * self._dt
        while self._history and self._history[0][0] < self._t - horizon - 1e-12:
            self._history.popleft()

