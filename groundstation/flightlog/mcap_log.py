"""One MCAP file per flight, written by a process of its own, finalized on every exit path.

Protobuf channels use Foxglove's schemas so Foxglove shows the flight in 3D without set-up: mocap poses as
received (``/mocap/<body>``, the Zenoh payload bytes unchanged; publish time = the mocap's stamp), the state
estimate (``/state/pose``), transforms world -> body -> module_<i> (``/tf``), the assembly, the reference path
and the geofence as a scene (``/scene``, :mod:`groundstation.flightlog.scene`), events and errors (``/log``).
Numeric records go on JSON channels, each with its JSON Schema (:mod:`groundstation.flightlog.schemas`), which
Foxglove plots directly: ``/control`` (one per period: phase, the state the controller used, setpoint, attitude
target, roll and yaw targets, desired wrench, per-module motor commands, mocap age, loop timing),
``/backend/telemetry`` (with link quality), ``/mocap/stats``, ``/loop/timing`` (summary), ``/flight/summary``.
Every record's log time is on one clock (the flight's, as seconds since the epoch). The resolved config, the code
version and the assembly are metadata, written first (a recovered log keeps them).

Why a process: encoding and writing MCAP is Python work (JSON, protobuf, the ``mcap`` writer, chunk
compression), and in the flight process it competed with the control loop for the GIL even when done between
periods: with the writer doing nothing, real-time 500 Hz runs had no late periods, with it 0-2 per minute. Here
the flight process only appends to a deque; a feeder thread, between control periods, pickles what has queued
into one frame down the writer's stdin (a few microseconds of GIL), and the writer process does the rest. The
writer is started as ``python -m groundstation.flightlog.mcap_log``, not with multiprocessing, whose "spawn"
would re-run the caller's main script in the child unless it is guarded by ``if __name__ == "__main__"``.

Live view: with ``live_port``, the writer process also serves every record over the Foxglove WebSocket protocol
(``foxglove-sdk``), so Foxglove shows the flight as it happens, at no cost to the flight process.

Robustness: chunks are small (32 KiB) and the file is flushed about once a second. :meth:`FlightLog.close`
finishes the file (summary, footer) and is called on normal exit, Ctrl-C and SIGTERM. If the flight process is
killed (SIGKILL), the writer sees its pipe close and finishes the file itself, losing only what had not been fed
to it yet (under one control period). If both are killed, every complete chunk is on disk and :func:`recover`
reads the file with a streaming reader and writes a finalized copy.
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import select
import struct
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from google.protobuf.timestamp_pb2 import Timestamp
from mcap.records import Attachment, Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from groundstation.assembly.assembly import Assembly
from groundstation.flightlog.scene import module_transforms, scene
from groundstation.flightlog.schemas import schema_of
from groundstation.loop_activity import LoopActivity
from groundstation.rotations import matrix_to_quat

CHUNK_BYTES = 32 * 1024
FLUSH_S = 1.0
POLL_S = 0.02
"""Wake-up interval of the feeder when no control loop signals the end of its periods, and of the writer
process between batches (for its once-a-second flush), s."""
FEED_BUDGET_S = 5e-4
"""Idle time the feeder wants left before the next control period to pickle and send a batch, s."""
FEED_BATCH = 16
"""Most items pickled at once (measured: 16 typical items in ~20 us). A backlog, e.g. what queued while the
writer process was still starting, goes out in pieces between periods: sent whole, it held the GIL across the
first periods' starts (5 late periods in the first 50 ms of a 500 Hz flight)."""
CLOSE_TIMEOUT_S = 10.0
_FRAME = struct.Struct("<I")
"""Length prefix of each pickled batch on the writer's stdin."""
LEVELS = {"debug": Log.DEBUG, "info": Log.INFO, "warning": Log.WARNING, "error": Log.ERROR, "fatal": Log.FATAL}


