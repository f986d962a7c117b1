"""Mocap samples that lie: stamps that are not times or disagree with their arrival, a copied source id, samples
without the shared key's MAC, captured samples re-sent. Real Zenoh sessions on loopback."""

import struct
import time

import numpy as np
import pytest
import zenoh

from groundstation.mocap.auth import MocapKey
from groundstation.mocap.codec import PoseSample, encode
from groundstation.mocap.zenoh_link import PosePublisher, PoseSubscriber, SubscriberSettings, open_session

KEY = "mocap/body/pose"


@pytest.fixture
def sessions():
    """(publisher's, ground station's, attacker's): the ground station listens and the publisher connects to it;
    the attacker connects to both (it reads the genuine samples, as anyone on a shared network can)."""
    gs = open_session(listen=["tcp/127.0.0.1:7486"])
    a = open_session(listen=["tcp/127.0.0.1:7487"], connect=["tcp/127.0.0.1:7486"])
    c = open_session(connect=["tcp/127.0.0.1:7486", "tcp/127.0.0.1:7487"])
    time.sleep(0.3)
    yield a, gs, c
    for s in (c, a, gs):
        s.close()


def _genuine(pub: PosePublisher, sub: PoseSubscriber, k0: int, count: int, x0: float = 0.0) -> None:
    """``count`` samples of a body hovering at ``x0``, 100 Hz, stamped with the wall clock, each polled (from
    ``k0 = 0``: after the declarations have reached the other session). Each is published 5 ms after a poll, as a
    bridge's samples fall between the polls: with a key, a poll's challenge has reached the publisher by then."""
    if k0 == 0:
        time.sleep(0.3)
    seen = sub.received + sub.malformed + sub.unauthenticated + sub.foreign
    for _ in range(count):
        sub.poll()
        time.sleep(0.005)
        pub.publish(np.array([x0, 0.0, 1.0]), np.eye(3), time.time())
        time.sleep(0.005)
    _wait(sub, seen + count)  # on a loaded machine the last ones may still be on their way


def _wait(sub: PoseSubscriber, count: int) -> None:
    deadline = time.monotonic() + 3.0
    while sub.received + sub.malformed + sub.unauthenticated + sub.foreign < count and time.monotonic() < deadline:
        time.sleep(0.005)
        sub.poll()


def test_stamps_that_are_not_times_are_malformed(sessions):
    a, b, c = sessions
    sub = PoseSubscriber(b, KEY)
    pub = PosePublisher(a, KEY)
    _genuine(pub, sub, 0, 10)
    raw = a.declare_publisher(KEY)
    payload, _ = encode(PoseSample(11, time.time(), np.array([3.0, 0.0, 1.0]), np.eye(3)))
    for seq, stamp in ((11, float("nan")), (12, float("inf")), (13, -1.0)):
        raw.put(payload, attachment=struct.pack("<Qd", seq, stamp))
    _wait(sub, 13)
    assert sub.malformed == 3 and sub.accepted == 10
    np.testing.assert_allclose(sub.latest().position, [0.0, 0.0, 1.0])
    assert all(np.isfinite(stamp) for _, _, stamp in sub.drain_raw())  # nothing unfit for the log


@pytest.mark.parametrize("offset_s", [100.0, -100.0, 0.2, -0.2])
def test_a_stamp_far_from_its_arrival_cannot_open_the_gates(sessions, offset_s):
    """Today's bug: a stamp 100 s ahead made the speed and position gates 100 s wide; a sample 3 m away passed."""
    a, b, c = sessions
    sub = PoseSubscriber(b, KEY)
    pub = PosePublisher(a, KEY)
    _genuine(pub, sub, 0, 20)
    pub.publish(np.array([3.0, 0.0, 1.0]), np.eye(3), time.time() + offset_s)
    _wait(sub, 21)
    assert sub.bad_stamps == 1 and sub.accepted == 20
    assert sub.last_rejection.endswith("ms off its arrival time")
    np.testing.assert_allclose(sub.latest().position, [0.0, 0.0, 1.0])
    _genuine(pub, sub, 21, 5)  # the genuine stream goes on
    assert sub.accepted == 25 and not sub.fault()


def test_exact_copies_of_a_sample_are_dropped_not_a_second_sender(sessions):
    """Every sample delivered five times (a bridge or network repeating itself: same bytes, same sequence): each
    taken once, the copies counted, no conflict and no fault."""
    a, b, c = sessions
    sub = PoseSubscriber(b, KEY)
    raw = a.declare_publisher(KEY)
    time.sleep(0.3)
    for seq in range(1, 31):
        payload, attachment = encode(PoseSample(seq, time.time(), np.array([0.0, 0.0, 1.0]), np.eye(3)))
        for _ in range(5):
            raw.put(payload, attachment=attachment)
        time.sleep(0.01)
        sub.poll()
    _wait(sub, 150)
    assert sub.accepted == 30 and sub.duplicates == 120 and sub.conflicts == 0 and sub.rejected == 0
    assert not sub.fault()


