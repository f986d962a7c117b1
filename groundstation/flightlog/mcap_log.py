"""One MCAP file per flight, written off the control thread, finalized on every exit path.

Protobuf channels use Foxglove's schemas so Foxglove shows the flight in 3D without set-up: mocap poses as
received (``/mocap/<body>``, the Zenoh payload bytes unchanged), the state estimate (``/state/pose``),
transforms world -> body (``/tf``), the assembly as a scene (``/scene``), events and errors (``/log``).
Numeric records go on JSON channels with a JSON schema, which Foxglove plots directly: ``/control`` (one per
period: flight state, setpoint, desired wrench, per-module motor commands, loop timing), ``/backend/telemetry``,
``/loop/timing`` (summary), ``/flight/summary``.

Robustness: chunks are small (32 KiB) and the file is flushed about once a second, so after SIGKILL every
complete chunk is on disk; :func:`recover` reads such a file with a streaming reader and writes a finalized
copy. :meth:`FlightLog.close` finishes the file (summary, footer) and is called on normal exit, Ctrl-C and
SIGTERM.
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.timestamp_pb2 import Timestamp
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import register_schema

from groundstation.assembly.assembly import Assembly
from groundstation.rotations import matrix_to_quat
from groundstation.runtime.loop import LoopActivity

CHUNK_BYTES = 32 * 1024
FLUSH_S = 1.0
POLL_S = 0.02
ITEM_BUDGET_S = 1e-3
"""Idle time the writer wants left before the next control period to start a message, s. Most messages take
< 0.1 ms (one that closes a chunk up to ~0.5 ms), but at 500 Hz a 0.4 ms budget still left 2 late periods per
minute with real-time priority and 1 ms left none in 3 of 4 runs (compute p99 0.55-0.88 ms -> 0.34-0.58 ms)."""
"""The writer's wake-up interval when no control loop signals the end of its periods, s."""
_JSON_SCHEMA = json.dumps({"type": "object"}).encode()
LEVELS = {"debug": Log.DEBUG, "info": Log.INFO, "warning": Log.WARNING, "error": Log.ERROR, "fatal": Log.FATAL}


def _jsonable(value):
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    raise TypeError(f"cannot log a {type(value).__name__} as JSON")


def _stamp(t: float) -> Timestamp:
    return Timestamp(seconds=int(t), nanos=int((t % 1) * 1e9))


