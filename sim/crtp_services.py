"""The Crazyflie firmware services cflib's ``Crazyflie`` class talks to while connecting, and the parameter service.

A simulated module answers them so the real cflib (``Crazyflie.open_link``, ``param.get_value``,
``param.set_value``) connects to it and reads and writes its parameters over UDP, as with hardware. Packets follow
crazyflie-firmware's CRTP services as cflib 0.1.3x expects them:

* link control (port 15, channel 1): the sink request ``0x00`` is answered with ``"Bitcraze Crazyflie"``;
* logging (port 5): reset (channel 1, ``[5]`` -> ``[5, 0, 0]``), then an empty TOC (channel 0);
* memories (port 4, channel 0): none;
* parameters (port 2): TOC v2 on channel 0 (``[3]`` -> count and CRC, ``[2, id]`` -> type byte, group, name;
  the type byte carries 0x40 for read-only and 0x10 for "extended", i.e. persistent), read on channel 1
  (``[id]`` -> ``[id, status 0, value]``), write on channel 2 (``[id, value]`` -> the same packet back once
  applied; a read-only parameter is silently not written, as the firmware does), and on the misc channel 3 the
  extended type (``[7, id]`` -> ``[7, id, 0, 1 = persistent]``), the persistent store (``[3, id]`` ->
  ``[3, id, 0]``) and its state (``[4, id]`` -> ``[4, id, stored 1 / not 0, default value, stored value if
  stored]``, as ``paramPersistentGetState``). Ids are little-endian uint16. A reboot
  (:meth:`FirmwareServices.reboot`) restores the defaults, then the stored values.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

PORT_PARAM, PORT_MEM, PORT_LOG, PORT_LINKCTRL = 0x02, 0x04, 0x05, 0x0F
MAGIC = b"Bitcraze Crazyflie"
CMD_TOC_ITEM_V2, CMD_TOC_INFO_V2 = 2, 3
CMD_MEM_INFO_NBR = 1
CMD_RESET_LOGGING = 5
PARAM_MISC_CHANNEL = 3
MISC_PERSISTENT_STORE, MISC_PERSISTENT_GET_STATE, MISC_GET_EXTENDED_TYPE_V2 = 3, 4, 7
TOC_READ_ONLY, TOC_EXTENDED = 0x40, 0x10
EXTENDED_PERSISTENT = 1
ENOENT = 2
TYPES = {"uint8": (0x08, "<B"), "uint16": (0x09, "<H"), "int32": (0x02, "<i"), "float": (0x06, "<f")}
"""Parameter types: cflib's TOC type code and struct format."""


@dataclass
class FirmwareParam:
    group: str
    name: str
    ctype: str
    """One of :data:`TYPES`."""
    default: float
    """Value after boot, unless a stored value replaces it."""
    persistent: bool = False
    read_only: bool = False

    def __post_init__(self) -> None:
        self.value = self.default

    @property
    def toc_type(self) -> int:
        return (TYPES[self.ctype][0] | (TOC_READ_ONLY if self.read_only else 0)
                | (TOC_EXTENDED if self.persistent else 0))


