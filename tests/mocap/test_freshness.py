"""Keyed mocap's challenges: the ground station's nonces echoed by the publisher prove when a sample was made. Real
Zenoh sessions on loopback; the man in the middle is ``sim.tcp_relay`` holding back what the mocap sends."""

import contextlib
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import zenoh

from groundstation.mocap.auth import MocapKey
from groundstation.mocap.codec import challenge_key, decode_challenge, encode_challenge
from groundstation.mocap.zenoh_link import PosePublisher, PoseSubscriber, open_session

KEY = "mocap/body/pose"
MAC_KEY = MocapKey(bytes(range(32)))
MOCAP_PORT, RELAY_PORT = 7581, 7582


def test_only_a_key_holder_challenges():
    """A challenge's MAC binds its token and key: anyone else's tokens, echoed, would push the ground station's out
    of the slots a sample carries."""
    token = b"challengr" + bytes(6) + b"\x01"
    payload, tag = encode_challenge(token, MAC_KEY, challenge_key(KEY))
    assert challenge_key(KEY) == "mocap/body/challenge"
    assert decode_challenge(payload, tag, MAC_KEY, challenge_key(KEY)) == token
    for p, t, k, expr in [(payload, tag, MocapKey(bytes(32)), challenge_key(KEY)),  # another key
                          (token[:-1] + b"\x02", tag, MAC_KEY, challenge_key(KEY)),  # another token
                          (payload, tag, MAC_KEY, "mocap/other/challenge"),  # another body's
                          (payload, None, MAC_KEY, challenge_key(KEY)),  # no MAC
                          (bytes(16), encode_challenge(bytes(16), MAC_KEY, challenge_key(KEY))[1], MAC_KEY,
                           challenge_key(KEY))]:  # the zero token: "none" in an echo
        assert decode_challenge(p, t, k, expr) is None


@contextlib.contextmanager
def _held_back(delay_ms: float):
    """(mocap's session, ground station's session): the ground station connects through ``sim.tcp_relay``, which
    holds back what the mocap sends by ``delay_ms`` from the first byte on (0: relayed at once)."""
    relay = subprocess.Popen([sys.executable, "-m", "sim.tcp_relay", "--listen", str(RELAY_PORT), "--target",
                              str(MOCAP_PORT), "--cut-at", "1e9", "--delay-growth", "1e9", "--delay-max",
                              str(delay_ms)], stdout=subprocess.PIPE, text=True)
    mocap = gs = None
    try:
        assert relay.stdout.readline().strip() == "ready"
        if delay_ms:
            relay.send_signal(signal.SIGUSR2)  # the delay from now on: before the sessions connect
        mocap = open_session(listen=[f"tcp/127.0.0.1:{MOCAP_PORT}"])
        gs = open_session(connect=[f"tcp/127.0.0.1:{RELAY_PORT}"])
        yield mocap, gs
    finally:
        for s in (gs, mocap):
            if s is not None:
                s.close()
        relay.terminate()
        relay.wait(10)


def _stream(mocap: zenoh.Session, gs: zenoh.Session, seconds: float) -> PoseSubscriber:
    """A keyed bridge at 100 Hz for ``seconds``, the ground station polling at ~250 Hz as a flight does."""
    sub = PoseSubscriber(gs, KEY, mac_key=MAC_KEY)
    pub = PosePublisher(mocap, KEY, mac_key=MAC_KEY)
    deadline = time.monotonic() + 1.0
    while sub.received + sub.bad_stamps == 0 and time.monotonic() < deadline:  # the declarations cross the relay
        pub.publish(np.array([0.0, 0.0, 1.0]), np.eye(3), time.time())
        time.sleep(0.01)
        sub.poll()
    for _ in range(int(seconds * 100)):
        pub.publish(np.array([0.0, 0.0, 1.0]), np.eye(3), time.time())
        for _ in range(2):
            time.sleep(0.004)
            sub.poll()
    for _ in range(50):  # the last ones on their way (polled on: a late poll proves less of when they arrived)
        time.sleep(0.004)
        sub.poll()
    pub.close()
    return sub


@pytest.mark.parametrize("delay_ms", [60, 150])
def test_a_stream_held_back_from_its_first_sample_is_never_taken(delay_ms):
    """A man in the middle holding back the genuine keyed stream (valid MACs, order kept) from before its first
    sample: without the echo its delay was the network's latency as far as the stamps could tell, and the poses,
    that old, were taken for fresh. Each sample echoes a challenge older than ``fresh_s`` when it arrives: none is
    taken, each is named."""
    with _held_back(delay_ms) as (mocap, gs):
        sub = _stream(mocap, gs, 1.5)
    assert sub.received >= 100 and sub.accepted == 0 and sub.unauthenticated == 0
    assert sub.bad_stamps == sub.received, (sub.bad_stamps, sub.received)
    age = int(sub.last_rejection.removeprefix("echoes a challenge ").removesuffix(" ms old"))
    assert delay_ms - 5 <= age <= delay_ms + 40, sub.last_rejection