def _jsonable(value):
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    raise TypeError(f"cannot log a {type(value).__name__} as JSON")


def _rpy_deg(r: np.ndarray) -> list[float]:
    """ZYX roll, pitch, yaw of a rotation matrix, deg."""
    return np.degrees([np.arctan2(r[2, 1], r[2, 2]), -np.arcsin(np.clip(r[2, 0], -1, 1)),
                       np.arctan2(r[1, 0], r[0, 0])]).tolist()


def _with_attitudes(data):
    """A JSON record with every ``rotation`` matrix replaced by ``orientation`` (quaternion) and ``rpy_deg``."""
    if not isinstance(data, dict):
        return data
    out = {}
    for k, v in data.items():
        if k == "rotation":
            r = np.asarray(v, float)
            out["orientation"] = list(matrix_to_quat(r))
            out["rpy_deg"] = _rpy_deg(r)
        else:
            out[k] = _with_attitudes(v)
    return out


def _stamp(t: float) -> Timestamp:
    return Timestamp(seconds=int(t), nanos=int((t % 1) * 1e9))


class FlightLog:
    """Thread-safe, non-blocking logger: calls enqueue; a feeder thread hands batches to the writer process."""

    def __init__(self, path: str | Path, metadata: dict[str, str] | None = None,
                 activity: LoopActivity | None = None, live_port: int | None = None) -> None:
        self.path = Path(path)
        # A session of its own: the operator's Ctrl-C (a signal to the terminal's process group) lands the flight
        # and must not kill the log; the writer ends when its input does, at close or when this process dies.
        self._process = subprocess.Popen([sys.executable, "-m", "groundstation.flightlog.mcap_log"],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True)
        self._send([("open", str(self.path), {"metadata": dict(metadata or {}), "live_port": live_port}, 0.0)])
        # Producers append without waking anyone; the feeder runs between control periods (see LoopActivity).
        self._items: deque = deque()
        self._schemas: set[str] = set()
        """Protobuf schemas already sent to the writer (message classes do not pickle; descriptors do)."""
        self._activity = activity or LoopActivity()
        self._closed = False
        self.dropped = 0
        self.error: str | None = None
        """Why the writer failed (None while it works)."""
        self.writer_pid = self._process.pid
        """The writer process (it outlives this one if this one is killed)."""
        self._thread = threading.Thread(target=self._feed, name="mcap-feeder", daemon=True)
        self._thread.start()

    # -- producer side (any thread) ------------------------------------------------------------------------------
    def protobuf(self, topic: str, message, t: float) -> None:
        self.raw_protobuf(topic, type(message), message.SerializeToString(), t)

    def raw_protobuf(self, topic: str, message_type, payload: bytes, t: float,
                     publish_time: float | None = None) -> None:
        """Log already-serialized protobuf bytes (e.g. a Zenoh payload) under ``message_type``'s schema, at log time
        ``t``; ``publish_time`` (default ``t``) is when the source produced it (s since the epoch)."""
        name = message_type.DESCRIPTOR.full_name
        if name not in self._schemas:  # once per type, before its first message
            # Queued before the name is marked sent, so another thread's message of this type cannot overtake it
            # (two threads may both send it; the writer registers it once).
            self._put(("schema", name, build_file_descriptor_set(message_type).SerializeToString(), t))
            self._schemas.add(name)
        self._put(("pb", topic, (name, payload, t if publish_time is None else publish_time), t))

    def record(self, topic: str, data: dict, t: float) -> None:
        """A JSON record; numpy values are converted by the writer (pass copies of arrays you reuse)."""
        self._put(("json", topic, data, t))

    def event(self, level: str, text: str, t: float, name: str = "groundstation") -> None:
        self.protobuf("/log", Log(timestamp=_stamp(t), level=LEVELS[level], message=text, name=name), t)

    def pose(self, topic: str, position, rotation, t: float) -> None:
        """A pose on ``topic`` and the matching world -> body transform on ``/tf`` (built by the writer)."""
        self._put(("pose", topic, (np.array(position, float), np.array(rotation, float)), t))

    def scene(self, assembly: Assembly, t: float, reference: np.ndarray | None = None,
              geofence: tuple | None = None) -> None:
        """The assembly (frame-locked to ``body``), the module frames, the reference path and the geofence (see
        :mod:`groundstation.flightlog.scene`)."""
        for tf in module_transforms(assembly, t):
            self.protobuf("/tf", tf, t)
        self.protobuf("/scene", scene(assembly, t, reference, geofence), t)

    def _put(self, item) -> None:
        if self._closed or self.error is not None:
            self.dropped += 1  # counted, not kept: a dead writer must not grow the queue for the rest of a flight
            return
        self._items.append(item)

    # -- feeder thread ----------------------------------------------------------------------------------------------
    def _feed(self) -> None:
        try:
            while True:
                self._activity.wait_end(POLL_S)
                if self._process.poll() is not None:  # the writer died (a full disk, a crash, killed)
                    self._writer_gone()
                    return
                while self._items and (self._activity.may_work(FEED_BUDGET_S) or self._closed):
                    batch = [self._items.popleft() for _ in range(min(FEED_BATCH, len(self._items)))]
                    self._send(batch)
                    if batch[-1][0] == "stop":
                        return
        except OSError:  # the writer process is gone
            self._writer_gone()

    def _writer_gone(self) -> None:
        """Record why the writer stopped (its last words, or its exit) and stop queueing: :attr:`error` is what
        the flight watches."""
        why = ""
        with contextlib.suppress(OSError, ValueError):
            self._process.wait(1.0)
            why = json.loads(self._process.stdout.read() or b"{}").get("error") or ""
        code = self._process.poll()
        self.error = self.error or (why or f"the writer process stopped (exit code {code})")
        self.dropped += len(self._items)
        self._items.clear()

    def _send(self, batch: list) -> None:
        frame = pickle.dumps(batch, protocol=pickle.HIGHEST_PROTOCOL)
        self._process.stdin.write(_FRAME.pack(len(frame)) + frame)
        self._process.stdin.flush()

    def close(self, timeout: float = CLOSE_TIMEOUT_S) -> None:
        """Write what is queued, finish the file (summary and footer) and close it. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._items.append(("stop", None, None, 0.0))
        self._activity.end()  # wake the feeder now (harmless to a loop: it has finished when we close)
        self._thread.join(timeout)
        try:  # closes the writer's stdin: it finishes the file even if "stop" did not get through
            out, _ = self._process.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self._process.kill()
            out, _ = self._process.communicate()
        except (OSError, ValueError):  # the writer died earlier and its pipes are gone (error already known)
            out = b""
        with contextlib.suppress(ValueError):
            self.error = json.loads(out or b"{}").get("error") or self.error
        if self._process.returncode != 0 and self.error is None:
            self.error = f"the writer process exited with code {self._process.returncode}"

    def __enter__(self) -> FlightLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


LIBRARY = "groundstation"
"""The MCAP header's library field: how replay recognizes a flight log of this program."""


