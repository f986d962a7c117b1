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

    Callbacks run on Zenoh's thread; :meth:`state` and :meth:`age` are safe to call from the control loop.
    """

    def __init__(self, session: zenoh.Session, key: str, settings: SubscriberSettings | None = None,
                 clock=time.monotonic) -> None:
        self.settings = settings or SubscriberSettings()
        self._clock = clock
        self._cond = threading.Condition()
        self._last: PoseSample | None = None
        self._received_at = 0.0
        self._velocity = np.zeros(3)
        self._omega = np.zeros(3)
        self.rejected = 0
        self.received = 0
        self.malformed = 0
        self._raw: list[tuple[float, bytes]] = []
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
        try:
            pose = decode(payload, attachment)
        except ValueError:
            with self._cond:
                self.malformed += 1
            return
        now = self._clock()
        with self._cond:
            self.received += 1
            self._raw.append((now, payload))
            last = self._last
            if last is not None:
                if pose.sequence <= last.sequence:
                    return  # repeated or out of order
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
            self._cond.notify_all()

    def state(self) -> RigidState | None:
        """Newest accepted pose with filtered velocities (angular: body frame), or None before the first."""
        with self._cond:
            if self._last is None:
                return None
            return RigidState(self._last.position.copy(), self._velocity.copy(), self._last.rotation.copy(),
                              self._omega.copy())

    def latest(self) -> PoseSample | None:
        with self._cond:
            return self._last

    def age(self) -> float:
        """Seconds since the newest accepted pose arrived (inf before the first)."""
        with self._cond:
            return self._clock() - self._received_at if self._last is not None else float("inf")

    def wait_for(self, sequence: int, timeout: float) -> bool:
        """Block until a pose with at least ``sequence`` was accepted; False on timeout."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._last is None or self._last.sequence < sequence:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._cond.wait(remaining)
            return True

    def drain_raw(self) -> list[tuple[float, bytes]]:
        """Payloads as received, with arrival times, since the last call (for logging)."""
        with self._cond:
            out, self._raw = self._raw, []
        return out

    def close(self) -> None:
        self._sub.undeclare()
