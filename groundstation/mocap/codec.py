"""Wire format of motion-capture poses on Zenoh: protobuf ``foxglove.PoseInFrame`` plus an attachment.

Payload: ``foxglove.PoseInFrame`` (frame ``world``, z up, metres; the same bytes are logged to MCAP unchanged and
Foxglove draws them). Attachment: 16 bytes little-endian, ``uint64 sequence`` then ``float64 stamp``, so a
subscriber can detect drops without parsing the payload; with a shared key (:mod:`groundstation.mocap.auth`) the
newest challenge of each of up to :data:`ECHOES` ground stations the publisher heard follows (tokens of
:data:`TOKEN_BYTES`, zeros for none), and a 16-byte MAC over it all (96 bytes in all). The stamp (in the attachment
and the payload's timestamp) is the publisher's wall clock (seconds since the epoch) when the pose was measured: the
clock flight logs use, so a logged pose and the flight's records share one time base (across machines, as far as
their clocks are synchronized).

Challenges (with a key): the ground station puts a token with its MAC on ``<prefix>/<body>/challenge`` at most
every 10 ms: its own random id (8 bytes, new each run) and a counter (8 bytes, big-endian), so the publisher keeps
the newest of each ground station and ignores one that is not newer (a captured challenge put again: it pushed the
genuine ones out, and 70 % of the genuine samples were refused, in a review); it echoes them in each sample. A
sample that echoes a token was made after that token was sent, whatever its stamp says: a man in the middle can
hold the stream back (the MAC stays valid) but not make it echo a challenge sent after it was made, so a delay
longer than the subscriber's ``fresh_s`` shows as an old echo (:class:`~groundstation.mocap.zenoh_link
.PoseSubscriber`), from the stream's first sample on.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from google.protobuf.timestamp_pb2 import Timestamp

from groundstation.mocap.auth import TAG_BYTES, MocapKey
from groundstation.rotations import matrix_to_quat, quat_to_matrix

_ATTACHMENT = struct.Struct("<Qd")
WORLD_FRAME = "world"
CHALLENGER_BYTES = 8
TOKEN_BYTES = CHALLENGER_BYTES + 8
"""A challenge: the ground station's id, then its counter."""
ECHOES = 4
"""Ground stations whose newest challenge each sample echoes (one flight and monitors on the key; a fifth pushes
out the one heard from longest ago)."""
_NO_TOKEN = bytes(TOKEN_BYTES)


class Unauthenticated(ValueError):
    """A sample without a valid MAC where a key is configured."""


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
    echoes: tuple[bytes, ...] = ()
    """The newest challenge token of each ground station the publisher heard (with a key; none without)."""


def pose_message(position: np.ndarray, rotation: np.ndarray, stamp: float, frame: str = WORLD_FRAME) -> PoseInFrame:
    """A ``foxglove.PoseInFrame`` for a position (m) and rotation matrix at ``stamp`` (s)."""
    msg = PoseInFrame(timestamp=Timestamp(seconds=int(stamp), nanos=int((stamp % 1) * 1e9)), frame_id=frame)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = matrix_to_quat(np.asarray(rotation, float))
    return msg


def encode(sample: PoseSample, key: MocapKey | None = None, key_expr: str = "") -> tuple[bytes, bytes]:
    """(payload, attachment) for Zenoh; with ``key``, the attachment carries the sample's echoes and ends with the
    MAC for ``key_expr``."""
    payload = pose_message(sample.position, sample.rotation, sample.stamp).SerializeToString()
    attachment = _ATTACHMENT.pack(sample.sequence, sample.stamp)
    if key is not None:
        echoes = list(sample.echoes[-ECHOES:])
        assert all(len(e) == TOKEN_BYTES for e in echoes), "echoes are challenge tokens"
        attachment += b"".join(echoes + [_NO_TOKEN] * (ECHOES - len(echoes)))
        attachment += key.tag(key_expr, attachment, payload)
    return payload, attachment


def challenge_key(pose_key: str) -> str:
    """Where the challenges for the poses on ``pose_key`` (``<prefix>/<body>/pose``) are put."""
    return pose_key.rpartition("/")[0] + "/challenge"


def encode_challenge(token: bytes, key: MocapKey, key_expr: str) -> tuple[bytes, bytes]:
    """(payload, attachment) of a challenge: the token, and its MAC (only a key holder may challenge: anyone else's
    tokens, echoed, would push the ground station's out)."""
    return token, key.tag(key_expr, b"", token)


def decode_challenge(payload: bytes, attachment: bytes | None, key: MocapKey, key_expr: str) -> bytes | None:
    """The token of a challenge with a valid MAC; None for anything else."""
    if len(payload) != TOKEN_BYTES or payload == _NO_TOKEN or attachment is None:
        return None
    return payload if key.verify(key_expr, b"", payload, attachment) else None


def decode(payload: bytes, attachment: bytes | None, key: MocapKey | None = None, key_expr: str = "") -> PoseSample:
    """Inverse of :func:`encode`; raises ``ValueError`` on malformed input (a stamp that is not a finite,
    non-negative time included) and :class:`Unauthenticated` when ``key`` is given and the MAC is missing or wrong.
    Without a key a MAC is ignored: an unauthenticated subscriber reads an authenticated stream."""
    signed = _ATTACHMENT.size + ECHOES * TOKEN_BYTES
    if attachment is None or len(attachment) not in (_ATTACHMENT.size, signed + TAG_BYTES):
        raise ValueError("missing or malformed sequence/stamp attachment")
    head = attachment[:_ATTACHMENT.size]
    echoes: tuple[bytes, ...] = ()
    if key is not None:
        if len(attachment) == _ATTACHMENT.size:
            raise Unauthenticated("no MAC")
        if not key.verify(key_expr, attachment[:signed], payload, attachment[signed:]):
            raise Unauthenticated("wrong MAC")
        echoes = tuple(e for i in range(_ATTACHMENT.size, signed, TOKEN_BYTES)
                       if (e := attachment[i:i + TOKEN_BYTES]) != _NO_TOKEN)
    msg = PoseInFrame()
    try:
        msg.ParseFromString(payload)
    except Exception as exc:  # protobuf raises its own DecodeError type
        raise ValueError(f"not a foxglove.PoseInFrame: {exc}") from None
    seq, stamp = _ATTACHMENT.unpack(head)
    if not (np.isfinite(stamp) and stamp >= 0.0):
        raise ValueError(f"stamp {stamp} is not a time")
    p, o = msg.pose.position, msg.pose.orientation
    q = np.array([o.x, o.y, o.z, o.w])
    pos = np.array([p.x, p.y, p.z])
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(pos))) or abs(np.linalg.norm(q) - 1.0) > 1e-3:
        raise ValueError("pose is not finite or its orientation is not a unit quaternion")
    return PoseSample(seq, stamp, pos, quat_to_matrix(q), echoes)