class _Live:
    """Every written record also served over the Foxglove WebSocket protocol (``foxglove-sdk``).

    The server starts with the first ``/control`` record, once the flight has created the channels a client
    subscribes to at once (mocap, transforms, scene, state, control): channels that exist when a client connects
    are advertised with the connection, while foxglove-sdk 0.30.3 can refuse a subscription sent the instant a
    channel is advertised to an already connected client (3 runs in 8 under a CPU hog: "Unknown channel ID"). The
    Foxglove app retries its connection until the server is up."""

    START_TOPIC = "/control"

    def __init__(self, port: int) -> None:
        import foxglove

        self._foxglove = foxglove
        self.port = port
        self._server = None
        self._channels: dict[str, object] = {}

    def publish(self, topic: str, encoding: str, schema_name: str, schema_encoding: str, schema: bytes,
                payload: bytes, ns: int) -> None:
        """Raises what starting the server raises (a port in use) at the first ``/control`` record."""
        ch = self._channels.get(topic)
        if ch is None:
            fg = self._foxglove
            ch = self._channels[topic] = fg.Channel(topic, message_encoding=encoding,
                                                    schema=fg.Schema(name=schema_name, encoding=schema_encoding,
                                                                     data=schema))
        ch.log(payload, log_time=ns)
        if self._server is None and topic == self.START_TOPIC:
            self._server = self._foxglove.start_server(name="groundstation", host="127.0.0.1", port=self.port)

    def close(self) -> None:
        if self._server is not None:
            self._server.stop()


