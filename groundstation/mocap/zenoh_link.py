"""Mocap poses over Zenoh: session set-up, a publisher per rigid body, and a subscriber that checks what it
receives and hands the estimator measurements on the local clock.

Sessions default to peer mode on an explicit loopback endpoint with multicast scouting off (no traffic leaves
the machine unless the config names another endpoint). One side listens, the other connects. Sessions are
closed explicitly (an unclosed session keeps the process alive at exit).
"""

from __future__ import annotations

import json
import os
import resource
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
import zenoh

from groundstation.errors import SessionError
from groundstation.estimation.measurement import PoseMeasurement
from groundstation.mocap.auth import MocapKey
from groundstation.mocap.codec import (
    CHALLENGER_BYTES,
    ECHOES,
    PoseSample,
    Unauthenticated,
    challenge_key,
    decode,
    decode_challenge,
    encode,
    encode_challenge,
)
from groundstation.mocap.stamp_clock import StampClock, StampClockSettings


@dataclass(frozen=True)
class Security:
    """TLS (with mutual authentication by default) and access control of a Zenoh session on a lab network.

    Endpoints then use ``tls/HOST:PORT``. ``root_ca``: the CA that signed every peer's certificate;
    ``certificate``/``private_key``: this peer's (PEM files), presented both when listening and when connecting;
    ``mutual``: peers must present a certificate signed by ``root_ca``. ``access_control``: Zenoh's
    ``access_control`` block (JSON5 text: rules, subjects, policies; e.g. only the mocap host may put on
    ``mocap/**``)."""

    root_ca: str | None = None
    certificate: str | None = None
    private_key: str | None = None
    mutual: bool = True
    access_control: str | None = None


CHALLENGE_S = 0.01
"""A keyed subscriber challenges its publisher at most this often, on its polls (every 12 ms at 250 Hz), s: the
echo of a sample is then about this plus the round trip older than the sample."""

RECONNECT = {"period_init_ms": 50, "period_max_ms": 200, "period_increase_factor": 2}
"""Zenoh's retry of a connect endpoint whose link went down (``connect/retry``): first after 50 ms, then at most
every 200 ms. Zenoh's default (1 s, up to 4 s) left a flight 1-4 s without poses after a lab network hiccup; the
poses are back within ~0.2 s of the link (measured: the fault table's 300 ms cut)."""


SESSION_FDS = 48
"""File descriptors a process with a Zenoh session needs at least (its runtime's threads, sockets and pipes; a
flight's log and links besides): with 24 (``ulimit -n 24``) Zenoh's runtime panicked in a thread of its own and
the flight ended in a traceback (hostile campaign 28); 48 flew."""


