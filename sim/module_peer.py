"""Simulated modules in another process: PyBullet in real time behind a module wire protocol, pose on Zenoh.

The ground station flies such a peer with its hardware backend, through the real link library, exactly as it
would fly hardware. :class:`ModulePeer` holds what every protocol shares (physics in real time, the virtual mocap,
the rules a module's firmware applies: armed flag, latching emergency stop, command staleness timeout); each
protocol (:mod:`sim.crazyflie_peer`, :mod:`sim.mavlink_peer`) opens its links and serves its packets.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from groundstation.assembly.assembly import Assembly
from groundstation.mocap.zenoh_link import PosePublisher, open_session
from sim.pybullet_backend import PyBulletBackend, SimConfig
from sim.virtual_mocap import VirtualMocap


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
    physics_hz: float = 240.0
    motor_time_constant: float = 0.02
    """s"""
    command_timeout: float = 0.1
    """The Crazyflie motor app stops its motors when no command arrived for this long, s (PX4 modules use their
    ``COM_OF_LOSS_T`` parameter instead)."""
    state_rate_hz: float = 100.0
    """Module state replies, Hz (every command is applied; replies are rate-limited like a radio's acks)."""
    battery_v: float = 4.0
    """V"""
    params: tuple[tuple[str, float], ...] = ()
    """Firmware parameters set on every module before it starts (a module already configured); the others keep
    their stock values."""


class ModuleRules:
    """What one module's firmware enforces, whatever the protocol: thrust only while armed, not stopped, fresh."""

    def __init__(self) -> None:
        self.u = np.zeros(4)
        """Rotor inputs last commanded, rad^2/s^2."""
        self.armed = False
        self.stopped = False
        """Emergency-stopped: latches until the module restarts."""
        self.last_command = -np.inf
        """Monotonic time of the last motor command, s."""

    def command(self, u: np.ndarray, now: float) -> None:
        self.last_command = now
        self.u = u if self.armed else np.zeros(4)

    def arm(self, armed: bool) -> None:
        self.armed = armed and not self.stopped
        if not self.armed:
            self.u = np.zeros(4)

    def emergency_stop(self) -> None:
        self.stopped = True
        self.arm(False)

    def enforce_timeout(self, now: float, timeout: float) -> bool:
        """Disarm when no command arrived for ``timeout`` s while armed; True if that happened now."""
        if self.armed and now - self.last_command > timeout:
            self.arm(False)
            return True
        return False

    def thrust(self) -> np.ndarray:
        return self.u if self.armed and not self.stopped else np.zeros(4)


class ModulePeer:
    """The modules of one assembly: links (per protocol), firmware rules, physics in real time, mocap on Zenoh."""

    def __init__(self, assembly: Assembly, config: PeerConfig | None = None) -> None:
        self.assembly = assembly
        self.config = c = config or PeerConfig()
        self.modules = [ModuleRules() for _ in range(assembly.n)]
        self._session = None
        self._publisher = None
        self._vmocap = None
        sim_config = SimConfig(physics_hz=c.physics_hz, motor_time_constant=c.motor_time_constant)
        self.sim = PyBulletBackend(assembly, sim_config, observers=[self._observe])
        self.stop_event = threading.Event()
        self.packets = 0
        """Packets received from the ground station."""

    # -- per protocol -------------------------------------------------------------------------------------------
    def _open_links(self) -> None:
        raise NotImplementedError

    def _close_links(self) -> None:
        raise NotImplementedError

    def _serve(self, now: float) -> None:
        """Read every pending packet, apply it to :attr:`modules`, and reply at ``state_rate_hz``."""
        raise NotImplementedError

    def command_timeout(self, i: int) -> float:
        """Module i stops its motors when no command arrived for this long, s."""
        return self.config.command_timeout

    # -- shared -------------------------------------------------------------------------------------------------
    def _observe(self, t: float, state) -> None:
        if self._vmocap is not None:
            self._vmocap.on_step(t, state)

    def open(self) -> None:
        c = self.config
        try:
            self._open_links()
        except OSError as exc:
            self.close()
            raise OSError(f"cannot listen on udp {c.host}:{c.port}..{c.port + self.assembly.n - 1}: {exc}") from None
        self._session = open_session(listen=[c.mocap_endpoint])
        self._publisher = PosePublisher(self._session, c.mocap_key)
        self._vmocap = VirtualMocap(self._publisher, c.mocap_rate_hz, c.position_noise, c.attitude_noise,
                                    c.mocap_latency)
        self.sim.connect()
        self.sim.arm()  # the per-module rules gate the rotors

    def close(self) -> None:
        self._close_links()
        if self._publisher is not None:
            self._publisher.close()
            self._publisher = None
        if self._session is not None:
            self._session.close()
            self._session = None
        self.sim.close()

    def run(self, duration: float | None = None) -> None:
        """Simulate in real time until :attr:`stop_event` is set (or ``duration`` s passed)."""
        dt = 1.0 / self.config.physics_hz
        t0 = time.monotonic()
        k = 0
        while not self.stop_event.is_set() and (duration is None or k * dt < duration):
            now = time.monotonic()
            self._serve(now)
            for i, m in enumerate(self.modules):
                m.enforce_timeout(now, self.command_timeout(i))
            self.sim.send(np.concatenate([m.thrust() for m in self.modules]))
            k += 1
            self.sim.advance_to(k * dt)
            remaining = t0 + k * dt - time.monotonic()
            if remaining > 0:
                time.sleep(remaining)
            elif remaining < -0.1:  # far behind (machine stalled): resynchronise rather than race
                t0 -= remaining

    def module_gyro(self, i: int) -> np.ndarray:
        """Module i's gyro: the body rate in the module's frame, rad/s."""
        return self.assembly.module_rotations[i].T @ self.sim.telemetry().gyro

    def module_motors(self, i: int) -> np.ndarray:
        """Module i's rotor inputs as the physics applies them (after the motor lag), rad^2/s^2."""
        return self.sim.telemetry().motors[4 * i:4 * i + 4]

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