class _Writer:
    """The MCAP file, in the writer process."""

    def __init__(self, path: str, metadata: dict[str, str], live_port: int | None = None) -> None:
        self._fh = open(path, "wb")  # noqa: SIM115 (closed in finish)
        self._mcap = Writer(self._fh, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        self._mcap.start(profile="", library=LIBRARY)
        for name, data in metadata.items():
            self._mcap.add_metadata(name, {"value": data})
        self._fh.flush()  # the metadata is on disk before the first message: a recovered log keeps it
        self._channels: dict[str, tuple[int, str, str, str, bytes]] = {}
        """topic -> (channel id, message encoding, schema name, schema encoding, schema data)."""
        self._schemas: dict[str, tuple[int, bytes]] = {}
        for cls in (PoseInFrame, FrameTransform, Log):  # pose items are built here; Log for the live-view notice
            self._schema(cls.DESCRIPTOR.full_name, build_file_descriptor_set(cls).SerializeToString())
        self._live = _Live(live_port) if live_port else None

    def _schema(self, name: str, descriptor_set: bytes) -> None:
        if name not in self._schemas:
            self._schemas[name] = (self._mcap.register_schema(name, "protobuf", descriptor_set), descriptor_set)

    def _channel(self, topic: str, schema: str | None) -> tuple[int, str, str, str, bytes]:
        """The channel of ``topic``: protobuf of ``schema`` (registered before), or JSON if None."""
        if topic not in self._channels:
            if schema is None:
                name, data = topic.strip("/").replace("/", "."), schema_of(topic)
                sid = self._mcap.register_schema(name, "jsonschema", data)
                self._channels[topic] = (self._mcap.register_channel(topic, "json", sid), "json", name,
                                         "jsonschema", data)
            else:
                sid, data = self._schemas[schema]
                self._channels[topic] = (self._mcap.register_channel(topic, "protobuf", sid), "protobuf", schema,
                                         "protobuf", data)
        return self._channels[topic]

    def _add(self, topic: str, schema: str | None, payload: bytes, t: float, publish: float | None = None) -> None:
        ns = int(t * 1e9)
        cid, encoding, schema_name, schema_encoding, schema_data = self._channel(topic, schema)
        self._mcap.add_message(cid, log_time=ns, data=payload,
                               publish_time=ns if publish is None else int(publish * 1e9))
        if self._live is not None:
            try:
                self._live.publish(topic, encoding, schema_name, schema_encoding, schema_data, payload, ns)
            except Exception as exc:  # noqa: BLE001 - a port in use must not cost the log
                port, self._live = self._live.port, None
                note = Log(timestamp=_stamp(t), level=Log.WARNING, name="groundstation",
                           message=f"live view on port {port} unavailable: {exc}")
                self._add("/log", Log.DESCRIPTOR.full_name, note.SerializeToString(), t)

    def write(self, item) -> None:
        kind, topic, data, t = item
        if kind == "schema":
            self._schema(topic, data)
        elif kind == "pose":
            position, rotation = data
            msg = PoseInFrame(timestamp=_stamp(t), frame_id="world")
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
            o = msg.pose.orientation
            o.x, o.y, o.z, o.w = matrix_to_quat(rotation)
            tf = FrameTransform(timestamp=_stamp(t), parent_frame_id="world", child_frame_id="body")
            tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in position)
            tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = o.x, o.y, o.z, o.w
            self._add(topic, PoseInFrame.DESCRIPTOR.full_name, msg.SerializeToString(), t)
            self._add("/tf", FrameTransform.DESCRIPTOR.full_name, tf.SerializeToString(), t)
        elif kind == "json":
            self._add(topic, None, json.dumps(_with_attitudes(data), default=_jsonable).encode(), t)
        else:
            self._add(topic, data[0], data[1], t, data[2])

    def flush(self) -> None:
        self._fh.flush()

    def finish(self) -> None:
        self._mcap.finish()
        self._fh.close()
        if self._live is not None:
            self._live.close()

    def abandon(self) -> None:
        """Close without the summary (it cannot be written): every complete chunk stays readable."""
        if self._live is not None:
            self._live.close()
        self._fh.close()


