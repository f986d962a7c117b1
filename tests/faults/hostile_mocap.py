"""A hostile publisher on a body's mocap key, in a process of its own (fault injection for the fault table).

    python -m tests.faults.hostile_mocap --connect tcp/127.0.0.1:8490 --key mocap/assembly/pose
                                         --mode second|huge-seq|replay|drift|spoof|malformed|copy-id|
                                                nan-stamp|future-stamp|replay-captured|sink|resync|
                                                handover-replay [--after 5]
                                                [--duration 10]

Modes: ``second`` publishes a plausible pose of its own (0.3 m off) at 100 Hz; ``huge-seq`` one sample with a
sequence number of 2^40, then goes quiet; ``replay`` re-sends old sequence numbers; ``drift`` a pose that drifts
away from the flight path at 5 cm/s; ``spoof`` the hover pose 5 cm off with the attitude 20 deg off; ``malformed``
payloads that do not decode. The next modes first read the genuine stream (any peer on the network can) and
publish under its source id (copied from its samples): ``copy-id`` the genuine pose dragged off at 0.5 m/s, its
sequence numbers one ahead of the genuine ones; ``sink`` the same dragged down; ``nan-stamp`` samples whose stamp
is NaN, infinite or negative; ``future-stamp`` a pose 1 m off stamped 100 s ahead; ``replay-captured`` the genuine
samples re-sent as captured (MACs included) 0.1 s later. ``handover-replay``, as a publisher of its own: once the
genuine stream has been silent for 0.55 s, the samples it sent in the 0.3 s before its silence, as captured, at
100 Hz (a restarted bridge to a ground station that takes one with the key). It connects to the ground station's
Zenoh endpoint (the ground station listens: ``mocap.listen = true``), waits ``--after`` seconds, then attacks.
"""

from __future__ import annotations

import argparse
import json
import struct
import time

import numpy as np
import zenoh

from groundstation.mocap.codec import PoseSample, decode, encode
from groundstation.mocap.zenoh_link import PosePublisher
from groundstation.rotations import rotvec_to_matrix


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--key", default="mocap/assembly/pose")
    ap.add_argument("--mode", required=True,
                    choices=("second", "huge-seq", "replay", "drift", "spoof", "malformed", "copy-id", "nan-stamp",
                             "future-stamp", "replay-captured", "sink", "resync", "handover-replay"))
    ap.add_argument("--after", type=float, default=5.0)
    ap.add_argument("--duration", type=float, default=10.0)
    a = ap.parse_args(argv)
    cfg = zenoh.Config()  # as open_session, but retrying the connection every 50 ms: it may start first
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("connect/endpoints", json.dumps([a.connect]))
    # Listening on loopback, not Zenoh's default (every address, of which it announces only non-loopback ones): the
    # genuine publisher, told of us by the ground station, connects here even on a host with loopback alone.
    cfg.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    cfg.insert_json5("connect/retry", '{period_init_ms: 50, period_max_ms: 50, period_increase_factor: 1}')
    session = zenoh.open(cfg)
    captured: list[zenoh.Sample] = []
    heard: list[float] = []  # when each was captured (monotonic), for handover-replay
    spy = session.declare_subscriber(a.key, lambda s: (heard.append(time.monotonic()), captured.append(s)))
    try:
        time.sleep(a.after)
        if a.mode == "handover-replay":
            return _after_the_silence(session, a, captured, heard)
        if a.mode in ("copy-id", "nan-stamp", "future-stamp", "replay-captured", "sink", "resync"):
            return _as_the_genuine_source(session, a, captured)
        spy.undeclare()
        pub = PosePublisher(session, a.key)
        raw = session.declare_publisher(a.key)
        end = time.monotonic() + a.duration
        k = 0
        while time.monotonic() < end:
            k += 1
            now = time.time()
            if a.mode == "second":
                pub.publish(np.array([0.3, 0.0, 1.0]), np.eye(3), now)
            elif a.mode == "huge-seq":
                payload, att = encode(PoseSample(2**40, now, np.array([0.0, 0.0, 1.0]), np.eye(3)))
                raw.put(payload, attachment=att)
                break
            elif a.mode == "replay":
                payload, att = encode(PoseSample(max(1, k % 50), now, np.array([0.0, 0.0, 1.0]), np.eye(3)))
                raw.put(payload, attachment=att)
            elif a.mode == "drift":
                pub.publish(np.array([0.05 * k * 0.01, 0.0, 1.0]), np.eye(3), now)
            elif a.mode == "spoof":
                pub.publish(np.array([0.05, 0.0, 1.0]), rotvec_to_matrix(np.radians([20.0, 0.0, 0.0])), now)
            else:
                raw.put(b"\x00\xffnot a pose", attachment=b"short")
            time.sleep(0.01)
        time.sleep(0.5)
    finally:
        session.close()
    return 0


