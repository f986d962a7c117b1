"""A loopback TCP relay that breaks its connections on a schedule: a lab network cable pulled and put back.

    python -m sim.tcp_relay --listen 7530 --target 7531 --cut-at 6.0 --cut-for 0.3

Relays every connection to ``127.0.0.1:<listen>`` (what the ground station's Zenoh session connects to) to
``127.0.0.1:<target>`` (where the mocap publisher listens), both ways. ``--cut-at`` seconds after the first
connection, or when it gets SIGUSR1, it resets every connection (the peers see the link go down at once) and
refuses new ones for ``--cut-for`` seconds; then it accepts again and the peers reconnect on their own. Runs until
SIGTERM/SIGINT and then prints one JSON line: connections accepted, refused during the cut, bytes relayed, when
the cut began and ended (s after the first connection).
"""

from __future__ import annotations

import argparse
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
                 host: str = "127.0.0.1") -> None:
        self._target = (host, target_port)
        self._server = socket.create_server((host, listen_port), reuse_port=False)
        self._server.setblocking(False)
        self._pairs: dict[socket.socket, socket.socket] = {}
        self._cut_at, self._cut_for = cut_at, cut_for
        self._t0: float | None = None
        self._running = True
        self.stats = {"accepted": 0, "refused": 0, "bytes": 0, "cut_began_s": None, "cut_ended_s": None}

    def stop(self, *_args) -> None:
        self._running = False

    def cut_now(self, *_args) -> None:
        """Begin the cut now (a signal handler: SIGUSR1)."""
        self._cut_at = self._elapsed()

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
                x.close()
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

    def run(self) -> None:
        cut = False
        while self._running:
            if self._in_cut() and not cut:
                cut = True
                self.stats["cut_began_s"] = round(self._elapsed(), 4)
                self._reset_all()
            elif cut and not self._in_cut() and self.stats["cut_ended_s"] is None:
                self.stats["cut_ended_s"] = round(self._elapsed(), 4)
            readable, _, _ = select.select([self._server, *self._pairs], [], [], 0.005)
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
    a = ap.parse_args(argv)
    relay = TcpRelay(a.listen, a.target, a.cut_at, a.cut_for)
    signal.signal(signal.SIGTERM, relay.stop)
    signal.signal(signal.SIGINT, relay.stop)
    signal.signal(signal.SIGUSR1, relay.cut_now)
    print("ready", flush=True)
    relay.run()
    print(json.dumps(relay.stats), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
