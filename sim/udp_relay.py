"""A loopback UDP relay that delays, drops, duplicates and reorders packets: link faults injected for real.

    python -m sim.udp_relay --listen 19950 --target 19850 --links 2 --delay-ms 30 [--loss 0.02]
                            [--duplicate 0.2] [--reorder 0.2 --reorder-ms 10] [--after 6] [--seed 1]
                            [--answer-timesync] [--swap-after 8 [--swap-way answers] [--swap-every 0.06]]

Link i relays ``127.0.0.1:<listen + i>`` (what the ground station talks to) to ``127.0.0.1:<target + i>`` (a
simulated module from ``groundstation sim-peer``) and the replies back. Every packet, in either direction, is
delayed by ``--delay-ms``; lost with probability ``--loss``; sent twice with ``--duplicate``; and with
``--reorder`` held back a further ``--reorder-ms`` so that later packets overtake it. Faults start ``--after``
seconds after the first packet (a link that degrades mid-flight). With ``--answer-timesync`` (MAVLink links) the
relay, once its faults start, answers the ground station's ``TIMESYNC`` probes itself at once, on the module's
clock as the module's newest ``ATTITUDE`` showed it, and keeps them from the module: a hostile relay hiding what it
holds back. With ``--swap-after`` the links trade places that long after the first packet: link i then reaches
module i + 1 (the last, module 0), both ways, or with ``--swap-way`` only the commands' way (link i's packets go to
module i + 1, whose answers still come on link i + 1) or only the answers' (module i's answers come on link i - 1,
the commands still reach their module); with ``--swap-every`` they swap back and again that often. Runs until
SIGTERM/SIGINT and then prints how many packets it relayed, dropped, duplicated, reordered and answered as one JSON
line.
"""

from __future__ import annotations

import argparse
import heapq
import json
import select
import signal
import socket
import sys
import time
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Faults:
    delay_s: float = 0.0
    """Added one-way delay of every packet, s."""
    loss: float = 0.0
    """Probability a packet is dropped."""
    duplicate: float = 0.0
    """Probability a packet is sent twice."""
    reorder: float = 0.0
    """Probability a packet is held back by ``reorder_s`` more (later ones overtake it)."""
    reorder_s: float = 0.01
    after_s: float = 0.0
    """Faults start this long after the first packet, s."""
    answer_timesync: bool = False
    """Answer MAVLink ``TIMESYNC`` probes in the module's name (see the module docstring)."""
    swap_after_s: float = float("inf")
    """The links trade places this long after the first packet, s (see the module docstring)."""
    swap_way: str = "both"
    """Which way the swap takes: "both", "commands" or "answers"."""
    swap_every_s: float = 0.0
    """With a swap: back, and again, every this long (0: swapped for good), s."""


@dataclass
class Counts:
    relayed: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    answered: int = 0
    queue: list = field(default_factory=list, repr=False)


class _ClockForger:
    """One MAVLink link's forger: learns the module (system id, ``time_boot_ms`` and when it came) from what it sends,
    and answers a probe (``tc1`` 0) in its name on that clock advanced by the time since."""

    def __init__(self) -> None:
        from pymavlink import mavutil

        self._mavlink = mavutil.mavlink
        self._down = mavutil.mavlink.MAVLink(None)
        self._up = mavutil.mavlink.MAVLink(None)
        self._down.robust_parsing = self._up.robust_parsing = True
        self._module: tuple[int, float, float] | None = None
        """(system id, its time_boot_ms in ms, when that arrived here on ``time.monotonic``)."""

    def from_module(self, data: bytes, now: float) -> None:
        for msg in self._down.parse_buffer(data) or ():
            if msg.get_type() == "ATTITUDE":
                self._module = (msg.get_srcSystem(), float(msg.time_boot_ms), now)

    def answer(self, data: bytes, now: float) -> bytes | None:
        """The forged answer to ``data`` if it is a probe and the module's clock is known (else None)."""
        probes = [m for m in self._up.parse_buffer(data) or () if m.get_type() == "TIMESYNC" and m.tc1 == 0]
        if not probes or self._module is None:
            return None
        system, boot_ms, seen = self._module
        as_module = self._mavlink.MAVLink(None, srcSystem=system, srcComponent=self._mavlink.MAV_COMP_ID_AUTOPILOT1)
        tc1 = int((boot_ms + (now - seen) * 1e3) * 1e6)
        return as_module.timesync_encode(tc1, probes[-1].ts1).pack(as_module)


