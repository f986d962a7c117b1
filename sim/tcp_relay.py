"""A loopback TCP relay that breaks its connections on a schedule: a lab network cable pulled and put back.

    python -m sim.tcp_relay --listen 7530 --target 7531 --cut-at 6.0 --cut-for 0.3

Relays every connection to ``127.0.0.1:<listen>`` (what the ground station's Zenoh session connects to) to
``127.0.0.1:<target>`` (where the mocap publisher listens), both ways. ``--cut-at`` seconds after the first
connection, or when it gets SIGUSR1, it resets every connection (the peers see the link go down at once) and
refuses new ones for ``--cut-for`` seconds; then it accepts again and the peers reconnect on their own. From
SIGUSR2 on, what the target sends is held back by a delay that grows at ``--delay-growth`` ms per s up to
``--delay-max`` ms, in order (a man in the middle slowing the mocap stream too gradually to be a step). Runs until
SIGTERM/SIGINT and then prints one JSON line: connections accepted, refused during the cut, bytes relayed, when
the cut began and ended and when the delay began (s after the first connection).
"""

from __future__ import annotations

import argparse
import collections
import json
import select
import signal
import socket
import struct
import sys
import time


class TcpRelay:
    """See the module docstring; :meth:`run` serves until :meth:`stop`."""

    def __init__(self, listen_port: int, target_port: int, cut_at: float, cut_for: float,
                 host: str = "127.0.0.1", delay_growth: float = 0.0, max_delay: float = 0.0) -> None:
        self._target = (host, target_port)
        self._server = socket.create_server((host, listen_port), reuse_port=False)
        self._server.setblocking(False)
        self._pairs: dict[socket.socket, socket.socket] = {}
        self._cut_at, self._cut_for = cut_at, cut_for
        self._t0: float | None = None
        self._running = True
        self._from_target: set[socket.socket] = set()
        self._growth, self._max_delay = delay_growth, max_delay
        self._delay_since: float | None = None
        self._held: collections.deque[tuple[float, socket.socket, bytes]] = collections.deque()
        """(when due, to, data) held back by the delay, in order (the delay never shrinks)."""
        self.stats = {"accepted": 0, "refused": 0, "bytes": 0, "cut_began_s": None, "cut_ended_s": None,
                      "delay_began_s": None}

    def stop(self, *_args) -> None:
        self._running = False

    def cut_now(self, *_args) -> None:
        """Begin the cut now (a signal handler: SIGUSR1)."""
        self._cut_at = self._elapsed()

    def delay_now(self, *_args) -> None:
        """Begin the growing delay now (a signal handler: SIGUSR2)."""
        self._delay_since = time.monotonic()
        self.stats["delay_began_s"] = round(self._elapsed(), 4)

    def _delay(self) -> float:
        """What the target sends now is held back this long, s."""
        if self._delay_since is None:
            return 0.0
        return min(self._max_delay, self._growth * (time.monotonic() - self._delay_since))

    def _send(self, peer: socket.socket, data: bytes) -> None:
        if peer.fileno() < 0:  # closed meanwhile (a cut, the other side gone)
            return
        peer.setblocking(True)
        try:
            peer.sendall(data)
            self.stats["bytes"] += len(data)
        except OSError:
            pass
        finally:
            if peer.fileno() >= 0:
                peer.setblocking(False)

    def _send_due(self) -> None:
        now = time.monotonic()
        while self._held and self._held[0][0] <= now:
            _, peer, data = self._held.popleft()
            self._send(peer, data)

    def _elapsed(self) -> float:
        return 0.0 if self._t0 is None else time.monotonic() - self._t0

    def _in_cut(self) -> bool:
        return self._t0 is not None and self._cut_at <= self._elapsed() < self._cut_at + self._cut_for

    def _reset_all(self) -> None:
        linger = struct.pack("ii", 1, 0)  # close with RST, as a pulled cable looks to a peer that sends next
        for s in list(self._pairs):
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, linger)
            s.close()
        self._pairs.clear()
        self._from_target.clear()
        self._held.clear()

    def _accept(self) -> None:
        try:
            client, _ = self._server.accept()
        except BlockingIOError:
            return
        if self._in_cut():
            self.stats["refused"] += 1
            client.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            client.close()
            return
        try:
            upstream = socket.create_connection(self._target, timeout=1.0)
        except OSError:
            client.close()
            return
        for s in (client, upstream):
            s.setblocking(False)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._pairs[client], self._pairs[upstream] = upstream, client
        self._from_target.add(upstream)
        self.stats["accepted"] += 1
        if self._t0 is None:
            self._t0 = time.monotonic()

    def _relay(self, s: socket.socket) -> None:
        peer = self._pairs.get(s)
        if peer is None:
            return
        try:
            data = s.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:  # one side closed: close the other
            for x in (s, peer):
                self._pairs.pop(x, None)
                self._from_target.discard(x)
                x.close()
            return
        delay = self._delay() if s in self._from_target else 0.0
        if delay > 0.0 or (self._held and s in self._from_target):  # behind what is held: in order
            self._held.append((time.monotonic() + delay, peer, data))
        else:
            self._send(peer, data)

    def run(self) -> None:
        cut = False
        while self._running:
            if self._in_cut() and not cut:
                cut = True
                self.stats["cut_began_s"] = round(self._elapsed(), 4)
                self._reset_all()
            elif cut and not self._in_cut() and self.stats["cut_ended_s"] is None:
                self.stats["cut_ended_s"] = round(self._elapsed(), 4)
            self._send_due()
            wait = 0.005 if not self._held else max(0.0, min(0.005, self._held[0][0] - time.monotonic()))
            readable, _, _ = select.select([self._server, *self._pairs], [], [], wait)
            for s in readable:
                if s is self._server:
                    self._accept()
                else:
                    self._relay(s)
        self._reset_all()
        self._server.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--listen", type=int, required=True)
    ap.add_argument("--target", type=int, required=True)
    ap.add_argument("--cut-at", type=float, default=float("inf"), help="s after the first connection")
    ap.add_argument("--cut-for", type=float, default=0.0, help="s")
    ap.add_argument("--delay-growth", type=float, default=0.0, help="ms per s, from SIGUSR2")
    ap.add_argument("--delay-max", type=float, default=0.0, help="ms")
    a = ap.parse_args(argv)
    relay = TcpRelay(a.listen, a.target, a.cut_at, a.cut_for, delay_growth=a.delay_growth * 1e-3,
                     max_delay=a.delay_max * 1e-3)
    signal.signal(signal.SIGTERM, relay.stop)
    signal.signal(signal.SIGINT, relay.stop)
    signal.signal(signal.SIGUSR1, relay.cut_now)
    signal.signal(signal.SIGUSR2, relay.delay_now)
    print("ready", flush=True)
    relay.run()
    print(json.dumps(relay.stats), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
