"""Wire format of motion-capture poses on Zenoh: protobuf ``foxglove.PoseInFrame`` plus an attachment.

Payload: ``foxglove.PoseInFrame`` (frame ``world``, z up, metres; the same bytes are logged to MCAP unchanged and
Foxglove draws them). Attachment: 16 bytes little-endian, ``uint64 sequence`` then ``float64 stamp``, so a
subscriber can detect drops without parsing the payload. The stamp (in the attachment and the payload's
timestamp) is the publisher's wall clock (seconds since the epoch) when the pose was measured: the clock flight
logs use, so a logged pose and the flight's records share one time base (across machines, as far as their clocks
are synchronized).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from google.protobuf.timestamp_pb2 import Timestamp

from groundstation.rotations import matrix_to_quat, quat_to_matrix

_ATTACHMENT = struct.Struct("<Qd")
WORLD_FRAME = "world"


@dataclass(frozen=True, eq=False)
class PoseSample:
    """One measured pose of a rigid body."""

    sequence: int
    stamp: float
    """Measurement time, publisher's wall clock, s since the epoch."""
    position: np.ndarray
    """World frame, m."""
    rotation: np.ndarray
    """Body-to-world rotation."""


def pose_message(position: np.ndarray, rotation: np.ndarray, stamp: float, frame: str = WORLD_FRAME) -> PoseInFrame:
    """A ``foxglove.PoseInFrame`` for a position (m) and rotation matrix at ``stamp`` (s)."""
    msg = PoseInFrame(timestamp=Timestamp(seconds=int(stamp), nanos=int((stamp % 1) * 1e9)), frame_id=frame)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = matrix_to_quat(np.asarray(rotation, float))
    return msg


def encode(sample: PoseSample) -> tuple[bytes, bytes]:
    """(payload, attachment) for Zenoh."""
    payload = pose_message(sample.position, sample.rotation, sample.stamp).SerializeToString()
    return payload, _ATTACHMENT.pack(sample.sequence, sample.stamp)


def decode(payload: bytes, attachment: bytes | None) -> PoseSample:
    """Inverse of :func:`encode`; raises ``ValueError`` on malformed input."""
    msg = PoseInFrame()
    try:
        msg.ParseFromString(payload)
    except Exception as exc:  # protobuf raises its own DecodeError type
        raise ValueError(f"not a foxglove.PoseInFrame: {exc}") from None
    if attachment is None or len(attachment) != _ATTACHMENT.size:
        raise ValueError("missing or malformed sequence/stamp attachment")
    seq, stamp = _ATTACHMENT.unpack(attachment)
    p, o = msg.pose.position, msg.pose.orientation
    q = np.array([o.x, o.y, o.z, o.w])
    pos = np.array([p.x, p.y, p.z])
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(pos))) or abs(np.linalg.norm(q) - 1.0) > 1e-3:
        raise ValueError("pose is not finite or its orientation is not a unit quaternion")
    return PoseSample(seq, stamp, pos, quat_to_matrix(q))
