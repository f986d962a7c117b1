"""An emulated Crazyradio dongle under cflib's real radio driver, relaying to simulated modules on UDP.

No dongle can be plugged in here, so this stands in for the one piece that cannot run: the USB device. cflib's
``RadioDriver``, its per-dongle ``_SharedRadio`` thread, the link threads that poll with null packets, and the
Crazyflie backend above them all run unchanged. Each transaction takes ``transaction_s`` (2.1 ms by default:
Bitcraze's ~450-500 round trips a second per dongle) and is serialized per dongle as on the real one. A packet
to radio address ``..XX`` goes to the simulated module on UDP port ``base_port + XX`` (``groundstation sim-peer``
module ``XX``); the acknowledgement carries at most one packet the module has sent since, as the nRF firmware's
ack payload does. Safelink is not emulated (the driver falls back to repeating unanswered requests).

    with emulated_crazyradios(base_port=19850):
        ...  # radio://0/80/2M/E7E7E7E700, radio://1/80/2M/E7E7E7E701 reach sim-peer modules 0 and 1
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator

SAFELINK_ENABLE = (0xFF, 0x05, 0x01)


class _Ack:
    """What ``Crazyradio.send_packet`` returns (``cflib.drivers.crazyradio._radio_ack``)."""

    def __init__(self, ack: bool, data: tuple = ()) -> None:
        self.ack = ack
        self.powerDet = False
        self.retry = 0
        self.data = data


class EmulatedCrazyradio:
    """The subset of ``cflib.drivers.crazyradio.Crazyradio`` that cflib's radio driver uses."""

    DR_250KPS, DR_1MPS, DR_2MPS = 0, 1, 2
    base_port = 19850
    transaction_s = 0.0021
    gate: threading.Event | None = None
    """If set, every transaction waits for it (a stalled dongle, for tests)."""
    transactions: dict[int, int] = {}
    """Transactions per dongle index, since the class was configured."""

    def __init__(self, device=None, devid: int = 0, serial=None) -> None:
        self.devid = devid
        self.version = 0.5
        self.address = (0xE7,) * 5
        self.arc = 3
        self._socks: dict[int, socket.socket] = {}

    def set_channel(self, channel: int) -> None:
        self.channel = channel

    def set_address(self, address) -> None:
        self.address = tuple(address)

    def set_data_rate(self, datarate: int) -> None:
        self.datarate = datarate

    def set_arc(self, arc: int) -> None:
        self.arc = arc

    def set_ack_enable(self, enable: bool) -> None:
        self.ack_enable = enable

    def _sock(self, module: int) -> socket.socket:
        if module not in self._socks:
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", 0))
            s.setblocking(False)
            self._socks[module] = s
        return self._socks[module]

    def send_packet(self, data) -> _Ack:
        if self.gate is not None:
            self.gate.wait()
        time.sleep(self.transaction_s)
        type(self).transactions[self.devid] = type(self).transactions.get(self.devid, 0) + 1
        data = tuple(data)
        if data == SAFELINK_ENABLE:
            return _Ack(True)  # no echo: cflib runs the link without safelink
        module = self.address[-1]
        sock = self._sock(module)
        if data and data[0] != 0xFF:
            # The nRF hands the packet to the STM32 with the link-layer bits (2-3 of the header) cleared to 1s.
            with contextlib.suppress(OSError):
                sock.sendto(bytes([data[0] | 0x0C]) + bytes(data[1:]), ("127.0.0.1", self.base_port + module))
        try:
            reply = sock.recv(64)
        except (BlockingIOError, InterruptedError):
            return _Ack(True)
        return _Ack(True, tuple(reply))

    def close(self) -> None:
        for s in self._socks.values():
            s.close()
        self._socks = {}


@contextlib.contextmanager
def emulated_crazyradios(base_port: int, transaction_s: float = 0.0021) -> Iterator[type[EmulatedCrazyradio]]:
    """cflib's radio driver talks to emulated dongles for the block (every ``radio://N`` is a dongle)."""
    import cflib.crtp.radiodriver as radiodriver

    saved = radiodriver.Crazyradio
    radiodriver.Crazyradio = EmulatedCrazyradio
    EmulatedCrazyradio.base_port = base_port
    EmulatedCrazyradio.transaction_s = transaction_s
    EmulatedCrazyradio.transactions = {}
    EmulatedCrazyradio.gate = None
    radiodriver.RadioManager._radios = []
    try:
        yield EmulatedCrazyradio
    finally:
        radiodriver.Crazyradio = saved
        radiodriver.RadioManager._radios = []
