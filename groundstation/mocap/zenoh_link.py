"""Mocap poses over Zenoh: session set-up, a publisher per rigid body, and a subscriber that estimates state.

Sessions default to peer mode on an explicit loopback endpoint with multicast scouting off (no traffic leaves
the machine unless the config names another endpoint). One side listens, the other connects. Sessions are
closed explicitly (an unclosed session keeps the process alive at exit).
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass

import numpy as np
import zenoh

from groundstation.control.state import RigidState
from groundstation.errors import GroundstationError
from groundstation.mocap.codec import PoseSample, decode, encode
from groundstation.rotations import matrix_to_rotvec


class LinkError(GroundstationError):
    """A Zenoh session could not be opened (endpoint in use, malformed, unreachable)."""


def open_session(listen: list[str] | None = None, connect: list[str] | None = None) -> zenoh.Session:
    """A peer-mode session listening on and/or connecting to explicit endpoints, multicast scouting off."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("listen/endpoints", json.dumps(list(listen or [])))
    cfg.insert_json5("connect/endpoints", json.dumps(list(connect or [])))
    try:
        return zenoh.open(cfg)
    except Exception as exc:  # zenoh raises ZError carrying the transport's reason
        raise LinkError(f"cannot open Zenoh session (listen {listen}, connect {connect}): {exc}") from None


def pose_key(prefix: str, body: str) -> str:
    return f"{prefix}/{body}/pose"


class PosePublisher:
    """Publishes poses of one rigid body on its key (``<prefix>/<body>/pose``)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self._pub = session.declare_publisher(key, express=True)
        self._seq = 0

    def publish(self, position: np.ndarray, rotation: np.ndarray, stamp: float) -> PoseSample:
        self._seq += 1
        sample = PoseSample(self._seq, stamp, np.asarray(position, float), np.asarray(rotation, float))
        payload, attachment = encode(sample)
        self._pub.put(payload, attachment=attachment)
        return sample

    def close(self) -> None:
        self._pub.undeclare()


@dataclass(frozen=True)
class SubscriberSettings:
    max_speed: float = 10.0
    """A pose implying a faster move than this from the last accepted one is rejected as an outlier, m/s."""
    velocity_cutoff_hz: float = 8.0
    """First-order low-pass on the finite-difference velocities, Hz."""


class PoseSubscriber:
    """Keeps the newest pose of one body, rejects jumps, estimates linear and angular velocity.

    Samples wait in a Zenoh ring buffer (the newest ``RING`` kept) and are decoded when the control loop asks for
    the state, on the caller's thread. A Python callback would run on Zenoh's thread and take the GIL away from
    the control loop at every sample; measured at 500 Hz that was the largest source of late periods. The cost is
    that arrival is timed when the samples are polled, at most one control period late. Lost samples show up as
    gaps in the publisher's sequence numbers (:attr:`missed`).
    """

    RING = 64
    """Samples buffered between polls; at 500 Hz mocap that is 128 ms of poses."""

    def __init__(self, session: zenoh.Session, key: str, settings: SubscriberSettings | None = None,
                 clock=time.monotonic) -> None:
        self.settings = settings or SubscriberSettings()
        self._clock = clock
        self._lock = threading.Lock()
        self._last: PoseSample | None = None
        self._received_at = 0.0
        self._velocity = np.zeros(3)
        self._omega = np.zeros(3)
        self.rejected = 0
        self.received = 0
        self.accepted = 0
        """Samples the estimate used."""
        self.malformed = 0
        self.missed = 0
        self._raw: list[tuple[float, bytes, float]] = []
        self._sub = session.declare_subscriber(key, zenoh.handlers.RingChannel(self.RING))

    def poll(self) -> int:
        """Take every buffered sample in arrival order; returns how many arrived since the last poll."""
        n = 0
        with self._lock:
            while self._sub is not None and (sample := self._sub.try_recv()) is not None:
                n += 1
                self._accept(sample, self._clock())
        return n

    def _accept(self, sample: zenoh.Sample, now: float) -> None:
        payload = sample.payload.to_bytes()
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
        try:
            pose = decode(payload, attachment)
        except ValueError:
            self.malformed += 1
            return
        self.received += 1
        self._raw.append((now, payload, pose.stamp))
        last = self._last
        if last is not None:
            if pose.sequence <= last.sequence:
                return  # repeated or out of order
            self.missed += pose.sequence - last.sequence - 1
            dt = pose.stamp - last.stamp
            step = float(np.linalg.norm(pose.position - last.position))
            if dt <= 0 or step > self.settings.max_speed * dt + 0.005:
                self.rejected += 1
                return
            a = 1.0 - np.exp(-2 * np.pi * self.settings.velocity_cutoff_hz * dt)
            self._velocity += a * ((pose.position - last.position) / dt - self._velocity)
            self._omega += a * (matrix_to_rotvec(last.rotation.T @ pose.rotation) / dt - self._omega)
        self._last = pose
        self._received_at = now
        self.accepted += 1

    def state(self) -> RigidState | None:
        """Newest accepted pose with filtered velocities (angular: body frame), or None before the first."""
        self.poll()
        with self._lock:
            if self._last is None:
                return None
            return RigidState(self._last.position.copy(), self._velocity.copy(), self._last.rotation.copy(),
                              self._omega.copy())

    def latest(self) -> PoseSample | None:
        self.poll()
        with self._lock:
            return self._last

    def age(self) -> float:
        """Seconds since the newest accepted pose was polled (inf before the first)."""
        self.poll()
        with self._lock:
            return self._clock() - self._received_at if self._last is not None else float("inf")

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
        logging."""
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
