"""CRTP packets between the ground station and one module's motor app (the Crazyflie firmware's app channel).

Stock Crazyflie firmware has no per-motor setpoint, so each module runs a small out-of-tree app (see
``firmware_params/README.md``) that takes four normalized rotor commands from the app channel and acknowledges
with its state. Each CRTP packet is one header byte (``port << 4 | 0b11 << 2 | channel``, as cflib builds it) and
at most 30 data bytes; over cflib's UDP driver one datagram carries one packet, which is what a simulated module
on loopback speaks.

* Motor command, ground -> module, port 13 (platform) channel 2 (app): ``<BB4H`` = sequence (mod 256), flags
  (bit 0: armed), four rotor inputs as ``round(u / u_max * 65535)`` in the module's rotor order q = 1..4.
* State, module -> ground, same port and channel: ``<BB4H4f`` = sequence of the last command applied, flags
  (bit 0 armed, bit 1 emergency-stopped), the four rotor inputs applied (same scale), battery voltage in V and the
  gyro rate in rad/s in the module's body frame.
* Emergency stop, ground -> module: the supervisor's command (port 9, channel 1, byte ``0x03``), exactly what
  ``cf.supervisor.send_emergency_stop()`` sends; the firmware stops the motors and stays locked.
* Link probe: the null packet ``0xFF`` (cflib's UDP scan); a module answers with its state.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

PORT_PLATFORM = 0x0D
APP_CHANNEL = 2
PORT_SUPERVISOR = 0x09
SUPERVISOR_COMMAND_CHANNEL = 1
CMD_EMERGENCY_STOP = 0x03
NULL_HEADER = 0xFF
MAX_DATA = 30
"""CRTP payload limit, bytes."""

_COMMAND = struct.Struct("<BB4H")
_STATE = struct.Struct("<BB4H4f")
FLAG_ARMED = 0x01
FLAG_STOPPED = 0x02
FULL_SCALE = 65535


def header(port: int, channel: int) -> int:
    """The CRTP header byte, as ``cflib.crtp.crtpstack.CRTPPacket`` builds it."""
    return ((port & 0x0F) << 4) | (0x3 << 2) | (channel & 0x03)


APP_HEADER = header(PORT_PLATFORM, APP_CHANNEL)
STOP_HEADER = header(PORT_SUPERVISOR, SUPERVISOR_COMMAND_CHANNEL)


def port_channel(head: int) -> tuple[int, int]:
    return (head >> 4) & 0x0F, head & 0x03


def to_counts(u: np.ndarray, u_max: float) -> list[int]:
    """Rotor inputs (rad^2/s^2, already bounded to [0, u_max]) as 16-bit fractions of u_max."""
    return [int(v) for v in np.rint(np.clip(np.asarray(u, float) / u_max, 0.0, 1.0) * FULL_SCALE)]


def from_counts(counts, u_max: float) -> np.ndarray:
    return np.asarray(counts, float) / FULL_SCALE * u_max


@dataclass(frozen=True, eq=False)
class MotorCommand:
    sequence: int
    """Sender's counter, mod 256."""
    armed: bool
    counts: tuple[int, int, int, int]
    """Rotor inputs q = 1..4 as fractions of u_max, 0..65535."""

    def pack(self) -> bytes:
        flags = FLAG_ARMED if self.armed else 0
        return _COMMAND.pack(self.sequence & 0xFF, flags, *self.counts)

    @classmethod
    def unpack(cls, data: bytes) -> MotorCommand:
        if len(data) != _COMMAND.size:
            raise ValueError(f"motor command must be {_COMMAND.size} bytes, got {len(data)}")
        seq, flags, *counts = _COMMAND.unpack(data)
        return cls(seq, bool(flags & FLAG_ARMED), tuple(counts))


@dataclass(frozen=True, eq=False)
class ModuleState:
    sequence: int
    """Sequence of the last command applied."""
    armed: bool
    stopped: bool
    """Emergency-stopped (locked until the module restarts)."""
    counts: tuple[int, int, int, int]
    """Rotor inputs applied, fractions of u_max, 0..65535."""
    battery_v: float
    """V"""
    gyro: tuple[float, float, float]
    """Module body frame, rad/s."""

    def pack(self) -> bytes:
        flags = (FLAG_ARMED if self.armed else 0) | (FLAG_STOPPED if self.stopped else 0)
        return _STATE.pack(self.sequence & 0xFF, flags, *self.counts, self.battery_v, *self.gyro)

    @classmethod
    def unpack(cls, data: bytes) -> ModuleState:
        if len(data) != _STATE.size:
            raise ValueError(f"module state must be {_STATE.size} bytes, got {len(data)}")
        seq, flags, c0, c1, c2, c3, battery, gx, gy, gz = _STATE.unpack(data)
        return cls(seq, bool(flags & FLAG_ARMED), bool(flags & FLAG_STOPPED), (c0, c1, c2, c3), battery,
                   (gx, gy, gz))

