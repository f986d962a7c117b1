"""The Crazyflie firmware services cflib's ``Crazyflie`` class talks to while connecting, and the parameter service.

A simulated module answers them so the real cflib (``Crazyflie.open_link``, ``param.get_value``,
``param.set_value``) connects to it and reads and writes its parameters over UDP, as with hardware. Packets follow
crazyflie-firmware's CRTP services as cflib 0.1.3x expects them:

* link control (port 15, channel 1): the sink request ``0x00`` is answered with ``"Bitcraze Crazyflie"``;
* platform version (port 13, channel 1): ``[0]`` -> ``[0, protocol version]`` (7: TOC v2, no extended types);
* logging (port 5): reset (channel 1, ``[5]`` -> ``[5, 0, 0]``), then an empty TOC (channel 0);
* memories (port 4, channel 0): none;
* parameters (port 2): TOC v2 on channel 0 (``[3]`` -> count and CRC, ``[2, id]`` -> type byte, group, name),
  read on channel 1 (``[id]`` -> ``[id, status 0, value]``), write on channel 2 (``[id, value]`` -> the same
  packet back once applied). Ids are little-endian uint16.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

PORT_PARAM, PORT_MEM, PORT_LOG, PORT_PLATFORM, PORT_LINKCTRL = 0x02, 0x04, 0x05, 0x0D, 0x0F
PROTOCOL_VERSION = 7
MAGIC = b"Bitcraze Crazyflie"
CMD_TOC_ITEM_V2, CMD_TOC_INFO_V2 = 2, 3
CMD_MEM_INFO_NBR = 1
CMD_RESET_LOGGING = 5
TYPES = {"uint8": (0x08, "<B"), "uint16": (0x09, "<H"), "int32": (0x02, "<i"), "float": (0x06, "<f")}
"""Parameter types: cflib's TOC type code and struct format."""


@dataclass
class FirmwareParam:
    group: str
    name: str
    ctype: str
    """One of :data:`TYPES`."""
    value: float


def stock_params() -> list[FirmwareParam]:
    """The parameters ``firmware_params/crazyflie.toml`` sets, at stock firmware values (what a fresh module has)."""
    return [FirmwareParam("supervisor", "tmblChckEn", "uint8", 1),
            FirmwareParam("stabilizer", "controller", "uint8", 0),
            FirmwareParam("motorPowerSet", "enable", "uint8", 0)]


class FirmwareServices:
    """Answers one module's connection-setup and parameter packets; :meth:`handle` returns the replies."""

    def __init__(self, params: list[FirmwareParam]) -> None:
        self.params = params
        names = b"".join(f"{p.group}.{p.name}:{p.ctype}".encode() for p in params)
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

    def handle(self, head: int, body: bytes) -> list[bytes] | None:
        """Replies (whole CRTP packets) to one packet, or None if it is not for these services."""
        port, channel = (head >> 4) & 0x0F, head & 0x03
        if port == PORT_LINKCTRL and channel == 1 and body[:1] == b"\x00":
            return [bytes([head]) + MAGIC]
        if port == PORT_PLATFORM and channel == 1 and body[:1] == b"\x00":
            return [bytes([head, 0, PROTOCOL_VERSION])]
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
            item = bytes([TYPES[p.ctype][0]]) + p.group.encode() + b"\x00" + p.name.encode() + b"\x00"
            return [bytes([head]) + body[:3] + item]
        if channel in (1, 2) and len(body) >= 2:
            ident = struct.unpack("<H", body[:2])[0]
            if ident >= len(self.params):
                return []
            p = self.params[ident]
            fmt = TYPES[p.ctype][1]
            if channel == 2:  # write: apply, then echo (cflib reads the echo as the new value)
                p.value = struct.unpack(fmt, body[2:2 + struct.calcsize(fmt)])[0]
                return [bytes([head]) + body[:2] + struct.pack(fmt, p.value)]
            return [bytes([head]) + body[:2] + b"\x00" + struct.pack(fmt, p.value)]
        return []