def test_a_stamp_that_goes_backwards_is_rejected(sessions):
    """The next sequence number, the same pose, stamped 20 ms before the last sample (inside the 50 ms skew bound,
    so only the order tells): rejected and counted; the stream goes on."""
    a, b, c = sessions
    sub = PoseSubscriber(b, KEY)
    pub = PosePublisher(a, KEY)
    _genuine(pub, sub, 0, 20)
    last = sub.latest().stamp
    pub.publish(np.array([0.0, 0.0, 1.0]), np.eye(3), last - 0.02)
    _wait(sub, 21)
    assert sub.accepted == 20 and sub.rejected == 1 and sub.last_rejection == "stamp not after the last one"
    assert sub.latest().stamp == last
    _genuine(pub, sub, 21, 5)
    assert sub.accepted == 25 and not sub.fault()


def test_the_speed_gate_scales_with_the_local_clock_not_the_stamps(sessions):
    """A sample right after the last, stamped 40 ms ahead (inside the skew bound), 1 m away: beyond max_speed
    (10 m/s) over any time the stamps or the local clock allow, rejected, the stream unmoved."""
    a, b, c = sessions
    sub = PoseSubscriber(b, KEY)
    pub = PosePublisher(a, KEY)
    _genuine(pub, sub, 0, 20)
    t = time.time()
    pub.publish(np.array([1.0, 0.0, 1.0]), np.eye(3), t + 0.04)
    _wait(sub, 21)
    assert sub.accepted == 20 and sub.rejected == 1 and sub.last_rejection.startswith("moves 1.00 m in ")


def test_a_copied_source_id_is_a_fault(sessions):
    """An attacker reads the genuine publisher's entity id from its samples and sends its own under it: every
    sample claims the genuine source, so only the interleaved sequences give it away."""
    a, b, c = sessions
    sub = PoseSubscriber(b, KEY)
    pub = PosePublisher(a, KEY)
    seen = []
    spy = c.declare_subscriber(KEY, lambda s: seen.append(s.source_info.source_id))
    _genuine(pub, sub, 0, 10)
    assert seen and sub.untrusted_since() is None
    genuine = sub.measurements()
    forger = c.declare_publisher(KEY)
    seq = 10
    for k in range(20):  # forged samples one ahead of the genuine ones, interleaved with them
        seq += 1
        payload, att = encode(PoseSample(seq + 1, time.time(), np.array([0.0, 0.002 * (k + 1), 1.0]), np.eye(3)))
        forger.put(payload, attachment=att, source_info=zenoh.SourceInfo(seen[0], seq + 1))
        pub.publish(np.array([0.0, 0.0, 1.0]), np.eye(3), time.time())
        time.sleep(0.01)
        sub.poll()
    _wait(sub, 50)
    spy.undeclare()
    assert sub.foreign == 0  # the id was copied: the one-publisher rule alone sees nothing
    assert sub.conflicts >= 3 and sub.fault().startswith(f"two sequences under one source id on {KEY}")
    # Untrusted from a sample interval (and the latency) before the first forged sample taken: that is after the
    # earlier genuine ones, within an interval of the last (a loaded machine delivers the first forged sample
    # sooner after it than the 10 ms the samples were sent apart: a run failed on 0.2 ms).
    first_forged = min(m.t for m in sub.measurements() if m.position[1] > 0.0)
    assert genuine[-1].t - sub.settings.latency - 0.025 < sub.untrusted_since() <= first_forged - 0.005


def test_authenticated_stream(sessions):
    a, b, c = sessions
    key = MocapKey(bytes(range(32)))
    sub = PoseSubscriber(b, KEY, mac_key=key)
    pub = PosePublisher(a, KEY, mac_key=key)
    _genuine(pub, sub, 0, 10)
    assert sub.accepted == 10 and sub.unauthenticated == 0
    forgers = [PosePublisher(c, KEY), PosePublisher(c, KEY, mac_key=MocapKey(bytes(32)))]
    for forger in forgers:  # without the key and with another key: never used, not even as a second source
        forger.publish(np.array([0.5, 0.0, 1.0]), np.eye(3), time.time())
    _wait(sub, 12)
    assert sub.unauthenticated == 2 and sub.foreign == 0 and not sub.fault()
    captured = []
    spy = c.declare_subscriber(KEY, lambda s: captured.append((s.payload.to_bytes(), s.attachment.to_bytes(),
                                                               s.source_info)))
    time.sleep(0.3)
    _genuine(pub, sub, 10, 10)
    spy.undeclare()
    assert len(captured) >= 5
    replayer = c.declare_publisher(KEY)
    for payload, attachment, info in captured[:5]:  # valid MACs, old stamps and sequence numbers, the id copied
        replayer.put(payload, attachment=attachment, source_info=info)
    _wait(sub, 27)
    assert sub.accepted == 20 and sub.rejected == 5
    _genuine(pub, sub, 20, 5)
    assert sub.accepted == 25
    np.testing.assert_allclose(sub.latest().position, [0.0, 0.0, 1.0])


