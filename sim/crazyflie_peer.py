"""Simulated Crazyflie modules on loopback: PyBullet physics behind the modules' real CRTP wire protocol.

One UDP socket per module speaks CRTP exactly as cflib's UDP driver expects (one packet per datagram). Behind it
each module runs a model of crazyflie-firmware 2026.08 with the motor app flashed (:mod:`sim.crazyflie_firmware`:
supervisor arming, emergency stop and watchdogs, the app's mailbox and gate, one state per batch of commands, the
parameter services with persistent storage, reboots through cflib's ``PowerSwitch``). The forces the firmware
outputs become rotor thrust through the platform's map (the assembly's ``module_params.motor_command``, with the
module's battery voltage), and the pose goes out over Zenoh (:class:`sim.module_peer.ModulePeer`). The ground
station flies it with the Crazyflie backend, in another process, exactly as it would fly hardware:

    groundstation sim-peer configs/assemblies/toy_v2.json --port 19850 --mocap tcp/127.0.0.1:7448

Modules listen on ``port, port + 1, ...`` in assembly order. Each batch of app packets is answered with one state,
sent to the address the ground station last sent from (a radio link carries it back in the acknowledgements of the
ground station's packets). Each module's supervisor sees the module's own accelerometer (the specific force in its
frame: a module mounted beyond 60 degrees of tilt trips the tumble check, as on hardware) and motor speeds.
"""

from __future__ import annotations

import contextlib
import socket
import time

import numpy as np

from sim.crazyflie_firmware import FirmwareBuild, SimulatedCrazyflie
from sim.module_peer import ModulePeer


class _Link:
    def __init__(self, sock: socket.socket, firmware: SimulatedCrazyflie) -> None:
        self.sock = sock
        self.peer: tuple | None = None
        """Address of the ground station (learnt from its packets)."""
        self.firmware = firmware


class SimulatedCrazyflies(ModulePeer):
    """Crazyflie modules running the motor app, one UDP socket each."""

    def _open_links(self) -> None:
        c = self.config
        if self.assembly.params.motor_command is None:
            raise ValueError("the assembly's module_params has no motor_command: a simulated Crazyflie needs the "
                             "thrust map of its platform")
        build = FirmwareBuild(platform=c.platform, motor_app=c.motor_app)
        self._links: list[_Link] = []
        for i in range(self.assembly.n):
            # A unique id per module and per peer (its first port), as every MCU has its own.
            firmware = SimulatedCrazyflie(build, time.monotonic(), c.params, self.assembly.params.motor_command,
                                          c.battery_v, uid=(0x00370041, c.port, 0x38380000 + i))
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._links.append(_Link(s, firmware))
            s.bind((c.host, c.port + i))
            s.setblocking(False)

    def firmware(self, i: int) -> SimulatedCrazyflie:
        """Module i's firmware (parameters, supervisor, app)."""
        return self._links[i].firmware

    def armed(self, i: int) -> bool:
        fw = self.firmware(i)
        return fw.supervisor.can_fly and fw.app.latest is not None and fw.app.latest.armed

    def locked(self, i: int) -> bool:
        return self.firmware(i).supervisor.locked

    def ratios(self, i: int) -> np.ndarray:
        """Module i's motor ratios now (0..1)."""
        return self.firmware(i).ratios(time.monotonic())

    def _close_links(self) -> None:
        for link in getattr(self, "_links", []):
            link.sock.close()
        self._links = []

    def _serve(self, now: float) -> None:
        acc, rpm = self.module_frames(self.specific_force()), self.module_rpms()
        for i, link in enumerate(self._links):
            while True:
                try:
                    data, addr = link.sock.recvfrom(64)
                except (BlockingIOError, InterruptedError):
                    break
                self.packets += 1
                link.peer = addr
                for reply in link.firmware.handle(data, now):
                    with contextlib.suppress(OSError):
                        link.sock.sendto(reply, addr)
            link.firmware.step(now, acc[i], rpm[i])
            if link.peer is not None and link.firmware.state_due():
                packet = link.firmware.state_packet(now, self.module_gyro(i))
                with contextlib.suppress(OSError):  # the ground station went away: motors stop on the timeout
                    link.sock.sendto(packet, link.peer)

    def _rotor_inputs(self, now: float) -> np.ndarray:
        params = self.assembly.params
        ratios = np.array([link.firmware.ratios(now) for link in self._links])
        thrust = params.motor_command.thrust(ratios, np.full(len(self._links), self.config.battery_v))
        return (thrust / params.c_f).reshape(-1)