class UdpRelay:
    """``links`` relays on loopback; :meth:`run` serves them until :meth:`stop`."""

    def __init__(self, listen_port: int, target_port: int, links: int, faults: Faults, seed: int = 0,
                 host: str = "127.0.0.1") -> None:
        self.faults = faults
        self.counts = Counts()
        self._rng = np.random.default_rng(seed)
        self._front, self._back, self._client = [], [], [None] * links
        self._targets = [(host, target_port + i) for i in range(links)]
        for i in range(links):
            front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            front.bind((host, listen_port + i))
            back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            back.bind((host, 0))
            self._front.append(front)
            self._back.append(back)
        self._started: float | None = None
        self._running = True
        self._seq = 0
        self._forgers = [_ClockForger() for _ in range(links)] if faults.answer_timesync else []

    def stop(self, *_) -> None:
        self._running = False

    def _schedule(self, now: float, sock: socket.socket, data: bytes, addr) -> None:
        f = self.faults
        active = self._started is not None and now - self._started >= f.after_s
        if active and self._rng.random() < f.loss:
            self.counts.dropped += 1
            return
        delay = f.delay_s if active else 0.0
        copies = 2 if active and self._rng.random() < f.duplicate else 1
        self.counts.duplicated += copies - 1
        if active and self._rng.random() < f.reorder:
            delay += f.reorder_s
            self.counts.reordered += 1
        for _ in range(copies):
            self._seq += 1
            heapq.heappush(self.counts.queue, (now + delay, self._seq, sock, data, addr))

    def _forged(self, link: int, data: bytes, now: float) -> bytes | None:
        if not self._forgers or self._started is None or now - self._started < self.faults.after_s:
            return None
        return self._forgers[link].answer(data, now)

    def _swapped(self, now: float) -> tuple[int, int]:
        """(commands' way, answers' way): 1 where link i reaches module i + 1 that way, else 0."""
        since = now - self._started - self.faults.swap_after_s if self._started is not None else -1.0
        on = int(since >= 0.0)
        if on and self.faults.swap_every_s > 0.0:  # swapped, back, swapped...
            on = 1 - int(since / self.faults.swap_every_s) % 2
        way = self.faults.swap_way
        return on * (way in ("both", "commands")), on * (way in ("both", "answers"))

    def run(self) -> Counts:
        socks = self._front + self._back
        while self._running:
            q = self.counts.queue
            timeout = max(0.0, q[0][0] - time.monotonic()) if q else 0.05
            ready, _, _ = select.select(socks, [], [], min(timeout, 0.05))
            now = time.monotonic()
            for s in ready:
                try:
                    data, addr = s.recvfrom(2048)
                except OSError:
                    continue
                self._started = now if self._started is None else self._started
                if s in self._front:
                    i = self._front.index(s)
                    self._client[i] = addr
                    forged = self._forged(i, data, now)
                    if forged is not None:
                        s.sendto(forged, addr)
                        self.counts.answered += 1
                    else:  # to module i, or i + 1 when the commands' way is swapped, from its own socket
                        t = (i + self._swapped(now)[0]) % len(self._targets)
                        self._schedule(now, self._back[t], data, self._targets[t])
                else:
                    i = self._back.index(s)  # module i's
                    if self._forgers:
                        self._forgers[i].from_module(data, now)
                    f = (i - self._swapped(now)[1]) % len(self._front)
                    if self._client[f] is not None:
                        self._schedule(now, self._front[f], data, self._client[f])
            while q and q[0][0] <= time.monotonic():
                _, _, sock, data, addr = heapq.heappop(q)
                try:
                    sock.sendto(data, addr)
                    self.counts.relayed += 1
                except OSError:
                    self.counts.dropped += 1
        for s in socks:
            s.close()
        return self.counts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--listen", type=int, required=True, help="first port the ground station talks to")
    ap.add_argument("--target", type=int, required=True, help="first port of the simulated modules")
    ap.add_argument("--links", type=int, default=1)
    ap.add_argument("--delay-ms", type=float, default=0.0)
    ap.add_argument("--loss", type=float, default=0.0)
    ap.add_argument("--duplicate", type=float, default=0.0)
    ap.add_argument("--reorder", type=float, default=0.0)
    ap.add_argument("--reorder-ms", type=float, default=10.0)
    ap.add_argument("--after", type=float, default=0.0, help="faults start this long after the first packet, s")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--answer-timesync", action="store_true",
                    help="answer MAVLink TIMESYNC probes in the module's name, on its clock (a hostile relay)")
    ap.add_argument("--swap-after", type=float, default=float("inf"),
                    help="the links trade places this long after the first packet, s (link i reaches module i+1)")
    ap.add_argument("--swap-way", choices=("both", "commands", "answers"), default="both",
                    help="which way --swap-after swaps: both, only the commands' or only the answers'")
    ap.add_argument("--swap-every", type=float, default=0.0,
                    help="after --swap-after, swap back and again every this long, s (0: swapped for good)")
    a = ap.parse_args(argv)
    relay = UdpRelay(a.listen, a.target, a.links,
                     Faults(a.delay_ms * 1e-3, a.loss, a.duplicate, a.reorder, a.reorder_ms * 1e-3, a.after,
                            a.answer_timesync, a.swap_after, a.swap_way, a.swap_every), a.seed)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, relay.stop)
    c = relay.run()
    print(json.dumps({"relayed": c.relayed, "dropped": c.dropped, "duplicated": c.duplicated,
                      "reordered": c.reordered, "answered": c.answered}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