@pytest.mark.parametrize("keyed", [True, False])
def test_a_restarted_bridge_is_taken_with_the_key_and_a_fault_without(sessions, keyed):
    """The bridge restarts: a new publisher (a new entity id, its sequence from 1) after the old one's silence.
    With the key it becomes the source (only the key's holders publish); a third keyed publisher while it is heard
    is a second publisher. Without the key anyone could be the new one: a fault, never taken."""
    a, b, c = sessions
    key = MocapKey(bytes(range(32))) if keyed else None
    # A silence longer than the default's 0.1 s: the third publisher below must not arrive in one on a loaded machine.
    sub = PoseSubscriber(b, KEY, SubscriberSettings(handover_silence_s=0.5), mac_key=key)
    first = PosePublisher(a, KEY, mac_key=key)
    _genuine(first, sub, 0, 10)
    first.close()
    time.sleep(2 * sub.settings.handover_silence_s)
    restarted = PosePublisher(a, KEY, mac_key=key)
    time.sleep(0.3)  # its declaration reaches the ground station
    _genuine(restarted, sub, 10, 10, x0=0.01)
    if not keyed:
        assert sub.accepted == 10 and sub.foreign == 10 and sub.handovers == 0
        assert sub.fault().startswith(f"a second publisher on {KEY}")
        return
    assert sub.accepted == 20 and sub.foreign == 0 and sub.handovers == 1 and not sub.fault(), sub.last_rejection
    assert "a new publisher on mocap/body/pose after" in sub.last_handover
    np.testing.assert_allclose(sub.latest().position, [0.01, 0.0, 1.0])
    assert sub.latest().sequence == 10  # the new publisher's own count
    third = PosePublisher(c, KEY, mac_key=key)
    time.sleep(0.3)
    _genuine(restarted, sub, 20, 3, x0=0.01)  # heard again, then the third while it is
    third.publish(np.array([0.5, 0.0, 1.0]), np.eye(3), time.time())
    _genuine(restarted, sub, 23, 3, x0=0.01)
    assert sub.foreign >= 1 and sub.handovers == 1 and sub.fault().startswith(f"a second publisher on {KEY}")


def test_captured_samples_sent_again_once_the_keyed_bridge_falls_silent_are_not_a_restarted_bridge(sessions):
    """With the key: an attacker without it records the genuine samples (MAC and all) and sends them again once the
    bridge has been silent for the handover's 0.5 s. They echo challenges long gone (and their stamps are stale on
    the old source's clock): bad stamps, never taken. Before: taken for a restarted bridge (its clock learnt from
    those very samples), and the blind landing flew on old poses (motors off 0.9-1.1 m up, "landed"; hostile
    campaign 26). The bridge restarted after them (fresh stamps) is still taken: had they counted as a second
    publisher, it never would be."""
    a, b, c = sessions
    key = MocapKey(bytes(range(32)))
    sub = PoseSubscriber(b, KEY, SubscriberSettings(handover_silence_s=0.5), mac_key=key)
    recorder = c.declare_subscriber(KEY, zenoh.handlers.FifoChannel(64))
    genuine = PosePublisher(a, KEY, mac_key=key)
    _genuine(genuine, sub, 0, 30)
    genuine.close()
    captured = []
    deadline = time.monotonic() + 3.0
    while len(captured) < 30 and time.monotonic() < deadline:
        if (sample := recorder.try_recv()) is None:
            time.sleep(0.005)
        else:
            captured.append((sample.payload.to_bytes(), sample.attachment.to_bytes()))
    recorder.undeclare()
    assert len(captured) == 30
    silent_until = time.monotonic() + 2 * sub.settings.handover_silence_s
    while time.monotonic() < silent_until:  # the ground station polls on through the silence, as a flight does
        sub.poll()
        time.sleep(0.004)
    replayer = c.declare_publisher(KEY)
    time.sleep(0.3)
    for payload, attachment in captured:
        replayer.put(payload, attachment=attachment, source_info=zenoh.SourceInfo(replayer.id, 1))
        time.sleep(0.01)
        sub.poll()
    _wait(sub, 60)
    assert sub.unauthenticated == 0  # their MACs hold: only their age tells them
    assert sub.handovers == 0 and sub.accepted == 30 and sub.bad_stamps == 30, (sub.handovers, sub.last_handover)
    assert sub.last_rejection == "echoes no recent challenge of this ground station"
    assert sub.foreign == 0 and not sub.fault()
    restarted = PosePublisher(a, KEY, mac_key=key)
    time.sleep(0.3)
    _genuine(restarted, sub, 60, 10, x0=0.01)
    assert sub.handovers == 1 and sub.accepted == 40 and not sub.fault()
    np.testing.assert_allclose(sub.latest().position, [0.01, 0.0, 1.0])
