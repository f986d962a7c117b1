"""Real Crazyflie firmware in the loop: one ``cf_sitl`` process per module behind the same UDP links as
:mod:`sim.crazyflie_peer`, with the physics from our PyBullet world.

``firmware/crazyflie_sitl`` builds crazyflie-firmware (a user's checkout, 2026.08) natively with the motor app; each
process serves CRTP on ``port + i`` exactly as a simulated module does, so the ground station flies it with the same
Crazyflie backend and cflib. Each process gets sensor datagrams at the firmware's IMU rate, 1 kHz (two per physics
step at :data:`FIRMWARE_PHYSICS_HZ`; ``firmware/crazyflie_sitl/WIRE.md``): the specific force and body rate in its
module's own frame (rotated by its mount in the assembly, so the tumble check behaves as on hardware), the battery,
and its motors' speeds; it answers with the motor ratios its power distribution set, which become rotor thrust
through the platform's motor model (the assembly's ``motor_command``). A process that dies is a lost module (its
link goes silent, its rotors stop); one that exits for a reboot (cflib's ``PowerSwitch``, exit status 3) is started
again with its parameter file, so stored parameters survive as on hardware.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from sim.module_peer import ModulePeer

SENSOR = struct.Struct("<4sId3f3ff4H")
MOTOR = struct.Struct("<4sII4HB3x")
INFO_CAN_FLY, INFO_LOCKED = 0x08, 0x40
"""Bits of ``supervisorGetInfoBitfield`` in the motor datagram."""
FIRMWARE_IMU_HZ = 1000
"""The firmware's IMU rate: each sensor datagram releases one stabilizer step, so they come at this rate."""
FIRMWARE_PHYSICS_HZ = 500.0
"""Physics rate under real firmware, Hz: each step's IMU reading goes out ``FIRMWARE_IMU_HZ / physics_hz`` times
(a zero-order hold, as the stabilizer's 500 Hz attitude rate would see it). At 1 kHz the world took half a core,
the largest share of a flight on 2 cores after the ground station's loop; at 500 Hz it takes a quarter (2026-12-02).
The Python modules fly at 240 Hz."""
REBOOT_STATUS = 3
READY_TIMEOUT_S = 10.0
FIRMWARE_PRIORITY = 5
"""SCHED_FIFO priority of the firmware processes (and every task thread of theirs), where the host permits it and
they fit (:data:`FIRMWARE_CPU_SHARE`): below the world that feeds them (20) and the ground station's loop (10),
above every ordinary process. On hardware each module's firmware has a processor of its own; behind ordinary
processes on a busy host it answered tens of ms late, which the ground station rightly takes for a degraded link.
Above the loop (15), they took the loop's core 1000 times a second: 500-930 of a flight's 6000 periods were late
(against 10-160 at 5), and in one flight in three more than the flight's 25 % bound (2026-12-02, with the world at
:data:`FIRMWARE_PHYSICS_HZ`; at 1 kHz the world itself held them back below the loop)."""
FIRMWARE_CPU_SHARE = 0.2
"""What one firmware process takes of a core, fed at 1 kHz (measured 13-19 %: its 1 kHz tick, the stabilizer, the
links' 1 ms polls; its idle task sleeps in ``vApplicationIdleHook``). Real-time processes are never preempted by
ordinary ones, so they get the priority only while all of them fit in the host's cores less one (n <= 5 on 2
cores): more would starve everything else, the ground station's own threads included."""


def _firmware_priority() -> None:
    """``preexec_fn`` of a firmware process: :data:`FIRMWARE_PRIORITY` where permitted (as it was otherwise; the
    parent reads back which: :attr:`FirmwareCrazyflies.realtime_firmware`). Only a system call, no lock taken: safe
    in the child of a process with threads."""
    with contextlib.suppress(PermissionError, OSError):
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIRMWARE_PRIORITY))