def _enough_descriptors() -> None:
    """Raise the soft limit on open files to at least 256 where the hard limit allows; a SessionError if the hard
    limit is below :data:`SESSION_FDS`."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    unlimited = hard == resource.RLIM_INFINITY
    want = 256 if unlimited else min(256, hard)
    if soft != resource.RLIM_INFINITY and soft < want:
        resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
        soft = want
    if soft != resource.RLIM_INFINITY and soft < SESSION_FDS:
        raise SessionError(f"this process may open only {soft} files (ulimit -n {soft}): a Zenoh session needs "
                           f"at least {SESSION_FDS}")


def open_session(listen: list[str] | None = None, connect: list[str] | None = None,
                 security: Security | None = None) -> zenoh.Session:
    """A peer-mode session listening on and/or connecting to explicit endpoints, multicast scouting off."""
    _enough_descriptors()
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    try:
        cfg.insert_json5("listen/endpoints", json.dumps(list(listen or [])))
        cfg.insert_json5("connect/endpoints", json.dumps(list(connect or [])))
    except zenoh.ZError as exc:  # a malformed endpoint: Zenoh's reason, first line
        raise SessionError(f"bad Zenoh endpoint (listen {listen}, connect {connect}): "
                           f"{str(exc).splitlines()[0][:200]}") from None
    cfg.insert_json5("connect/retry", json.dumps(RECONNECT))
    if security is not None:
        tls = "transport/link/tls/"
        if security.root_ca is not None:
            cfg.insert_json5(tls + "root_ca_certificate", json.dumps(security.root_ca))
            cfg.insert_json5(tls + "enable_mtls", json.dumps(security.mutual))
        if security.certificate is not None:
            for side in ("listen", "connect"):
                cfg.insert_json5(f"{tls}{side}_certificate", json.dumps(security.certificate))
                cfg.insert_json5(f"{tls}{side}_private_key", json.dumps(security.private_key))
        if security.access_control is not None:
            cfg.insert_json5("access_control", security.access_control)
    for endpoint in listen or []:
        check_listenable(endpoint)
    try:
        return zenoh.open(cfg)
    except Exception as exc:  # zenoh raises ZError carrying the transport's reason
        raise SessionError(f"cannot open Zenoh session (listen {listen}, connect {connect}): {exc}") from None


def check_listenable(endpoint: str) -> None:
    """Refuse at once an IP endpoint whose address this host cannot listen on (a port in use, an address not
    ours): Zenoh retries a listen endpoint for 10 s before it gives up with the same reason."""
    proto, _, address = endpoint.partition("/")
    kind = {"tcp": socket.SOCK_STREAM, "tls": socket.SOCK_STREAM, "udp": socket.SOCK_DGRAM,
            "quic": socket.SOCK_DGRAM}.get(proto)
    host, _, port = address.split("?")[0].split("#")[0].rpartition(":")
    if kind is None or not port.isdigit() or int(port) == 0:
        return  # not an IP endpoint with a fixed port: Zenoh's own check
    try:
        family, _, _, _, where = socket.getaddrinfo(host.strip("[]"), int(port), type=kind)[0]
        with socket.socket(family, kind) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as Zenoh binds: TIME_WAIT is no conflict
            probe.bind(where)
    except OSError as exc:
        raise SessionError(f"cannot listen on {endpoint}: {exc.strerror or exc}") from None


def pose_key(prefix: str, body: str) -> str:
    return f"{prefix}/{body}/pose"


class PosePublisher:
    """Publishes poses of one rigid body on its key (``<prefix>/<body>/pose``), each with the publisher's Zenoh
    entity id and the sequence number as source info, so a subscriber can tell publishers apart, and with
    ``mac_key`` a MAC (:mod:`groundstation.mocap.auth`) and the newest challenges heard, echoed
    (:mod:`groundstation.mocap.codec`)."""

    CHALLENGES = 64
    """Challenges buffered between two samples (a ground station sends one every ``CHALLENGE_S``)."""

    def __init__(self, session: zenoh.Session, key: str, mac_key: MocapKey | None = None) -> None:
        self._pub = session.declare_publisher(key, express=True)
        self._key = key
        self._mac_key = mac_key
        self._seq = 0
        self._echoes: dict[bytes, bytes] = {}
        """The newest challenge token of each ground station (by its id), the one heard from last at the end."""
        # Drained as each sample is made, on the caller's thread (a Python callback on Zenoh's thread deadlocked
        # against a session's close in a test).
        self._challenges = (session.declare_subscriber(challenge_key(key), zenoh.handlers.RingChannel(self.CHALLENGES))
                            if mac_key is not None else None)

    def publish(self, position: np.ndarray, rotation: np.ndarray, stamp: float) -> PoseSample:
        self._seq += 1
        if self._challenges is not None:
            while (c := self._challenges.try_recv()) is not None:
                attachment = c.attachment.to_bytes() if c.attachment is not None else None
                token = decode_challenge(c.payload.to_bytes(), attachment, self._mac_key, str(c.key_expr))
                if token is not None:
                    self._heard(token)
        sample = PoseSample(self._seq, stamp, np.asarray(position, float), np.asarray(rotation, float),
                            tuple(self._echoes.values()))
        payload, attachment = encode(sample, self._mac_key, self._key)
        self._pub.put(payload, attachment=attachment, source_info=zenoh.SourceInfo(self._pub.id, self._seq))
        return sample

    def _heard(self, token: bytes) -> None:
        """Keep ``token`` (authenticated) if it is its ground station's newest: one not newer is a captured
        challenge put again (its counter, big-endian, compares as bytes)."""
        challenger = token[:CHALLENGER_BYTES]
        newest = self._echoes.pop(challenger, None)
        if newest is not None and token <= newest:
            token = newest
        self._echoes[challenger] = token
        while len(self._echoes) > ECHOES:  # the ground station heard from longest ago goes
            del self._echoes[next(iter(self._echoes))]

    def close(self) -> None:
        if self._challenges is not None:
            self._challenges.undeclare()
        self._pub.undeclare()


@dataclass(frozen=True)
class SubscriberSettings:
    max_speed: float = 10.0
    """A pose implying a faster move than this from the last accepted one is rejected as an outlier, m/s."""
    latency: float = 0.0
    """The mocap's latency from capture to the fastest arrival of a sample here, s: a measurement's capture time is
    its stamp on the local clock less this."""
    max_sequence_jump: int = 50
    """A sample more than this far ahead in sequence is not trusted (until it starts a track, below)."""
    resync_samples: int = 5
    """Consecutive rejected samples consistent among themselves (sequence, stamps, speed) after which the stream
    follows them: the body reappearing elsewhere after an occlusion, a publisher's counter starting anew."""
    stamps: StampClockSettings = StampClockSettings()
    """How far a stamp may disagree with its arrival time."""
    max_conflicts: int = 3
    """This many sequence conflicts (two interleaved sequences under one source id) within a second are a fault:
    a single publisher's samples arrive in order on Zenoh's ordered links, so only a second sender that copied the
    source id produces them."""
    fresh_s: float = 0.025
    """With a key: a sample must echo a challenge sent at most this long before the poll before the one that found
    it, s (one challenge interval, ``CHALLENGE_S``, and a round trip on a lab network: 10-12 ms). A sample held back
    on the way echoes an older one: before, a man in the middle delaying the stream from its first sample on was
    taken for the network's latency whatever the delay, and a delay grown slowly was followed up to the stamps'
    ``max_rise_s``. What it leaves: a delay shorter than about this less the challenge's own age passes, most
    samples taken (measured at 250 Hz polls: 10 ms 99 %, 20 ms 56 %, 30 ms none), and the stamps take it for the
    network's latency."""
    handover_silence_s: float = 0.5
    """With a key: a new authenticated publisher whose stamps are fresh on the old one's clock becomes the source once
    the old one has been silent this long (a bridge restarted: a new entity id, its sequence from 1, after a second
    or more), s. Not shorter: a second key holder
    took over after a 120 ms hiccup of the genuine bridge, which was then a second publisher. Without a key
    anyone may publish, and a new publisher is never taken (a second publisher is a fault)."""