def test_the_same_stream_relayed_at_once_is_taken():
    with _held_back(0) as (mocap, gs):
        sub = _stream(mocap, gs, 1.5)
    assert sub.received >= 140 and sub.accepted >= 0.9 * sub.received, (sub.accepted, sub.received,
                                                                          sub.last_rejection)


def _hovering(pub: PosePublisher, subs: list[PoseSubscriber], periods: int, between=lambda k: None) -> set:
    """``periods`` of 10 ms: every subscriber polled, ``between(k)``, a sample published; the tokens echoed."""
    echoed = set()
    for k in range(periods):
        for sub in subs:
            sub.poll()
        between(k)
        time.sleep(0.005)
        echoed.update(pub.publish(np.array([0.0, 0.0, 1.0]), np.eye(3), time.time()).echoes)
        time.sleep(0.005)
    for _ in range(25):
        time.sleep(0.004)
        for sub in subs:
            sub.poll()
    return echoed


def test_a_publisher_echoes_no_challenge_without_the_key():
    """Challenges put by someone without the key (a flood of them) never reach the echo: the ground station's
    own still do, and its samples are taken."""
    with _held_back(0) as (mocap, gs):
        flooder = gs.declare_publisher(challenge_key(KEY))
        sub = PoseSubscriber(gs, KEY, mac_key=MAC_KEY)
        pub = PosePublisher(mocap, KEY, mac_key=MAC_KEY)
        time.sleep(0.3)
        echoed = _hovering(pub, [sub], 100, lambda k: [flooder.put(b"%016d" % (k * 5 + j), attachment=bytes(16))
                                                      for j in range(5)])
        pub.close()
        flooder.undeclare()
    assert echoed and not any(e.isdigit() for e in echoed)
    assert sub.accepted >= 90, (sub.accepted, sub.last_rejection)


def test_captured_challenges_put_again_do_not_push_the_ground_stations_out():
    """The ground station's own challenges, captured (MACs valid) and put again every millisecond 0.1-0.3 s later:
    before, the publisher echoed the newest two it heard, the replays pushed the genuine ones out and 70-80 % of
    the genuine samples were refused (review). A token no newer than its ground station's newest is ignored."""
    with _held_back(0) as (mocap, gs):
        captured: list[tuple[bytes, bytes]] = []
        spy = mocap.declare_subscriber(challenge_key(KEY), lambda c: captured.append(
            (c.payload.to_bytes(), c.attachment.to_bytes())))
        replayer = mocap.declare_publisher(challenge_key(KEY))
        sub = PoseSubscriber(gs, KEY, mac_key=MAC_KEY)
        pub = PosePublisher(mocap, KEY, mac_key=MAC_KEY)
        time.sleep(0.3)

        def replay(k):
            for _ in range(10):
                if len(captured) > 30:
                    payload, tag = captured[-30 + k % 20]
                    replayer.put(payload, attachment=tag)
                time.sleep(0.0005)

        _hovering(pub, [sub], 150, replay)
        pub.close()
        spy.undeclare()
    assert len(captured) > 50 and sub.accepted >= 0.9 * sub.received, (sub.accepted, sub.received,
                                                                       sub.last_rejection)


def test_three_ground_stations_at_their_own_rates_each_have_their_echo():
    """A flight and two monitors on one key, polling at 250, 50 and 1000 Hz: each sample echoes the newest challenge
    of each (before, the newest two of any: 57-80 % of the samples of each taken, in a review)."""
    with _held_back(0) as (mocap, gs):
        subs = [PoseSubscriber(gs, KEY, mac_key=MAC_KEY) for _ in range(3)]
        pub = PosePublisher(mocap, KEY, mac_key=MAC_KEY)
        time.sleep(0.3)
        periods = {0: 1, 1: 2, 2: 1}  # polled every period (and by _hovering); the fast one 10 times more

        def monitors(k):
            for _ in range(10):
                subs[2].poll()
                time.sleep(0.0005)
            if k % periods[1]:
                subs[1].poll()

        _hovering(pub, [subs[0], subs[2]], 150, monitors)
        subs[1].poll()
        pub.close()
    for sub in subs:
        assert sub.received >= 140 and sub.accepted >= 0.95 * sub.received, (sub.accepted, sub.received,
                                                                               sub.last_rejection)
