"""The genuine stream stopping and coming back with a sequence gap wider than ``max_sequence_jump``: a publisher's
stall found in the subscriber's first poll, and a TCP relay between the sessions killed and started again (Zenoh
reconnects). Real Zenoh sessions on loopback."""

import contextlib
import socket
import threading
import time

import numpy as np
import pytest
import zenoh

from groundstation.mocap.codec import PoseSample, encode
from groundstation.mocap.zenoh_link import PoseSubscriber, SubscriberSettings, open_session

KEY = "mocap/body/pose"
GAP = 83
"""Sequence numbers the stream skips (campaign 25's "sequence jumps 83 ahead"); over ``max_sequence_jump``."""


class Sender:
    """The genuine publisher, its sequence numbers set by the test (a bridge counting the samples it could not
    send)."""

    def __init__(self, session: zenoh.Session) -> None:
        self._pub = session.declare_publisher(KEY, express=True)
        self.sequence = 0

    def send(self, skip: int = 0) -> None:
        self.sequence += 1 + skip
        payload, att = encode(PoseSample(self.sequence, time.time(), np.array([0.0, 0.0, 1.0]), np.eye(3)))
        self._pub.put(payload, attachment=att, source_info=zenoh.SourceInfo(self._pub.id, self.sequence))


@contextlib.contextmanager
def _sessions(port: int, relay: "Relay | None" = None):
    """(mocap's, ground station's) sessions: the mocap listens on ``port``, the ground station connects to it,
    or through ``relay`` (started here)."""
    mocap = open_session(listen=[f"tcp/127.0.0.1:{port}"])
    if relay is not None:
        relay.start()
    gs = open_session(connect=[f"tcp/127.0.0.1:{relay.port if relay is not None else port}"])
    try:
        yield mocap, gs
    finally:
        gs.close()
        if relay is not None:
            relay.kill()
        mocap.close()


def _until(sub: PoseSubscriber, done, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        time.sleep(0.004)
        sub.poll()


@pytest.mark.parametrize("skip", [0, GAP])
def test_a_stall_queued_before_the_first_poll_does_not_lock_the_stream_out(skip):
    """Campaign 25 (a fly's preflight): the subscriber declared, its first poll found what had queued since, and
    in it the publisher's 0.1 s stall. The offset was taken from the stall's last sample, old by then, and every
    genuine sample after it was "from the future" for good (bad stamps: 40 of the 50 here). Taken: the samples
    after the stall (with a sequence gap: after ``resync_samples`` of them) and the stream after them."""
    with _sessions(7830) as (mocap, gs):
        sub = PoseSubscriber(gs, KEY)
        pub = Sender(mocap)
        time.sleep(0.3)  # the declarations cross
        for k in range(20):  # 10 samples, a 0.15 s stall, 10 more (``skip`` numbers lost in it), none polled yet
            if k == 10:
                time.sleep(0.15)
            pub.send(skip if k == 10 else 0)
            time.sleep(0.01)
        time.sleep(0.1)
        _until(sub, lambda: sub.received >= 20)  # the first poll finds them all at once
        assert sub.received == 20
        for _ in range(30):  # the stream goes on, polled as a flight polls
            pub.send()
            time.sleep(0.01)
            sub.poll()
        _until(sub, lambda: sub.received >= 50)
        assert sub.bad_stamps == 0, sub.last_rejection
        assert sub.latest().sequence == pub.sequence and not sub.fault()
        assert sub.resyncs == (1 if skip else 0)
        assert sub.accepted == 50 - (sub.settings.resync_samples - 1 if skip else 0)


def _shut(s: socket.socket) -> None:
    with contextlib.suppress(OSError):
        s.shutdown(socket.SHUT_RDWR)


class Relay:
    """A TCP relay on loopback (the campaign's tcpproxy.py): ``kill`` closes it and its connections."""

    def __init__(self, port: int, target: int) -> None:
        self.port, self.target = port, target
        self._socks: list[socket.socket] = []
        self._srv: socket.socket | None = None

    def start(self) -> None:
        srv = socket.socket()
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        srv.bind(("127.0.0.1", self.port))
        srv.listen(4)
        self._srv = srv
        threading.Thread(target=self._serve, args=(srv,), daemon=True).start()

    def _serve(self, srv: socket.socket) -> None:
        while True:
            try:
                a, _ = srv.accept()
            except OSError:
                return
            b = socket.create_connection(("127.0.0.1", self.target))
            self._socks += [a, b]
            for x, y in ((a, b), (b, a)):
                threading.Thread(target=self._pipe, args=(x, y), daemon=True).start()

    @staticmethod
    def _pipe(a: socket.socket, b: socket.socket) -> None:
        with contextlib.suppress(OSError):
            while data := a.recv(65536):
                b.sendall(data)
        for s in (a, b):
            _shut(s)

    def kill(self) -> None:
        assert self._srv is not None
        _shut(self._srv)  # wakes the accept (a close alone leaves it listening)
        self._srv.close()
        for s in self._socks:
            _shut(s)
            s.close()
        self._socks.clear()


def test_the_stream_through_a_relay_killed_and_started_again_is_taken_back():
    """The relay between the ground station and the mocap killed (the mocap publishes on, its samples lost: a
    sequence gap over ``max_sequence_jump``), then started again: Zenoh reconnects, and after
    ``resync_samples`` samples the stream is the genuine one again, no fault, no second sender."""
    relay = Relay(7832, 7831)
    with _sessions(7831, relay) as (mocap, gs):
        sub = PoseSubscriber(gs, KEY, SubscriberSettings(max_sequence_jump=50))
        pub = Sender(mocap)
        stop = threading.Event()

        def publish() -> None:
            while not stop.is_set():
                pub.send()
                time.sleep(0.01)
        thread = threading.Thread(target=publish)
        try:
            time.sleep(0.3)
            thread.start()
            _until(sub, lambda: sub.accepted >= 20)
            assert sub.accepted >= 20
            relay.kill()
            time.sleep(0.1)
            down = pub.sequence
            _until(sub, lambda: pub.sequence > down + 2 * sub.settings.max_sequence_jump)  # polled on, nothing comes
            relay.start()
            back = pub.sequence
            _until(sub, lambda: sub.latest().sequence > back + 20)
            assert sub.latest().sequence > back + 20, (sub.received, sub.last_rejection)
            assert sub.resyncs == 1 and sub.last_rejection.startswith("sequence jumps ")
            assert sub.bad_stamps == 0 and sub.conflicts == 0 and not sub.fault()
            np.testing.assert_allclose(sub.latest().position, [0.0, 0.0, 1.0])
        finally:
            stop.set()
            if thread.is_alive():
                thread.join()