class FirmwareServices:
    """Answers one module's connection-setup and parameter packets; :meth:`handle` returns the replies."""

    def __init__(self, params: list[FirmwareParam]) -> None:
        self.params = params
        self.stored: dict[str, float] = {}
        """Persistent parameters stored in the module's EEPROM: name -> value."""
        names = b"".join(f"{p.group}.{p.name}:{p.ctype}:{p.toc_type}".encode() for p in params)
        self._crc = zlib.crc32(names)

    def _param(self, complete_name: str) -> FirmwareParam:
        for p in self.params:
            if f"{p.group}.{p.name}" == complete_name:
                return p
        raise ValueError(f"a simulated Crazyflie has no parameter {complete_name}")

    def value(self, complete_name: str) -> float:
        return self._param(complete_name).value

    def set(self, complete_name: str, value: float) -> None:
        p = self._param(complete_name)
        p.value = float(value) if p.ctype == "float" else int(round(value))

    def is_persistent(self, complete_name: str) -> bool:
        return self._param(complete_name).persistent

    def store(self, complete_name: str) -> None:
        """Store a persistent parameter's current value (it survives a reboot)."""
        p = self._param(complete_name)
        if not p.persistent:
            raise ValueError(f"{complete_name} is not a persistent parameter")
        self.stored[complete_name] = p.value

    def reboot(self) -> None:
        """Defaults, then the stored values, as at boot."""
        for p in self.params:
            p.value = self.stored.get(f"{p.group}.{p.name}", p.default)

    def handle(self, head: int, body: bytes) -> list[bytes] | None:
        """Replies (whole CRTP packets) to one packet, or None if it is not for these services."""
        port, channel = (head >> 4) & 0x0F, head & 0x03
        if port == PORT_LINKCTRL and channel == 1 and body[:1] == b"\x00":
            return [bytes([head]) + MAGIC]
        if port == PORT_LOG and channel == 1 and body[:1] == bytes([CMD_RESET_LOGGING]):
            return [bytes([head, CMD_RESET_LOGGING, 0, 0])]
        if port == PORT_LOG and channel == 0 and body[:1] == bytes([CMD_TOC_INFO_V2]):
            return [bytes([head, CMD_TOC_INFO_V2]) + struct.pack("<HI", 0, 0)]
        if port == PORT_MEM and channel == 0 and body[:1] == bytes([CMD_MEM_INFO_NBR]):
            return [bytes([head, CMD_MEM_INFO_NBR, 0])]
        if port == PORT_PARAM:
            return self._param_service(head, channel, body)
        return None

    def _param_service(self, head: int, channel: int, body: bytes) -> list[bytes]:
        if channel == 0 and body[:1] == bytes([CMD_TOC_INFO_V2]):
            return [bytes([head, CMD_TOC_INFO_V2]) + struct.pack("<HI", len(self.params), self._crc)]
        if channel == 0 and body[:1] == bytes([CMD_TOC_ITEM_V2]) and len(body) >= 3:
            ident = struct.unpack("<H", body[1:3])[0]
            if ident >= len(self.params):
                return []
            p = self.params[ident]
            item = bytes([p.toc_type]) + p.group.encode() + b"\x00" + p.name.encode() + b"\x00"
            return [bytes([head]) + body[:3] + item]
        if channel == PARAM_MISC_CHANNEL and len(body) >= 3:
            return self._misc(head, body)
        if channel in (1, 2) and len(body) >= 2:
            ident = struct.unpack("<H", body[:2])[0]
            if ident >= len(self.params):
                return []
            p = self.params[ident]
            fmt = TYPES[p.ctype][1]
            if channel == 2:  # write: apply, then echo (cflib reads the echo as the new value)
                if p.read_only:
                    return []  # the firmware ignores it without an answer
                p.value = struct.unpack(fmt, body[2:2 + struct.calcsize(fmt)])[0]
                return [bytes([head]) + body[:2] + struct.pack(fmt, p.value)]
            return [bytes([head]) + body[:2] + b"\x00" + struct.pack(fmt, p.value)]
        return []

    def _misc(self, head: int, body: bytes) -> list[bytes]:
        cmd, ident = body[0], struct.unpack("<H", body[1:3])[0]
        p = self.params[ident] if ident < len(self.params) else None
        if cmd == MISC_GET_EXTENDED_TYPE_V2:
            if p is None or not p.persistent:
                return [bytes([head]) + body[:3] + bytes([ENOENT])]
            return [bytes([head]) + body[:3] + bytes([0, EXTENDED_PERSISTENT])]
        if cmd == MISC_PERSISTENT_STORE:
            if p is None or not p.persistent:
                return [bytes([head]) + body[:3] + bytes([ENOENT])]
            self.stored[f"{p.group}.{p.name}"] = p.value
            return [bytes([head]) + body[:3] + bytes([0])]
        if cmd == MISC_PERSISTENT_GET_STATE:
            if p is None or not p.persistent:
                return [bytes([head]) + body[:3] + bytes([ENOENT])]
            fmt = TYPES[p.ctype][1]
            stored = self.stored.get(f"{p.group}.{p.name}")
            state = bytes([1 if stored is not None else 0]) + struct.pack(fmt, p.default)
            return [bytes([head]) + body[:3] + state + (struct.pack(fmt, stored) if stored is not None else b"")]
        return []