class PoseSubscriber:
    """Takes the poses of one body from one publisher, rejects what cannot be trusted, and hands the rest on as
    :class:`PoseMeasurement` s timed on the local clock (:meth:`measurements`) for the state estimator
    (:mod:`groundstation.estimation`), which judges them against the body's motion.

    Samples wait in a Zenoh ring buffer (the newest ``RING`` kept) and are decoded when the control loop asks for
    the state, on the caller's thread. A Python callback would run on Zenoh's thread and take the GIL away from
    the control loop at every sample; measured at 500 Hz that was the largest source of late periods. The cost is
    that arrival is timed when the samples are polled, at most one control period late.

    Integrity. With ``mac_key``, a sample without the key's MAC is counted (:attr:`unauthenticated`) and never
    used; that is what stops a forger (see the README's "Mocap on a lab network"). The first publisher heard is
    the body's source (its Zenoh entity id, in the samples' source info); a sample from any other is counted
    (:attr:`foreign`) and never used, and :meth:`fault` names it; with a key, a new publisher after the source's
    silence becomes the source (a restarted bridge: :attr:`handovers`). The id is only a claim (any publisher can copy
    it): without a key, two interleaved sequences under one id are counted (:attr:`conflicts`) and a fault too
    (with a key only the key's holders publish, and a sample behind the newest is a replay: rejected, no fault).
    A stamp must agree with the sample's arrival on this process's clock (:class:`StampClock`; else
    :attr:`bad_stamps`), so the speed gate, which scales with the time between stamps, is opened by the local
    clock, never by a stamp alone; the same clock times the measurements. A sample that repeats or goes back in
    sequence or time, jumps more than ``max_sequence_jump`` ahead or moves faster than ``max_speed`` is rejected
    without moving the stream on, so one forged sample cannot lock it out. Rejected samples that form a
    consistent track of their own for ``resync_samples`` samples are taken (:attr:`resyncs`). Lost samples show
    up as gaps in the sequence (:attr:`missed`).
    """

    RING = 64
    """Samples buffered between polls; at 500 Hz mocap that is 128 ms of poses."""

    def __init__(self, session: zenoh.Session, key: str, settings: SubscriberSettings | None = None,
                 clock=time.monotonic, mac_key: MocapKey | None = None) -> None:
        self.settings = settings or SubscriberSettings()
        self.key = key
        self._clock = clock
        self._mac_key = mac_key
        self._stamps = StampClock(self.settings.stamps)
        self._polled = clock()
        """When the samples were last polled (clock time), s; at first when the subscriber was declared (below):
        nothing the first poll finds arrived before."""
        self._conflicts: list[tuple[float, float]] = []
        """(arrival s, suspect s: :meth:`_conflict`) of the sequence conflicts of the last second."""
        self._untrusted_since: float | None = None
        self._cadence = 0.01
        """The stream's sample interval, s (filtered stamp differences per sequence step)."""
        self._behind_since_accept = False
        """A sample was rejected as not after the newest since the last one taken."""
        self._behind_of: PoseSample | None = None
        """The sample taken that the first such sample fell behind (a forger's, if it was one)."""
        self._lock = threading.Lock()
        self._last: PoseSample | None = None
        self._received_at = 0.0
        self._measurements: deque[PoseMeasurement] = deque(maxlen=self.RING)
        """Taken since the last :meth:`measurements` (the newest ``RING``: older ones are history by then)."""
        self._taken: list[PoseSample] = []
        """Taken in the current poll, timed when it ends."""
        self._source: str | None = None
        self._source_heard = -np.inf
        """When a sample of the source last arrived (clock time), s."""
        self._track: list[PoseSample] = []
        """Rejected samples consistent among themselves (a candidate for resynchronisation)."""
        self._abandoned: PoseSample | None = None
        """The newest sample of the track the stream last resynchronised away from (or of its continuation)."""
        self.rejected = 0
        self.received = 0
        self.accepted = 0
        """Samples handed on as measurements."""
        self.malformed = 0
        self.missed = 0
        self.foreign = 0
        """Samples from a publisher other than the source."""
        self.foreign_sources: set[str] = set()
        self.unauthenticated = 0
        """Samples without a valid MAC (with ``mac_key``)."""
        self.bad_stamps = 0
        """Samples of the source whose stamp disagrees with their arrival time or (with a key) that echo no challenge
        sent within ``fresh_s`` of it (held back on the way)."""
        self.unechoed = 0
        """Of :attr:`bad_stamps`, samples that echo no challenge this subscriber sent in the last second (a bridge
        that hears none: access control; or samples re-sent long after)."""
        self.conflicts = 0
        """Samples taken right after one of another sequence under the same source id was rejected."""
        self.resyncs = 0
        self.handovers = 0
        """Times a new authenticated publisher became the source after the old one's silence (with a key)."""
        self.last_handover = ""
        self.duplicates = 0
        """Exact copies of the newest accepted sample (sequence, stamp and pose): delivered twice by a network or
        a bridge, they say nothing new and nothing wrong, and are dropped."""
        self.last_rejection = ""
        """Why the newest rejected sample was rejected."""
        self._raw: list[tuple[float, bytes, float]] = []
        self._challenger = (session.declare_publisher(challenge_key(key), express=True)
                            if mac_key is not None else None)
        self._challenges: dict[bytes, float] = {}
        """Tokens sent in the last second, with when (clock time), s, oldest first."""
        self._challenger_id = os.urandom(CHALLENGER_BYTES)
        self._counter = 0
        self._challenged = -np.inf
        """When the last challenge was sent (clock time), s. Not at the declaration: what the first poll finds is
        known only to have arrived after it, so a stream held back 60 ms echoing a challenge sent then looked fresh
        (and preflight took it); the first sample or two, before any challenge reached the bridge, are refused."""
        self._sub = session.declare_subscriber(key, zenoh.handlers.RingChannel(self.RING))

    def poll(self) -> int:
        """Take every buffered sample in arrival order; returns how many arrived since the last poll."""
        with self._lock:
            found = []
            while self._sub is not None and (sample := self._sub.try_recv()) is not None:
                found.append(sample)
            # Timed after the drain: a sample that arrived while it ran (the process descheduled in it) must not be
            # timed before its arrival, which would look faster than the fastest path and lower the stream's offset.
            now = self._clock()
            before, self._polled = self._polled, now  # what is found now arrived after ``before``
            if self._challenger is not None and now - self._challenged >= CHALLENGE_S:
                self._challenge(now)
            for sample in found:
                self._accept(sample, now, before)
            n = len(found)
            # Timed once the poll is done: a burst found at once all "arrived" now, and the last of it says best
            # how late that is (the stream's offset after it).
            lat = self.settings.latency
            self._measurements.extend(PoseMeasurement(self._stamps.local(p.stamp) - lat, p.position, p.rotation)
                                      for p in self._taken)
            self._taken.clear()
        return n

    def _challenge(self, now: float) -> None:
        """Send a new token for the publisher to echo, and forget those sent more than a second ago."""
        self._counter += 1
        token = self._challenger_id + self._counter.to_bytes(8, "big")
        payload, tag = encode_challenge(token, self._mac_key, challenge_key(self.key))
        self._challenger.put(payload, attachment=tag)
        self._challenges[token] = self._challenged = now
        while (oldest := next(iter(self._challenges.items())))[1] < now - 1.0:
            del self._challenges[oldest[0]]

    def _unfresh(self, pose: PoseSample, before: float) -> str:
        """Why ``pose`` (keyed; it arrived after ``before``) is not shown fresh ("" if it is): it must echo a
        challenge sent at most ``fresh_s`` before ``before``."""
        sent = max((self._challenges[e] for e in pose.echoes if e in self._challenges), default=None)
        if sent is None:
            self.unechoed += 1
            return "echoes no recent challenge of this ground station"
        return f"echoes a challenge {(before - sent) * 1e3:.0f} ms old" if before - sent > self.settings.fresh_s else ""

    def _why_not(self, pose: PoseSample, last: PoseSample, now: float) -> str:
        """Why ``pose``, arriving at ``now``, cannot follow ``last``; "" if it can."""
        s = self.settings
        ahead = pose.sequence - last.sequence
        if ahead <= 0:
            return f"sequence {pose.sequence} not after {last.sequence}"
        if ahead > s.max_sequence_jump:
            return f"sequence jumps {ahead} ahead"
        if pose.stamp <= last.stamp:
            return "stamp not after the last one"
        if self._conflicts and pose.stamp - last.stamp < 0.5 * self._cadence:
            # A second sender under the source's id answers the genuine samples at once; the genuine publisher
            # keeps its rate. While one is seen, a sample off that rate is not taken (a forger can match the rate
            # too: the defence is the key).
            return f"{(pose.stamp - last.stamp) * 1e3:.1f} ms after the last sample: off the stream's cadence"
        # The gate scales with the time between the samples: the stamps' (precise) unless they claim more than
        # the local clock saw (plus the jitter a stamp may have), so a stamp cannot open it by itself.
        dt = min(pose.stamp - last.stamp, now - self._received_at + s.stamps.max_skew_s)
        step = float(np.linalg.norm(pose.position - last.position))
        if step > s.max_speed * dt + 0.005:
            return f"moves {step:.2f} m in {dt * 1e3:.0f} ms"
        return ""

    def _continues(self, prev: PoseSample, pose: PoseSample) -> bool:
        """``pose`` could follow ``prev`` on one publisher's track (sequence, stamps and speed; no gates)."""
        s = self.settings
        dt = pose.stamp - prev.stamp
        return (0 < pose.sequence - prev.sequence <= s.max_sequence_jump and dt > 0
                and float(np.linalg.norm(pose.position - prev.position)) <= s.max_speed * dt + 0.005)

    def _accept(self, sample: zenoh.Sample, now: float, before: float) -> None:
        payload = sample.payload.to_bytes()
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
        try:
            pose = decode(payload, attachment, self._mac_key, self.key)
        except Unauthenticated:
            self.unauthenticated += 1
            return
        except ValueError:
            self.malformed += 1
            return
        info = sample.source_info
        source = str(info.source_id) if info is not None else "unidentified"
        if self._source is not None and source != self._source and self._may_hand_over(now):
            # Stale on the old source's clock (captured samples sent again, a bridge whose first samples stalled):
            # not taken, and not a second publisher either, so a fresh sample of a restarted bridge after it still
            # hands over (counted as foreign, one stalled sample kept a restart out for good).
            if self._bad_stamp(pose, before, now, "a new publisher's stamp {} ms off the source's clock"):
                return
            self._hand_over(now)
        if self._source is None:
            self._source = source
        elif source != self._source:
            self.foreign += 1
            self.foreign_sources.add(source)
            return
        self._source_heard = now
        self.received += 1
        self._raw.append((now, payload, pose.stamp))
        last = self._last
        if (last is not None and pose.sequence == last.sequence and pose.stamp == last.stamp
                and np.array_equal(pose.position, last.position) and np.array_equal(pose.rotation, last.rotation)):
            # Not a sample behind the stream (a replay or a second sender would be): the same one again.
            self.duplicates += 1
            return
        if self._bad_stamp(pose, before, now, "stamp {} ms off its arrival time"):
            return
        last = self._last
        if last is not None:
            why = self._why_not(pose, last, now)
            if why:
                self.rejected += 1
                self.last_rejection = why
                if pose.sequence <= last.sequence and not self._behind_since_accept:
                    self._behind_since_accept, self._behind_of = True, last
                abandoned = self._abandoned
                if self._mac_key is None and abandoned is not None and self._continues(abandoned, pose):
                    # The track given up at the last resynchronisation goes on: two senders under one id (a forger
                    # sending bursts ahead in sequence was followed 50-82 times a flight, never a conflict).
                    self._abandoned = pose
                    self._conflict(now)
                track = self._track
                if track and not self._continues(track[-1], pose):
                    track.clear()
                track.append(pose)
                if len(track) < self.settings.resync_samples:
                    return
                self.resyncs += 1  # a consistent new track: follow it
                self._abandoned, self._behind_of = last, track[0]  # from its first sample, it may be forged
                track.clear()
                self._take(pose, now, before)
                return
            self._track.clear()
            if self._behind_since_accept and self._mac_key is None:  # with a key, samples behind are replays
                self._conflict(now)
            self.missed += pose.sequence - last.sequence - 1
            if not self._conflicts:  # the stream's own rate, learnt while a single sender is seen
                self._cadence += 0.05 * ((pose.stamp - last.stamp) / (pose.sequence - last.sequence) - self._cadence)
        self._take(pose, now, before)

    def _bad_stamp(self, pose: PoseSample, before: float, now: float, why: str) -> bool:
        """Whether ``pose``'s stamp disagrees with its arrival (after ``before``, by ``now``); if so it is counted,
        and ``why`` (its ``{}`` the disagreement, ms) is the last rejection. With a key the sample's echo comes
        first: held back on the way, it is late whatever its stamp says."""
        stale = self._unfresh(pose, before) if self._mac_key is not None else ""
        if not stale and self._stamps.believable(pose.stamp, before, now):
            return False
        self.rejected += 1
        self.bad_stamps += 1
        late = self._stamps.disagreement(pose.stamp, before, now)
        self.last_rejection = stale or why.format(f"{late * 1e3:+.0f}")
        if not stale and late > 0 and self._stamps.capped(now):
            # The operator's question is why a stream that flowed is late now: its clock has drifted (or its
            # delay grown) as far as the bound allows since it began.
            self.last_rejection += (f", its clock offset already {self._stamps.settings.max_rise_s * 1e3:.0f} ms "
                                    f"above the stream's least (mocap.clock_drift_s): the clocks drifted apart or "
                                    f"the delay grew")
        return True

    def _may_hand_over(self, now: float) -> bool:
        """A sample of another publisher, found at ``now``, may start a new source: it carries the key's MAC (it
        decoded), no second publisher was ever seen beside the source, and the source has been silent for
        ``handover_silence_s``. Its stamp must then be fresh on the old source's clock (a restarted bridge stamps
        on the same host's clock; :meth:`_accept`): a MAC proves who made a sample, not when it is sent. Samples
        captured from the genuine bridge and sent again once it fell silent were taken for a restarted bridge,
        their stamps judged on a clock learnt from them alone, and the blind landing flew on the old poses
        (motors off 0.9-1.1 m up, "landed"; in SITL the V climbed to 3 m; hostile campaign 26). A bridge
        restarted on a clock off by more than ``stamps.max_skew_s`` is never taken: the flight lands blind."""
        return (self._mac_key is not None and not self.foreign
                and now - self._source_heard >= self.settings.handover_silence_s)

    def _hand_over(self, now: float) -> None:
        """Forget the old source: the new one is taken as the first was (its sequence its own); its stamps go on
        being judged on the old source's clock (:meth:`_may_hand_over`); the estimator still judges its poses
        against the body's motion."""
        self.handovers += 1
        self.last_handover = (f"a new publisher on {self.key} after {(now - self._source_heard) * 1e3:.0f} ms of "
                              f"silence (a restarted bridge)")
        self._source = None
        self._last = None
        self._track.clear()
        self._conflicts.clear()
        self._behind_since_accept = False

    def _take(self, pose: PoseSample, now: float, before: float) -> None:
        self._last = pose
        self._received_at = now
        self._stamps.take(pose.stamp, now, before)
        self._taken.append(pose)
        self._behind_since_accept = False
        self.accepted += 1

    def _conflict(self, now: float) -> None:
        """Count a sequence conflict found at ``now``. Its suspect time is the capture time (local clock, as the
        measurements') of the sample the rejected one fell behind, less one sample interval: a forger's sample is
        taken first (its sequence ahead) and the genuine one after it refused, so what was taken from there on may
        be forged. Latched with the fault: :meth:`untrusted_since`."""
        self.conflicts += 1
        behind = self._behind_of
        suspect = self._stamps.local(behind.stamp) - self.settings.latency - self._cadence if behind else now
        self._conflicts = [c for c in self._conflicts if c[0] > now - 1.0] + [(now, suspect)]
        if len(self._conflicts) >= self.settings.max_conflicts and self._untrusted_since is None:
            self._untrusted_since = min(c[1] for c in self._conflicts)

    def untrusted_since(self) -> float | None:
        """Since when (the measurements' capture time, s) the samples may be a second sender's under the source's
        id (the fault "two sequences under one source id": without a key nothing tells its samples from the
        genuine ones); None while no such fault was found. Latched: nothing the stream sends later is trusted."""
        return self._untrusted_since

    def fault(self) -> str:
        """Why the stream cannot be trusted ("" while it can): another publisher on the body's key, or two
        sequences under one source id."""
        if self.foreign:
            return (f"a second publisher on {self.key} ({self.foreign} samples from "
                    f"{len(self.foreign_sources)} other source{'s' if len(self.foreign_sources) > 1 else ''})")
        if self._untrusted_since is not None:
            return (f"two sequences under one source id on {self.key} ({self.conflicts} samples out of sequence: "
                    f"a copied id or replayed samples)")
        return ""

    def measurements(self) -> list[PoseMeasurement]:
        """The samples taken since the last call, in order, timed on the local clock (:class:`PoseMeasurement`)."""
        self.poll()
        with self._lock:
            out = list(self._measurements)
            self._measurements.clear()
        return out

    def now(self) -> float:
        """The clock the measurements are timed on, s."""
        return self._clock()

    def latest(self) -> PoseSample | None:
        self.poll()
        with self._lock:
            return self._last

    def wait_for(self, sequence: int, timeout: float) -> bool:
        """Block until a pose with at least ``sequence`` was accepted; False on timeout."""
        deadline = time.monotonic() + timeout
        while (last := self.latest()) is None or last.sequence < sequence:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.002)
        return True

    def drain_raw(self) -> list[tuple[float, bytes, float]]:
        """(arrival (poll) time on this clock, payload as received, the publisher's stamp) since the last call, for
        logging (samples of the body's source only)."""
        self.poll()
        with self._lock:
            out, self._raw = self._raw, []
        return out

    def close(self) -> None:
        """Stop receiving; the last state stays readable."""
        with self._lock:
            if self._sub is not None:
                self._sub.undeclare()
                self._sub = None
            if self._challenger is not None:
                self._challenger.undeclare()
                self._challenger = None