class FlightLog:
    """Thread-safe, non-blocking logger: calls enqueue, a writer thread encodes and writes."""

    def __init__(self, path: str | Path, metadata: dict[str, str] | None = None,
                 activity: LoopActivity | None = None) -> None:
        self.path = Path(path)
        self._fh = self.path.open("wb")
        self._writer = Writer(self._fh, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="groundstation")
        for name, data in (metadata or {}).items():
            self._writer.add_metadata(name, {"value": data})
        self._channels: dict[str, int] = {}
        # Producers append without waking the writer; it runs between control periods (see LoopActivity).
        self._items: deque = deque()
        self._activity = activity or LoopActivity()
        self._closed = False
        self.dropped = 0
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
        self._thread.start()

    # -- producer side (any thread) ------------------------------------------------------------------------------
    def protobuf(self, topic: str, message, t: float) -> None:
        self._put(("pb", topic, message, t))

    def raw_protobuf(self, topic: str, message_type, payload: bytes, t: float) -> None:
        """Log already-serialized protobuf bytes (e.g. a Zenoh payload) under ``message_type``'s schema."""
        self._put(("raw", topic, (message_type, payload), t))

    def record(self, topic: str, data: dict, t: float) -> None:
        """A JSON record; numpy values are converted on the writer thread (pass copies of arrays you reuse)."""
        self._put(("json", topic, data, t))

    def event(self, level: str, text: str, t: float, name: str = "groundstation") -> None:
        self._put(("pb", "/log", Log(timestamp=_stamp(t), level=LEVELS[level], message=text, name=name), t))

    def pose(self, topic: str, position, rotation, t: float) -> None:
        """A pose on ``topic`` and the matching world -> body transform on ``/tf`` (built on the writer thread)."""
        self._put(("pose", topic, (np.array(position, float), np.array(rotation, float)), t))

    def _pose_messages(self, topic: str, position, rotation, t: float) -> None:
        msg = PoseInFrame(timestamp=_stamp(t), frame_id="world")
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = matrix_to_quat(rotation)
        tf = FrameTransform(timestamp=_stamp(t), parent_frame_id="world", child_frame_id="body")
        tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in position)
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = o.x, o.y, o.z, o.w
        for top, m in ((topic, msg), ("/tf", tf)):
            ns = int(t * 1e9)
            self._writer.add_message(self._channel(top, "pb", type(m)), log_time=ns, data=m.SerializeToString(),
                                     publish_time=ns)

    def scene(self, assembly: Assembly, t: float) -> None:
        """The assembly as cubes (modules) and arrows (thrust axes) in the ``body`` frame."""
        upd = SceneUpdate()
        ent = upd.entities.add(timestamp=_stamp(t), frame_id="body", id="assembly")
        hx, hy, hz = assembly.params.frame_half_extents
        for p, r in zip(assembly.module_positions, assembly.module_rotations, strict=True):
            cube = ent.cubes.add()
            cube.pose.position.x, cube.pose.position.y, cube.pose.position.z = (float(v) for v in p)
            q = cube.pose.orientation
            q.x, q.y, q.z, q.w = matrix_to_quat(r)
            cube.size.x, cube.size.y, cube.size.z = 2 * hx, 2 * hy, 2 * hz
            cube.color.r, cube.color.g, cube.color.b, cube.color.a = 0.1, 0.1, 0.1, 0.9
        self.protobuf("/scene", upd, t)

    def _put(self, item) -> None:
        if self._closed:
            self.dropped += 1
            return
        self._items.append(item)

    # -- writer thread -------------------------------------------------------------------------------------------
    def _channel(self, topic: str, kind: str, message_type) -> int:
        if topic not in self._channels:
            if kind == "json":
                sid = self._writer.register_schema(topic.strip("/").replace("/", "."), "jsonschema", _JSON_SCHEMA)
                self._channels[topic] = self._writer.register_channel(topic, "json", sid)
            else:
                sid = register_schema(self._writer, message_type)
                self._channels[topic] = self._writer.register_channel(topic, "protobuf", sid)
        return self._channels[topic]

    def _run(self) -> None:
        last_flush = time.monotonic()
        try:
            stopping = False
            while not stopping:
                self._activity.wait_end(POLL_S)
                # Between periods only (or once closing): finish the backlog, message by message.
                while self._items and (self._activity.may_work(ITEM_BUDGET_S) or self._closed):
                    item = self._items.popleft()
                    if item[0] == "stop":
                        stopping = True
                        break
                    self._write(item)
                if time.monotonic() - last_flush >= FLUSH_S:
                    self._fh.flush()
                    last_flush = time.monotonic()
        except BaseException as exc:  # surfaced to the main loop through .error
            self.error = exc

    def _write(self, item) -> None:
        kind, topic, data, t = item
        if kind == "pose":
            self._pose_messages(topic, *data, t)
            return
        if kind == "json":
            cid, payload = self._channel(topic, kind, None), json.dumps(data, default=_jsonable).encode()
        elif kind == "raw":
            cid, payload = self._channel(topic, kind, data[0]), data[1]
        else:
            cid, payload = self._channel(topic, kind, type(data)), data.SerializeToString()
        ns = int(t * 1e9)
        self._writer.add_message(cid, log_time=ns, data=payload, publish_time=ns)

    def close(self, timeout: float = 10.0) -> None:
        """Write what is queued, finish the file (summary and footer) and close it. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._items.append(("stop", None, None, 0.0))
        self._activity.end()  # wake the writer now (harmless to a loop: it has finished when we close)
        self._thread.join(timeout)
        self._writer.finish()
        self._fh.close()

    def __enter__(self) -> FlightLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def recover(src: str | Path, dst: str | Path) -> dict:
    """Copy every complete record of a possibly truncated MCAP (e.g. after SIGKILL) into a finalized file.

    Returns counts: messages recovered, channels, and whether the source ended cleanly.
    """
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[Message] = []
    clean = True
    with open(src, "rb") as fh:
        try:
            for rec in StreamReader(fh).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                elif isinstance(rec, Message):
                    messages.append(rec)
        except Exception:  # truncated tail: everything before it is kept
            clean = False
    with open(dst, "wb") as out:
        w = Writer(out, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        w.start(profile="", library="groundstation recover")
        schema_map = {sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in schemas.items()}
        chan_map = {cid: w.register_channel(c.topic, c.message_encoding, schema_map.get(c.schema_id, 0),
                                            dict(c.metadata)) for cid, c in channels.items()}
        kept = 0
        for m in messages:
            if m.channel_id in chan_map:
                w.add_message(chan_map[m.channel_id], m.log_time, m.data, m.publish_time, m.sequence)
                kept += 1
        w.finish()
    return {"messages": kept, "channels": len(chan_map), "source_was_complete": clean}
