"""Simulated Crazyflie modules on loopback: PyBullet physics behind the modules' real CRTP wire protocol.

One UDP socket per module speaks CRTP exactly as cflib's UDP driver expects (one packet per datagram), runs the
module motor app's rules (:mod:`groundstation.backends.crtp_wire`: armed flag, supervisor emergency stop that
locks, a staleness timeout that stops the motors when commands stop arriving) and replies with the module's
state. It also answers the firmware services cflib's ``Crazyflie`` class uses to connect and to read and write
parameters (:mod:`sim.crtp_services`), starting from stock parameter values unless ``PeerConfig.params`` sets
them. The pose goes out over Zenoh (:class:`sim.module_peer.ModulePeer`), so the ground station flies it with the
Crazyflie backend, in another process, exactly as it would fly hardware:

    groundstation sim-peer configs/assemblies/toy_v2.json --port 19850 --mocap tcp/127.0.0.1:7448

Modules listen on ``port, port + 1, ...`` in assembly order.
"""

from __future__ import annotations

import contextlib
import socket

import numpy as np

from groundstation.backends import crtp_wire as wire
from sim.crtp_services import FirmwareServices, stock_params
from sim.module_peer import ModulePeer


class _Link:
    def __init__(self, sock: socket.socket, firmware: FirmwareServices) -> None:
        self.sock = sock
        self.peer: tuple | None = None
        """Address of the ground station (learnt from its first packet)."""
        self.sequence = 0
        """Sequence number of the last command applied."""
        self.last_reply = -np.inf
        self.firmware = firmware
        """The module's parameters and connection-setup services."""


class SimulatedCrazyflies(ModulePeer):
    """Crazyflie modules running the motor app, one UDP socket each."""

    def _open_links(self) -> None:
        c = self.config
        self._links: list[_Link] = []
        for i in range(self.assembly.n):
            firmware = FirmwareServices(stock_params())
            for name, value in c.params:
                firmware.set(name, value)
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._links.append(_Link(s, firmware))
            s.bind((c.host, c.port + i))
            s.setblocking(False)

    def firmware(self, i: int) -> FirmwareServices:
        """Module i's parameters."""
        return self._links[i].firmware

    def _close_links(self) -> None:
        for link in getattr(self, "_links", []):
            link.sock.close()
        self._links = []

    def _serve(self, now: float) -> None:
        c = self.config
        u_max = self.assembly.params.u_max
        for i, (link, m) in enumerate(zip(self._links, self.modules, strict=True)):
            while True:
                try:
                    data, addr = link.sock.recvfrom(64)
                except (BlockingIOError, InterruptedError):
                    break
                self.packets += 1
                link.peer = addr
                if not data:
                    continue
                head, body = data[0], data[1:]
                if head == wire.NULL_HEADER:
                    link.last_reply = -np.inf  # a probe: answer now
                elif head == wire.STOP_HEADER and body[:1] == bytes([wire.CMD_EMERGENCY_STOP]):
                    m.emergency_stop()
                elif head == wire.APP_HEADER:
                    try:
                        cmd = wire.MotorCommand.unpack(body)
                    except ValueError:
                        continue
                    link.sequence = cmd.sequence
                    m.arm(cmd.armed)
                    m.command(wire.from_counts(cmd.counts, u_max), now)
                else:
                    for reply in link.firmware.handle(head, body) or ():
                        with contextlib.suppress(OSError):
                            link.sock.sendto(reply, addr)
            if link.peer is not None and now - link.last_reply >= 1.0 / c.state_rate_hz:
                st = wire.ModuleState(link.sequence, m.armed, m.stopped,
                                      tuple(wire.to_counts(self.module_motors(i), u_max)), c.battery_v,
                                      tuple(float(v) for v in self.module_gyro(i)))
                with contextlib.suppress(OSError):  # the ground station went away: motors stop on the timeout
                    link.sock.sendto(bytes([wire.APP_HEADER]) + st.pack(), link.peer)
                link.last_reply = now
