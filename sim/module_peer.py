"""Simulated modules in another process: PyBullet in real time behind a module wire protocol, pose on Zenoh.

The ground station flies such a peer with its hardware backend, through the real link library, exactly as it
would fly hardware. :class:`ModulePeer` holds what every protocol shares (physics in real time, the virtual
mocap); each protocol (:mod:`sim.crazyflie_peer`, :mod:`sim.mavlink_peer`) models its modules' firmware, opens its
links, serves its packets and says what reaches the rotors.
"""

from __future__ import annotations

import gc
import threading
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.module import GRAVITY
from groundstation.backends.section import SIM_MOTOR_TIME_CONSTANT, SIM_PHYSICS_HZ
from groundstation.mocap.auth import MocapKey
from groundstation.mocap.zenoh_link import PosePublisher, open_session
from groundstation.runtime.loop import realtime_priority
from sim.pybullet_backend import PyBulletBackend, SimConfig
from sim.virtual_mocap import VirtualMocap

WORLD_PRIORITY = 20
"""SCHED_FIFO priority of the physics (above the ground station's loop, 10): the world it stands for is never
late. At normal priority a 1 kHz firmware-in-the-loop peer fell 25 ms behind several times a minute on an idle
2-core machine, and each time the firmware's answers came that much later (link round trips of 26-46 ms: the
flight stopped on a degraded link)."""
MAX_LAG_S = 0.025
"""How far the physics may fall behind its real-time schedule before the schedule moves on (the world pauses), s.
Behind it, the peer steps without sleeping to catch up; each pose then leaves that much later than its (truthful)
stamp, and the ground station rejects a pose more than 50 ms later than the stream's fastest (``StampClockSettings``):
1 kHz firmware-in-the-loop peers on 2 cores lagged up to 100 ms, and a third of their poses were refused."""


@dataclass(frozen=True)
class PeerConfig:
    port: int = 19850
    """UDP port of module 0; module i listens on ``port + i`` (127.0.0.1)."""
    host: str = "127.0.0.1"
    mocap_endpoint: str = "tcp/127.0.0.1:7448"
    """Zenoh endpoint the virtual mocap listens on."""
    mocap_key: str = "mocap/assembly/pose"
    mocap_rate_hz: float = 100.0
    position_noise: float = 0.0005
    """m"""
    attitude_noise: float = np.radians(0.1)
    """rad"""
    mocap_latency: float = 0.005
    """s"""
    physics_hz: float = SIM_PHYSICS_HZ
    motor_time_constant: float = SIM_MOTOR_TIME_CONSTANT
    """s"""
    state_rate_hz: float = 100.0
    """PX4 modules: state streams, Hz (the Crazyflie motor app answers each batch of commands instead)."""
    battery_v: float = 4.0
    """V"""
    params: tuple[tuple[str, float], ...] = ()
    """Firmware parameters set on every module before it starts (a module already configured: on a Crazyflie
    they are stored, so they survive a reboot); the others keep their stock values."""
    platform: Literal["cf2", "cf21bl", "bolt"] = "bolt"
    """Crazyflie platform of the modules (the paper's 0.24 kg modules are Bolt builds): whether the supervisor
    must be asked to arm, and which thrust map the firmware applies (the assembly's ``motor_command``)."""
    motor_app: bool = True
    """Crazyflie: the motor app is flashed (False: stock firmware, which the ground station must refuse)."""
    mocap_mac_key: MocapKey | None = None
    """The virtual mocap authenticates its samples with this key (``groundstation mocap-key``)."""