def _frames(fd: int, poll_s: float):
    """Yield each frame read from ``fd`` (None every ``poll_s`` without one); stop at end of file."""
    buf = bytearray()
    while True:
        ready, _, _ = select.select([fd], [], [], poll_s)
        if not ready:
            yield None
            continue
        chunk = os.read(fd, 1 << 16)
        if not chunk:
            return
        buf += chunk
        while len(buf) >= _FRAME.size and len(buf) >= _FRAME.size + _FRAME.unpack_from(buf)[0]:
            n = _FRAME.unpack_from(buf)[0]
            yield pickle.loads(bytes(buf[_FRAME.size:_FRAME.size + n]))
            del buf[:_FRAME.size + n]


def _writer_main() -> None:
    """The writer process: open the file from the first frame, write every batch, flush each second, finish
    on "stop" or at end of input (the flight process died), and print ``{"error": ...}`` for the flight process."""
    writer = None
    error = None
    try:
        last_flush = time.monotonic()
        for batch in _frames(sys.stdin.fileno(), POLL_S):
            stop = False
            for item in batch or ():
                if item[0] == "open":
                    writer = _Writer(item[1], item[2]["metadata"], item[2]["live_port"])
                elif item[0] == "stop":
                    stop = True
                else:
                    writer.write(item)
            if stop:
                break
            if writer is not None and time.monotonic() - last_flush >= FLUSH_S:
                writer.flush()
                last_flush = time.monotonic()
    except Exception as exc:  # reported to the flight process (it watches for it in flight)
        error = f"{type(exc).__name__}: {exc}"
    finally:
        if writer is not None:
            try:
                writer.finish()
            except Exception as exc:  # noqa: BLE001 - a full disk fails the footer too: what is written stays
                error = error or f"{type(exc).__name__}: {exc}"
                with contextlib.suppress(OSError):
                    writer.abandon()
    with contextlib.suppress(OSError):  # nobody left to tell
        print(json.dumps({"error": error}), flush=True)


def recover(src: str | Path, dst: str | Path) -> dict:
    """Copy every complete record of a possibly truncated MCAP (e.g. after SIGKILL) into a finalized file.

    Returns counts: messages recovered, channels, and whether the source ended cleanly.
    """
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[Message] = []
    metadata: list[Metadata] = []
    attachments: list[Attachment] = []
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
                elif isinstance(rec, Metadata):
                    metadata.append(rec)
                elif isinstance(rec, Attachment):
                    attachments.append(rec)
        except Exception:  # truncated tail: everything before it is kept
            clean = False
    with open(dst, "wb") as out:
        w = Writer(out, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        w.start(profile="", library=f"{LIBRARY} recover")
        for m in metadata:
            w.add_metadata(m.name, dict(m.metadata))
        for a in attachments:
            w.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
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


if __name__ == "__main__":
    _writer_main()