class _Process:
    def __init__(self, binary: Path, crtp_port: int, params: Path, log: Path, uid: str, realtime: bool) -> None:
        self.sensor_port = _free_port()
        self.motor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.motor.bind(("127.0.0.1", 0))
        self.motor.setblocking(False)
        self.cmd = [str(binary), "--crtp-port", str(crtp_port), "--sensor-port", str(self.sensor_port),
                    "--motor-addr", f"127.0.0.1:{self.motor.getsockname()[1]}", "--params", str(params), "--uid", uid]
        self.log = log
        self.realtime = realtime
        """Whether the process is started at :data:`FIRMWARE_PRIORITY`."""
        self.ratios = np.zeros(4)
        self.info = 0
        self.heard = False
        self.boots = 0
        self.proc: subprocess.Popen | None = None
        self.running = False
        self.start()

    def start(self) -> None:
        self.boots += 1
        self.heard = False
        self.ratios = np.zeros(4)
        with open(self.log, "a") as out:
            self.proc = subprocess.Popen(self.cmd, stdout=out, stderr=subprocess.STDOUT,
                                         preexec_fn=_firmware_priority if self.realtime else None)
        self.running = True

    def alive(self) -> bool:
        """Whether the process still runs (asked of the OS; :attr:`running` keeps the answer for this step)."""
        self.running = self.proc.poll() is None
        return self.running

    def receive(self) -> None:
        while True:
            try:
                data = self.motor.recv(64)
            except (BlockingIOError, InterruptedError):
                return
            if len(data) == MOTOR.size and data[:4] == b"CFMO":
                *_, r0, r1, r2, r3, info = MOTOR.unpack(data)
                self.ratios = np.array([r0, r1, r2, r3]) / 65535.0
                self.info, self.heard = info, True

    def end(self) -> None:
        """Stop the process (SIGTERM, then SIGKILL after 2 s)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(2.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def stop(self) -> None:
        self.end()
        self.motor.close()


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class FirmwareCrazyflies(ModulePeer):
    """Crazyflie modules running the real firmware (``binary``: a ``cf_sitl`` built for the peer's platform)."""

    def __init__(self, assembly, config=None, binary: str | Path = "", state_dir: str | Path | None = None) -> None:
        super().__init__(assembly, config)
        self.binary = Path(binary)
        self._tmp = None if state_dir is not None else tempfile.TemporaryDirectory(prefix="cf_sitl-")
        self.state_dir = Path(state_dir if state_dir is not None else self._tmp.name)
        """Where each module keeps its stored parameters (``m<i>.params``) and its console log (``m<i>.log``)."""
        self.imu_per_step = 1
        """Sensor datagrams each module gets per physics step (:data:`FIRMWARE_PHYSICS_HZ`)."""
        self._tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._seq = 0
        self.realtime_firmware = False
        """Whether every firmware process runs at :data:`FIRMWARE_PRIORITY` (known once they are ready)."""

    def _open_links(self) -> None:
        if not self.binary.is_file():
            raise ValueError(f"no firmware-in-the-loop binary at {self.binary}: build firmware/crazyflie_sitl "
                             f"(make CRAZYFLIE_BASE=<crazyflie-firmware checkout> PLATFORM=<platform>)")
        if self.assembly.params.motor_command is None:
            raise ValueError("the assembly's module_params has no motor_command: the motors need their platform's "
                             "thrust model")
        rate = FIRMWARE_IMU_HZ / self.config.physics_hz
        if rate < 1 or abs(rate - round(rate)) > 1e-9:
            raise ValueError(f"physics at {self.config.physics_hz:g} Hz cannot pace the firmware's {FIRMWARE_IMU_HZ} "
                             f"Hz IMU: give a rate that divides it (e.g. {FIRMWARE_PHYSICS_HZ:g})")
        self.imu_per_step = round(rate)
        self.state_dir.mkdir(parents=True, exist_ok=True)
        c = self.config
        self._procs = []  # filled one by one: closing stops the ones already started if a later one fails
        fits = self.assembly.n * FIRMWARE_CPU_SHARE <= (os.cpu_count() or 1) - 1
        for i in range(self.assembly.n):
            # A unique id per module and per peer, like sim.crazyflie_peer's.
            self._procs.append(_Process(self.binary, c.port + i, self.state_dir / f"m{i}.params",
                                        self.state_dir / f"m{i}.log", f"00370041{c.port:08x}{0x38380000 + i:08x}",
                                        fits))
        self._wait_ready()
        with contextlib.suppress(OSError):  # a process that exited since: not real-time
            self.realtime_firmware = fits and all(os.sched_getscheduler(p.proc.pid) == os.SCHED_FIFO
                                                  for p in self._procs)

    def _wait_ready(self) -> None:
        """Feed level, at-rest sensors until every process sent its first motor datagram."""
        deadline = time.monotonic() + READY_TIMEOUT_S
        rest = np.array([0.0, 0.0, 1.0])
        while not all(p.heard for p in self._procs):
            if time.monotonic() > deadline or any(p.proc.poll() is not None for p in self._procs):
                dead = [i for i, p in enumerate(self._procs) if not p.heard]
                raise ValueError(f"firmware modules {dead} did not start (see {self.state_dir}/m<i>.log)")
            for i, p in enumerate(self._procs):
                self._send_sensors(p, self.module_frame(i, rest).tolist(), [0.0] * 3, [0] * 4)
                p.receive()
            time.sleep(0.001)

    def _close_links(self) -> None:
        for p in getattr(self, "_procs", []):
            p.stop()
        self._procs = []
        self._tx.close()
        if self._tmp is not None:
            self._tmp.cleanup()

    def _send_sensors(self, p: _Process, acc_g: list[float], gyro_deg_s: list[float], rpm: list[int]) -> None:
        # Plain floats, packed as they come: this runs for every module at 1 kHz, and numpy's per-call overhead
        # per module was a sixth of the step.
        self._seq += 1
        packet = SENSOR.pack(b"CFSI", self._seq & 0xFFFFFFFF, self.sim.time, *acc_g, *gyro_deg_s,
                             float(self.config.battery_v), *rpm)
        with contextlib.suppress(OSError):
            self._tx.sendto(packet, ("127.0.0.1", p.sensor_port))

    def _serve(self, now: float) -> None:
        # Every module's IMU at once (one call each, not one per module: a third of the 1 kHz step was per-module
        # numpy calls, 2026-12-02).
        acc = self.module_frames(self.specific_force()).tolist()
        gyro = np.degrees(self.module_gyros()).tolist()
        rpm = np.clip(np.rint(self.module_rpms()), 0, 65535).astype(int).tolist()
        for i, p in enumerate(self._procs):
            if not p.alive():
                if p.proc.returncode == REBOOT_STATUS:
                    p.start()  # a reboot: the same links, the stored parameters
                p.info = 0  # a dead process: its link is silent, its motors stop, nothing about it is known
                continue
            for _ in range(self.imu_per_step):
                self._send_sensors(p, acc[i], gyro[i], rpm[i])
            p.receive()

    def _rotor_inputs(self, now: float) -> np.ndarray:
        params = self.assembly.params
        ratios = np.array([p.ratios if p.running else np.zeros(4) for p in self._procs])
        thrust = params.motor_command.thrust(ratios, np.full(len(self._procs), self.config.battery_v))
        return (thrust / params.c_f).reshape(-1)

    def armed(self, i: int) -> bool:
        return bool(self._procs[i].info & INFO_CAN_FLY)

    def locked(self, i: int) -> bool:
        return bool(self._procs[i].info & INFO_LOCKED)

    def kill(self, i: int) -> None:
        """Kill module i's firmware process (a module lost in flight)."""
        self._procs[i].proc.kill()

    def restart(self) -> None:
        """Restart every firmware process (a power cycle of every module); stored parameters are kept."""
        for p in self._procs:
            p.end()
            p.start()
        self._wait_ready()

    def ratios(self, i: int) -> np.ndarray:
        """Module i's newest motor ratios (0..1)."""
        return self._procs[i].ratios.copy()