def _as_the_genuine_source(session: zenoh.Session, a: argparse.Namespace, captured: list) -> int:
    """The attacks that copy the genuine publisher's source id (read from its samples)."""
    genuine = [s for s in captured if s.source_info is not None]
    if not genuine:
        raise SystemExit("no genuine sample heard: nothing to copy")
    source = genuine[-1].source_info.source_id
    raw = session.declare_publisher(a.key)
    end = time.monotonic() + a.duration
    k = 0
    while time.monotonic() < end:
        k += 1
        newest = captured[-1]
        seq = struct.unpack("<Qd", newest.attachment.to_bytes()[:16])[0] + 1
        now = time.time()
        if a.mode == "resync":  # bursts of 5 consistent samples 1000 ahead in sequence, 3 cm low, 10 a second
            pose = decode(newest.payload.to_bytes(), newest.attachment.to_bytes())
            for j in range(5):
                s = seq + 1000 * k + j
                payload, att = encode(PoseSample(s, now - (4 - j) * 2e-4, pose.position - [0.0, 0.0, 0.03],
                                                 pose.rotation))
                raw.put(payload, attachment=att, source_info=zenoh.SourceInfo(source, s))
            time.sleep(0.1)
            continue
        if a.mode == "sink":  # the genuine pose, dragged down at 0.5 m/s: an estimate held low while airborne
            pose = decode(newest.payload.to_bytes(), newest.attachment.to_bytes())
            payload, att = encode(PoseSample(seq, now, pose.position - [0.0, 0.0, 0.005 * k], pose.rotation))
        elif a.mode == "copy-id":  # the genuine pose, dragged away at 0.5 m/s: each sample inside the gates
            pose = decode(newest.payload.to_bytes(), newest.attachment.to_bytes())
            payload, att = encode(PoseSample(seq, now, pose.position + [0.005 * k, 0.0, 0.0], pose.rotation))
        elif a.mode == "nan-stamp":
            stamp = (float("nan"), float("inf"), -1.0)[k % 3]
            payload = encode(PoseSample(seq, now, np.array([0.5, 0.0, 1.0]), np.eye(3)))[0]
            att = struct.pack("<Qd", seq, stamp)
        elif a.mode == "future-stamp":
            payload, att = encode(PoseSample(seq, now + 100.0, np.array([1.0, 0.0, 1.0]), np.eye(3)))
        else:  # replay-captured: what the genuine source sent 0.1 s ago, byte for byte
            old = captured[max(0, len(captured) - 11)]
            payload, att = old.payload.to_bytes(), old.attachment.to_bytes()
            seq = struct.unpack("<Qd", att[:16])[0]
        raw.put(payload, attachment=att, source_info=zenoh.SourceInfo(source, seq))
        time.sleep(0.01)
    time.sleep(0.5)
    return 0


def _after_the_silence(session: zenoh.Session, a: argparse.Namespace, captured: list, heard: list[float]) -> int:
    """handover-replay: the samples of the 0.3 s before the genuine stream's silence, once it has lasted 0.55 s."""
    end = time.monotonic() + a.duration
    while not heard or time.monotonic() - heard[-1] < 0.55:
        if time.monotonic() > end:
            return 0
        time.sleep(0.002)
    last = heard[-1]
    replayed = [s for t, s in zip(heard, captured, strict=False) if last - 0.3 <= t <= last]
    pub = session.declare_publisher(a.key)
    for s in replayed:
        pub.put(s.payload.to_bytes(), attachment=s.attachment.to_bytes())
        time.sleep(0.01)
    time.sleep(0.5)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