class ModulePeer:
    """The modules of one assembly: links (per protocol), firmware rules, physics in real time, mocap on Zenoh."""

    def __init__(self, assembly: Assembly, config: PeerConfig | None = None) -> None:
        self.assembly = assembly
        self.config = c = config or PeerConfig()
        self._session = None
        self._publisher = None
        self._vmocap = None
        sim_config = SimConfig(physics_hz=c.physics_hz, motor_time_constant=c.motor_time_constant,
                               mocap_rate_hz=0.0)  # the virtual mocap measures
        self.sim = PyBulletBackend(assembly, sim_config, observers=[self._observe])
        self._last_velocity: tuple[float, np.ndarray] | None = None
        """(time s, body velocity m/s) at the previous physics step, for the accelerometers."""
        self._t0 = time.monotonic()
        """The monotonic clock at simulated time 0 on the real-time schedule, s (moved on when a stall is given up
        on)."""
        self._wall_offset = time.time() - time.monotonic()
        """Wall clock less monotonic clock, s (the stamps are on the wall clock)."""
        self.stop_event = threading.Event()
        self.packets = 0
        """Packets received from the ground station."""
        self.pauses = 0
        """Times the physics fell more than ``MAX_LAG_S`` behind its schedule and the world paused."""
        self.realtime = False
        """The physics ran under real-time scheduling."""

    # -- per protocol -------------------------------------------------------------------------------------------
    def _open_links(self) -> None:
        raise NotImplementedError

    def _close_links(self) -> None:
        raise NotImplementedError

    def _serve(self, now: float) -> None:
        """Read every pending packet, apply it to the modules' firmware, and send what is due."""
        raise NotImplementedError

    def _rotor_inputs(self, now: float) -> np.ndarray:
        """What the modules' firmware drives the rotors with now, (4n,) rad^2/s^2."""
        raise NotImplementedError

    def armed(self, i: int) -> bool:
        """Module i would spin its motors on a command."""
        raise NotImplementedError

    def locked(self, i: int) -> bool:
        """Module i is emergency-stopped (until it restarts)."""
        raise NotImplementedError

    # -- shared -------------------------------------------------------------------------------------------------
    def _observe(self, t: float, state) -> None:
        if self._vmocap is not None:
            # Stamped at the moment the real-time schedule gives the step, not when a peer behind it (starved on a
            # loaded machine, racing to catch up) gets there: stamped "now", a state 30 ms old looked current and
            # the ground station's estimator, trusting the stamps, was pulled off by its speed x 30 ms per pose.
            self._vmocap.on_step(t, state, self._wall_offset + self._t0 + t)

    def open(self) -> None:
        c = self.config
        try:
            self._open_links()
        except OSError as exc:
            self.close()
            raise OSError(f"cannot listen on udp {c.host}:{c.port}..{c.port + self.assembly.n - 1}: {exc}") from None
        except BaseException:
            self.close()  # nothing half-open: the firmware processes already started stop with it
            raise
        self._session = open_session(listen=[c.mocap_endpoint])
        self._publisher = PosePublisher(self._session, c.mocap_key, c.mocap_mac_key)
        self._vmocap = VirtualMocap(self._publisher, c.mocap_rate_hz, c.position_noise, c.attitude_noise,
                                    c.mocap_latency)
        self.sim.connect()
        self.sim.arm()  # each module's firmware model gates its rotors

    def close(self) -> None:
        self._close_links()
        if self._publisher is not None:
            self._publisher.close()
            self._publisher = None
        if self._session is not None:
            self._session.close()
            self._session = None
        self.sim.close()

    def run_as_world(self, duration: float | None = None) -> None:
        """:meth:`run` as the ``sim-peer`` process does: under SCHED_FIFO at :data:`WORLD_PRIORITY` where permitted
        (:attr:`realtime` says whether it was), the heap allocated so far frozen out of the cyclic collector (its
        oldest-generation passes, scanning PyBullet, Zenoh and numpy, held the physics up for tens of ms). Both
        are the process's business: a peer run in a thread of a flight's process would share them with the
        flight's own."""
        gc.collect()
        gc.freeze()
        try:
            with realtime_priority(WORLD_PRIORITY) as self.realtime:
                self.run(duration)
        finally:
            gc.unfreeze()

    def run(self, duration: float | None = None) -> None:
        """Simulate in real time until :attr:`stop_event` is set (or ``duration`` s passed)."""
        dt = 1.0 / self.config.physics_hz
        self._wall_offset = time.time() - time.monotonic()
        self._t0 = time.monotonic() - self.sim.time
        k = round(self.sim.time / dt)
        start = k
        while not self.stop_event.is_set() and (duration is None or (k - start) * dt < duration):
            now = time.monotonic()
            self._serve(now)
            self.sim.send(self._rotor_inputs(now))
            k += 1
            self.sim.advance_to(k * dt)
            remaining = self._t0 + k * dt - time.monotonic()
            if remaining > 0:
                time.sleep(remaining)
            elif remaining < -MAX_LAG_S:  # behind (machine stalled): resynchronise rather than race
                self._t0 -= remaining
                self.pauses += 1

    def module_gyro(self, i: int) -> np.ndarray:
        """Module i's gyro: the body rate in the module's frame, rad/s, with noise of its own (read afresh: each
        module's IMU is a sensor of its own, and the ground station compares them)."""
        return self.module_frame(i, self.sim.gyro_readings(1)[0])

    def module_gyros(self) -> np.ndarray:
        """Every module's gyro at once, (n, 3) rad/s, each in its module's frame with noise of its own."""
        return np.einsum("nji,nj->ni", self.assembly.module_rotations, self.sim.gyro_readings(self.assembly.n))

    def specific_force(self) -> np.ndarray:
        """The body's specific force (acceleration less gravity) in the body frame, in g, from its velocity over
        the last physics step (at rest, level: 0 0 1); call once per step."""
        state = self.sim.true_state()
        now = self.sim.time
        accel = np.zeros(3)
        if self._last_velocity is not None and now > self._last_velocity[0]:
            accel = (state.velocity - self._last_velocity[1]) / (now - self._last_velocity[0])
        self._last_velocity = (now, state.velocity.copy())
        return state.rotation.T @ (accel + np.array([0.0, 0.0, GRAVITY])) / GRAVITY

    def module_frame(self, i: int, body_vector: np.ndarray) -> np.ndarray:
        """A body-frame vector in module i's frame (what its IMU measures)."""
        return self.assembly.module_rotations[i].T @ body_vector

    def module_frames(self, body_vector: np.ndarray) -> np.ndarray:
        """A body-frame vector in every module's frame, (n, 3)."""
        return body_vector @ self.assembly.module_rotations

    def module_rpms(self) -> np.ndarray:
        """Every module's motor speeds as bidirectional DSHOT reports them, (n, 4) RPM."""
        return np.sqrt(np.maximum(self.sim.rotor_inputs.reshape(-1, 4), 0.0)) * (60.0 / (2.0 * np.pi))

    def module_motors(self, i: int) -> np.ndarray:
        """Module i's rotor inputs as the physics applies them (after the motor lag), rad^2/s^2."""
        return self.sim.rotor_inputs[4 * i:4 * i + 4].copy()

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
