"""Simulated Crazyflie modules on loopback: PyBullet physics behind the modules' real wire protocol.

One UDP socket per module speaks CRTP exactly as cflib's UDP driver expects (one packet per datagram), runs the
module motor app's rules (:mod:`groundstation.backends.crtp_wire`: armed flag, supervisor emergency stop that
locks, a staleness timeout that stops the motors when commands stop arriving) and replies with the module's
state. The assembly is simulated in real time and its pose published over Zenoh by a virtual mocap, so the
ground station flies it with the Crazyflie backend, in another process, exactly as it would fly hardware:

    groundstation sim-peer configs/assemblies/toy_v2.json --port 19850 --mocap tcp/127.0.0.1:7448

Modules listen on ``port, port + 1, ...`` in assembly order.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from dataclasses import dataclass

import numpy as np

from groundstation.assembly.assembly import Assembly
from groundstation.backends import crtp_wire as wire
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
    """The module app stops its motors when no command arrived for this long, s."""
    state_rate_hz: float = 100.0
    """Module state replies, Hz (every command is applied; replies are rate-limited like a radio's acks)."""
    battery_v: float = 4.0
    """V"""


class _Module:
    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.peer: tuple | None = None
        self.u = np.zeros(4)
        self.armed = False
        self.stopped = False
        self.sequence = 0
        self.last_command = -np.inf
        self.last_reply = -np.inf


class SimulatedModules:
    """The modules of one assembly: sockets, the motor app's rules, physics in real time."""

    def __init__(self, assembly: Assembly, config: PeerConfig | None = None) -> None:
        self.assembly = assembly
        self.config = c = config or PeerConfig()
        self._modules: list[_Module] = []
        self._session = None
        self._publisher = None
        self._vmocap = None
        sim_config = SimConfig(physics_hz=c.physics_hz, motor_time_constant=c.motor_time_constant)
        self.sim = PyBulletBackend(assembly, sim_config, observers=[self._observe])
        self.stop_event = threading.Event()
        self.packets = 0

    def _observe(self, t: float, state) -> None:
        if self._vmocap is not None:
            self._vmocap.on_step(t, state)

    def open(self) -> None:
        c = self.config
        try:
            for i in range(self.assembly.n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.bind((c.host, c.port + i))
                s.setblocking(False)
                self._modules.append(_Module(s))
        except OSError as exc:
            self.close()
            raise OSError(f"cannot listen on udp {c.host}:{c.port}..{c.port + self.assembly.n - 1}: {exc}") from None
        self._session = open_session(listen=[c.mocap_endpoint])
        self._publisher = PosePublisher(self._session, c.mocap_key)
        self._vmocap = VirtualMocap(self._publisher, c.mocap_rate_hz, c.position_noise, c.attitude_noise,
                                    c.mocap_latency)
        self.sim.connect()
        self.sim.arm()  # the per-module armed flags gate the rotors below

    def close(self) -> None:
        for m in self._modules:
            m.sock.close()
        self._modules = []
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
            self.sim.send(np.concatenate([m.u if m.armed and not m.stopped else np.zeros(4)
                                          for m in self._modules]))
            k += 1
            self.sim.advance_to(k * dt)
            remaining = t0 + k * dt - time.monotonic()
            if remaining > 0:
                time.sleep(remaining)
            elif remaining < -0.1:  # far behind (machine stalled): resynchronise rather than race
                t0 -= remaining

    def _serve(self, now: float) -> None:
        c = self.config
        u_max = self.assembly.params.u_max
        gyro = self.sim.telemetry().gyro
        for i, m in enumerate(self._modules):
            while True:
                try:
                    data, addr = m.sock.recvfrom(64)
                except (BlockingIOError, InterruptedError):
                    break
                self.packets += 1
                m.peer = addr
                if not data:
                    continue
                head, body = data[0], data[1:]
                if head == wire.NULL_HEADER:
                    m.last_reply = -np.inf  # a probe: answer now
                elif head == wire.STOP_HEADER and body[:1] == bytes([wire.CMD_EMERGENCY_STOP]):
                    m.stopped, m.armed, m.u = True, False, np.zeros(4)
                elif head == wire.APP_HEADER:
                    try:
                        cmd = wire.MotorCommand.unpack(body)
                    except ValueError:
                        continue
                    m.sequence, m.last_command = cmd.sequence, now
                    m.armed = cmd.armed and not m.stopped
                    m.u = wire.from_counts(cmd.counts, u_max) if m.armed else np.zeros(4)
            if now - m.last_command > c.command_timeout:
                m.armed, m.u = False, np.zeros(4)  # the app's own watchdog: no fresh command, no thrust
            if m.peer is not None and now - m.last_reply >= 1.0 / c.state_rate_hz:
                r = self.assembly.module_rotations[i]
                applied = self.sim.telemetry().motors[4 * i:4 * i + 4]
                st = wire.ModuleState(m.sequence, m.armed, m.stopped, tuple(wire.to_counts(applied, u_max)),
                                      c.battery_v, tuple(float(v) for v in r.T @ gyro))
                with contextlib.suppress(OSError):  # the ground station went away: motors stop on the timeout
                    m.sock.sendto(bytes([wire.APP_HEADER]) + st.pack(), m.peer)
                m.last_reply = now

    def __enter__(self) -> SimulatedModules:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
