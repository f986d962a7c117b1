"""CRTP packets between the ground station and one module's motor app (``firmware/crazyflie_app``).

Stock Crazyflie firmware has no per-motor setpoint, so each module runs the motor app: an out-of-tree app and
controller that takes four normalized forces from the app channel and streams its state back. Each CRTP packet is
one header byte (``port << 4 | 0b11 << 2 | channel``, as cflib builds it) and at most 30 data bytes; over cflib's
UDP driver one datagram carries one packet, which is what a simulated module on loopback speaks. The C side of
the app-channel payloads is ``firmware/crazyflie_app/src/motor_protocol.c``; both are checked against
``firmware/crazyflie_app/test/packet_vectors.txt`` (:func:`vectors_text`), so they cannot drift.

App channel (port 13, channel 2), little-endian:

* Claim, ground -> module, 5 bytes ``<BI``: kind ``0x03``, the ground station's session id (random, not 0). The
  module answers with its identity report. It takes the claim unless another session's armed commands are
  fresh (it flies for that one); a new owner gets a new token, which every command must carry.
* Identity, module -> ground, 25 bytes ``<BBBI3I3h``: kind ``0x82``, state flags, the owner's token, the owner's
  session, the MCU's unique id (``cpu.id0..id2``), the accelerometer in milli-g (module frame: at rest, gravity's
  direction, up).
* Motor command, ground -> module, 13 bytes ``<BBBH4H``: kind ``0x01``, flags (bit 0 armed), the owner's token,
  a 16-bit sequence, four normalized forces ``round(f / f_max * 65535)`` in the module's rotor order (the
  platform's map from thrust to normalized force is :mod:`groundstation.assembly.motor_map`). A command with
  another token is dropped (counted).
* Broadcast command, ground -> up to four modules in one no-ack packet: kind ``0x02``, flags (bit 0 armed, bits
  1-3 the module count), sequence, first slot, token, then per module four 12-bit forces packed in 6 bytes
  (``motorApp.slot`` picks a module's).
* State, module -> ground, one per batch of commands the app receives (never unprompted, so a ground station that
  connects reads no backlog), 30 bytes ``<BBH4HH3fHH``: kind ``0x81``, flags (armed, locked, supervisor armed,
  fresh, can fly, flying), the sequence of the newest command accepted (the latency probe), the motor ratios that
  reach the motors (after the firmware's battery compensation, dead zone, idle floor and shared cap), battery in
  mV, gyro in rad/s (module frame), commands accepted and commands dropped (both wrap).

Firmware services the backend uses directly (crazyflie-firmware >= 2026.04, CRTP protocol 12):

* supervisor (port 9, channel 1): arm/disarm request ``[0x01, do_arm]`` answered ``[0x81, success, is_armed]``;
  emergency stop ``[0x03]`` (latches until reboot). Firmware before 2026.04 silently drops port 9, so the stop is
  also sent as the legacy localization packet (port 6, channel 1, ``[0x03]``), which every release honours.
* platform version (port 13, channel 1): ``[0x00]`` answered ``[0x00, int32 protocol version]``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

PORT_LOCALIZATION = 0x06
LOCALIZATION_GENERIC_CHANNEL = 1
LEGACY_EMERGENCY_STOP = 0x03
PORT_SUPERVISOR = 0x09
SUPERVISOR_COMMAND_CHANNEL = 1
CMD_ARM_SYSTEM = 0x01
CMD_EMERGENCY_STOP = 0x03
CMD_RESPONSE = 0x80
PORT_PLATFORM = 0x0D
VERSION_CHANNEL = 1
APP_CHANNEL = 2
GET_PROTOCOL_VERSION = 0x00
NULL_HEADER = 0xFF
MAX_DATA = 30
"""CRTP payload limit, bytes."""
MIN_PROTOCOL_VERSION = 12
"""crazyflie-firmware 2026.04: the supervisor port (arming, emergency stop) the backend relies on."""
APP_VERSION = 3
"""The contract version this module speaks; the app serves it read-only as ``motorApp.version``. Version 2: forces
only while the supervisor can fly, states report motor ratios and answer commands. Version 3: one owner at a
time (claim, token), the identity report."""

KIND_COMMAND = 0x01
KIND_BROADCAST = 0x02
KIND_CLAIM = 0x03
KIND_STATE = 0x81
KIND_IDENTITY = 0x82
FLAG_ARMED = 0x01
STATE_ARMED = 0x01
STATE_LOCKED = 0x02
STATE_SUPERVISOR_ARMED = 0x04
STATE_FRESH = 0x08
STATE_CAN_FLY = 0x10
STATE_FLYING = 0x20
FULL_SCALE = 65535
BROADCAST_FULL_SCALE = 4095
BROADCAST_MAX_MODULES = 4

_COMMAND = struct.Struct("<BBBH4H")
_CLAIM = struct.Struct("<BI")
_IDENTITY = struct.Struct("<BBBI3I3h")
_STATE = struct.Struct("<BBH4HH3fHH")
_BROADCAST_HEADER = struct.Struct("<BBHBB")
_BROADCAST_COUNT_SHIFT = 1
_VERSION_REPLY = struct.Struct("<Bi")


def header(port: int, channel: int) -> int:
    """The CRTP header byte, as ``cflib.crtp.crtpstack.CRTPPacket`` builds it."""
    return ((port & 0x0F) << 4) | (0x3 << 2) | (channel & 0x03)


APP_HEADER = header(PORT_PLATFORM, APP_CHANNEL)
VERSION_HEADER = header(PORT_PLATFORM, VERSION_CHANNEL)
SUPERVISOR_HEADER = header(PORT_SUPERVISOR, SUPERVISOR_COMMAND_CHANNEL)
LEGACY_STOP_HEADER = header(PORT_LOCALIZATION, LOCALIZATION_GENERIC_CHANNEL)


def port_channel(head: int) -> tuple[int, int]:
    return (head >> 4) & 0x0F, head & 0x03


def same_port(a: int, b: int) -> bool:
    """Two headers address the same port and channel (cflib's radio driver toggles bits 2-3 for safelink)."""
    return port_channel(a) == port_channel(b)


def to_counts(fractions) -> tuple[int, ...]:
    """Normalized forces (fractions of full scale) as 16-bit counts, clipped to [0, 1]."""
    return tuple(int(v) for v in np.rint(np.clip(np.asarray(fractions, float), 0.0, 1.0) * FULL_SCALE))


def from_counts(counts) -> np.ndarray:
    """16-bit counts as normalized forces."""
    return np.asarray(counts, float) / FULL_SCALE


@dataclass(frozen=True, eq=False)
class MotorCommand:
    sequence: int
    """Sender's counter, mod 65536."""
    armed: bool
    counts: tuple[int, int, int, int]
    """Normalized forces of rotors q = 1..4, 0..65535."""
    token: int = 0
    """The owner's token the sender holds (0: none; the module drops such commands)."""

    def pack(self) -> bytes:
        return _COMMAND.pack(KIND_COMMAND, FLAG_ARMED if self.armed else 0, self.token, self.sequence & 0xFFFF,
                             *self.counts)

    @classmethod
    def unpack(cls, data: bytes) -> MotorCommand:
        if len(data) != _COMMAND.size or data[0] != KIND_COMMAND:
            raise ValueError(f"not a motor command: {bytes(data).hex()}")
        _, flags, token, seq, *counts = _COMMAND.unpack(data)
        return cls(seq, bool(flags & FLAG_ARMED), tuple(counts), token)


@dataclass(frozen=True)
class Claim:
    """Ground -> module: become its owner (answered by an :class:`Identity`)."""

    session: int
    """The ground station's session id, 1..2^32-1."""

    def pack(self) -> bytes:
        return _CLAIM.pack(KIND_CLAIM, self.session)

    @classmethod
    def unpack(cls, data: bytes) -> Claim | None:
        """The claim in ``data``, or None if it is not a valid one (as the app decodes it)."""
        if len(data) != _CLAIM.size or data[0] != KIND_CLAIM:
            return None
        session = _CLAIM.unpack(data)[1]
        return cls(session) if session else None


@dataclass(frozen=True, eq=False)
class Identity:
    """Module -> ground: who owns the module, which module it is, where gravity points in its frame."""

    flags: int
    """State flags (``STATE_*``)."""
    token: int
    """The owner's token (0: no owner)."""
    session: int
    """The owner's session id."""
    uid: tuple[int, int, int]
    """The MCU's unique id (``cpu.id0``, ``id1``, ``id2``)."""
    acc_mg: tuple[int, int, int]
    """Accelerometer, milli-g, module frame."""

    @property
    def gravity_up(self) -> np.ndarray:
        """The measured specific force as a unit vector in the module frame (at rest: up); zeros if none."""
        a = np.asarray(self.acc_mg, float)
        n = float(np.linalg.norm(a))
        return a / n if n > 0 else a

    @property
    def uid_hex(self) -> str:
        return "".join(f"{v:08x}" for v in self.uid)

    def pack(self) -> bytes:
        return _IDENTITY.pack(KIND_IDENTITY, self.flags, self.token, self.session, *self.uid, *self.acc_mg)

    @classmethod
    def unpack(cls, data: bytes) -> Identity:
        if len(data) != _IDENTITY.size or data[0] != KIND_IDENTITY:
            raise ValueError(f"not an identity report: {bytes(data).hex()}")
        _, flags, token, session, u0, u1, u2, ax, ay, az = _IDENTITY.unpack(data)
        return cls(flags, token, session, (u0, u1, u2), (ax, ay, az))


@dataclass(frozen=True, eq=False)
class BroadcastCommand:
    """Commands for up to four modules (consecutive ``motorApp.slot`` values) in one packet."""

    sequence: int
    armed: bool
    first_slot: int
    counts: tuple[tuple[int, int, int, int], ...]
    """Per module, normalized forces 0..65535 (sent with 12 bits)."""
    token: int = 0
    """The owner's token (one for all: a ground station claims every module it broadcasts to; the modules give
    their tokens, so a broadcast goes to modules that gave the same one)."""

    def pack(self) -> bytes:
        n = len(self.counts)
        if not 1 <= n <= BROADCAST_MAX_MODULES or not 0 <= self.first_slot <= 256 - n:
            raise ValueError(f"a broadcast carries 1..{BROADCAST_MAX_MODULES} modules within slots 0..255")
        flags = (FLAG_ARMED if self.armed else 0) | n << _BROADCAST_COUNT_SHIFT
        out = bytearray(_BROADCAST_HEADER.pack(KIND_BROADCAST, flags, self.sequence & 0xFFFF, self.first_slot,
                                               self.token))
        for module in self.counts:
            packed = 0
            for q, c in enumerate(module):
                packed |= (int(c) * BROADCAST_FULL_SCALE + FULL_SCALE // 2) // FULL_SCALE << (12 * q)
            out += packed.to_bytes(6, "little")
        return bytes(out)

    def for_slot(self, slot: int) -> MotorCommand | None:
        """What module ``slot`` applies (as the app decodes it), or None if the packet is not for it."""
        k = slot - self.first_slot
        if not 0 <= k < len(self.counts):
            return None
        packed = int.from_bytes(self.pack()[6 + 6 * k:12 + 6 * k], "little")
        twelve = [(packed >> (12 * q)) & 0xFFF for q in range(4)]
        return MotorCommand(self.sequence & 0xFFFF, self.armed,
                            tuple((v * FULL_SCALE + BROADCAST_FULL_SCALE // 2) // BROADCAST_FULL_SCALE
                                  for v in twelve), self.token)


@dataclass(frozen=True, eq=False)
class ModuleState:
    flags: int
    sequence: int
    """Sequence of the newest command the module accepted."""
    counts: tuple[int, int, int, int]
    """Motor ratios that reach the motors (``motorsGetRatio``), 0..65535."""
    battery_mv: int
    gyro: tuple[float, float, float]
    """Module body frame, rad/s."""
    received: int
    """Commands accepted, mod 65536."""
    dropped: int
    """Commands not applied (older than the newest, malformed, lost to a full queue), mod 65536."""

    @property
    def armed(self) -> bool:
        return bool(self.flags & STATE_ARMED)

    @property
    def locked(self) -> bool:
        """The supervisor is locked (emergency stop or commander watchdog): the module must be rebooted."""
        return bool(self.flags & STATE_LOCKED)

    @property
    def supervisor_armed(self) -> bool:
        return bool(self.flags & STATE_SUPERVISOR_ARMED)

    @property
    def fresh(self) -> bool:
        return bool(self.flags & STATE_FRESH)

    @property
    def can_fly(self) -> bool:
        """The supervisor lets flight commands through (armed, past the brushless RPM check, not tumbled)."""
        return bool(self.flags & STATE_CAN_FLY)

    @property
    def flying(self) -> bool:
        """The supervisor's Flying (or WarningLevelOut) state: a motor over idle in the last 2 s. A module left
        there without commands levels out after 0.5 s and locks after 2 s (its commander watchdog)."""
        return bool(self.flags & STATE_FLYING)

    @property
    def battery_v(self) -> float:
        return self.battery_mv / 1000.0

    def pack(self) -> bytes:
        return _STATE.pack(KIND_STATE, self.flags, self.sequence & 0xFFFF, *self.counts, self.battery_mv,
                           *self.gyro, self.received & 0xFFFF, self.dropped & 0xFFFF)

    @classmethod
    def unpack(cls, data: bytes) -> ModuleState:
        if len(data) != _STATE.size or data[0] != KIND_STATE:
            raise ValueError(f"not a module state: {bytes(data).hex()}")
        _, flags, seq, c0, c1, c2, c3, mv, gx, gy, gz, received, dropped = _STATE.unpack(data)
        return cls(flags, seq, (c0, c1, c2, c3), mv, (gx, gy, gz), received, dropped)


def arm_request(do_arm: bool) -> bytes:
    """Supervisor arming (or disarming) request, as ``cf.supervisor.send_arming_request``."""
    return bytes([CMD_ARM_SYSTEM, 1 if do_arm else 0])


def arm_response(data: bytes) -> tuple[bool, bool] | None:
    """(granted, armed) from a supervisor reply, or None if ``data`` is not the answer to an arming request."""
    if len(data) >= 3 and data[0] == CMD_RESPONSE | CMD_ARM_SYSTEM:
        return bool(data[1]), bool(data[2])
    return None


def version_reply(data: bytes) -> int | None:
    """The CRTP protocol version from a platform version reply, or None."""
    if len(data) >= _VERSION_REPLY.size and data[0] == GET_PROTOCOL_VERSION:
        return _VERSION_REPLY.unpack_from(data)[1]
    return None


# -- the vectors shared with the C app ----------------------------------------------------------------------------
def _command_vectors() -> list[tuple[int, bytes, str, MotorCommand | None]]:
    """(slot, payload, status the app must report, the command it must decode)."""
    out = []
    for cmd in (MotorCommand(0, False, (0, 0, 0, 0)), MotorCommand(1, True, (0, 1, 32768, 65535), 1),
                MotorCommand(0xBEEF, True, (12345, 54321, 1000, 65000), 0xA5),
                MotorCommand(65535, False, (1, 2, 3, 4), 255)):
        out.append((0, cmd.pack(), "OK", cmd))
    bc = BroadcastCommand(0x1234, True, 2, ((0, 65535, 32768, 16), (65535, 0, 0, 65535), (100, 200, 300, 400)), 7)
    for slot in (2, 3, 4):
        out.append((slot, bc.pack(), "OK", bc.for_slot(slot)))
    out.append((1, bc.pack(), "NOT_FOR_US", None))
    out.append((5, bc.pack(), "NOT_FOR_US", None))
    good = MotorCommand(7, True, (1, 2, 3, 4)).pack()
    out.append((0, good[:-1], "BAD_LENGTH", None))
    out.append((0, good + b"\x00", "BAD_LENGTH", None))
    out.append((0, bytes([0x42]) + good[1:], "BAD_KIND", None))
    out.append((0, bytes([KIND_STATE]) + good[1:], "BAD_KIND", None))
    out.append((0, bc.pack()[:-1], "BAD_LENGTH", None))
    return out


CLAIM_VECTORS = (  # (payload, the session the app must decode, or None: not a claim)
    (Claim(1).pack(), 1), (Claim(0xDEADBEEF).pack(), 0xDEADBEEF), (Claim(0).pack(), None),
    (Claim(5).pack()[:-1], None), (Claim(5).pack() + b"\x00", None),
    (bytes([KIND_COMMAND]) + Claim(5).pack()[1:], None),
)

IDENTITY_VECTORS = (
    Identity(0, 0, 0, (0, 0, 0), (0, 0, 0)),
    Identity(STATE_SUPERVISOR_ARMED | STATE_CAN_FLY, 3, 0xA1B2C3D4, (0x00370041, 0x3236510D, 0x38383432),
             (-17, 342, -1000)),
    Identity(0xFF, 255, 0xFFFFFFFF, (0xFFFFFFFF, 1, 0x80000000), (32767, -32767, 1000)),
)

STATE_VECTORS = (
    ModuleState(0, 0, (0, 0, 0, 0), 0, (0.0, 0.0, 0.0), 0, 0),
    ModuleState(STATE_ARMED | STATE_SUPERVISOR_ARMED | STATE_FRESH | STATE_CAN_FLY | STATE_FLYING, 258,
                (1, 2, 65535, 32768), 3987, (0.5, -0.25, 1.0), 7, 43981),
    ModuleState(STATE_LOCKED, 65535, (65535, 65535, 65535, 65535), 16800, (3.1415927, -34.9, 1e-3), 65535, 1),
)


def vectors_text() -> str:
    """The vector file ``firmware/crazyflie_app/test/packet_vectors.txt``: encoded here, decoded by the C app."""
    lines = ["# Packet vectors shared by groundstation/backends/crtp_wire.py (which writes them: vectors_text())",
             "# and firmware/crazyflie_app/test/vector_check.c (which decodes the commands and re-encodes the",
             "# states). Regenerate with: python -m groundstation.backends.crtp_wire > <this file>"]
    for slot, payload, status, cmd in _command_vectors():
        fields = f"command slot={slot} status={status}"
        if cmd is not None:
            fields += (f" seq={cmd.sequence} armed={int(cmd.armed)} token={cmd.token} "
                       f"counts={','.join(map(str, cmd.counts))}")
        lines.append(f"{fields} hex={payload.hex()}")
    for payload, session in CLAIM_VECTORS:
        lines.append(f"claim valid={int(session is not None)} session={session or 0} hex={payload.hex()}")
    for ident in IDENTITY_VECTORS:
        lines.append(f"identity flags={ident.flags} token={ident.token} session={ident.session} "
                     f"uid={','.join(map(str, ident.uid))} acc_mg={','.join(map(str, ident.acc_mg))} "
                     f"hex={ident.pack().hex()}")
    for st in STATE_VECTORS:
        gyro = ",".join(repr(float(np.float32(g))) for g in st.gyro)  # exactly the float32 sent
        lines.append(f"state flags={st.flags} seq={st.sequence} counts={','.join(map(str, st.counts))} "
                     f"battery_mv={st.battery_mv} gyro={gyro} received={st.received} dropped={st.dropped} "
                     f"hex={st.pack().hex()}")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(vectors_text(), end="")
