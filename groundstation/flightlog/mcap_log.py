"""One MCAP file per flight, written by a process of its own, finalized on every exit path.

Protobuf channels use Foxglove's schemas so Foxglove shows the flight in 3D without set-up: mocap poses as
received (``/mocap/<body>``, the Zenoh payload bytes unchanged; publish time = the mocap's stamp), the state
estimate (``/state/pose``), transforms world -> body -> module_<i> (``/tf``), the assembly, the reference path
and the geofence as a scene (``/scene``, :mod:`groundstation.flightlog.scene`), events and errors (``/log``).
Numeric records go on JSON channels, each with its JSON Schema (:mod:`groundstation.flightlog.schemas`), which
Foxglove plots directly: ``/control`` (one per period: phase, the state the controller used, setpoint, position
error, attitude target, roll and yaw targets, desired wrench, rotor commands per module, mocap age, loop timing),
``/backend/telemetry`` (with link quality), ``/mocap/stats``, ``/loop/timing`` (summary), ``/flight/summary``; each
record is encoded by :func:`encode_json`, the one place JSON is written.
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
(``foxglove-sdk``), so Foxglove shows the flight as it happens, at no cost to the flight process. What is written
once per flight (the scene, the body -> module transforms: ``static`` messages) is sent again to every client that
subscribes to its channel, and to all every :data:`RESEND_S`: it is written before the server starts, and a client
that connects mid-flight would otherwise never get it. The SDK's own warnings (a client refused at its handshake,
a subscription to an unknown channel) go to ``/log``: printed, they would land in the pilot's status line.

Robustness: chunks are small (32 KiB) and the file is flushed about once a second. :meth:`FlightLog.close`
finishes the file (summary, footer) and is called on normal exit, Ctrl-C and SIGTERM. If the flight process is
killed (SIGKILL), the writer sees its pipe close and finishes the file itself, losing only what had not been fed
to it yet (under one control period). If both are killed, every complete chunk is on disk and :func:`recover`
reads the file with :class:`~groundstation.flightlog.salvage.LogScan` and writes a finalized copy. Every chunk
carries a CRC of its records and the data section one of its own (``enable_data_crcs``), so damage on the disk
(a flipped bit) is found when the file is read, not analysed or copied as if it were data.
"""

from __future__ import annotations

import array
import contextlib
import fcntl
import json
import logging
import math
import os
import pickle
import select
import struct
import subprocess
import sys
import termios
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
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from groundstation.assembly.assembly import Assembly
from groundstation.errors import UsageError
from groundstation.flightlog.salvage import MAGIC, LogScan
from groundstation.flightlog.scene import module_transforms, scene
from groundstation.flightlog.schemas import schema_of
from groundstation.loop_activity import LoopActivity
from groundstation.rotations import matrix_to_quat

CHUNK_BYTES = 32 * 1024
HEAD_WITNESS_BYTES = 4096
"""How much of the log's start each flush reads back and the next one checks (its header and metadata)."""
WITNESS_BYTES = 64
"""How much of the log's newest bytes each flush reads back and the next one checks."""
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


_OMIT = object()
"""What :func:`_finite` makes of a value that must not be written."""


def _finite(value):
    """``value`` without what is not finite: a member whose value is NaN or infinite, or an array holding one, is
    left out (an array's element cannot be: the indices after it would move); objects inside arrays are kept, less
    such members. JSON has no NaN: Python writes a bare ``NaN`` that Foxglove and every strict parser refuse."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            v = _finite(v)
            if v is not _OMIT:
                out[k] = v
        return out
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, list | tuple):
        items = [_finite(v) for v in value]
        return _OMIT if any(v is _OMIT for v in items) else items
    if isinstance(value, float | np.floating) and not math.isfinite(value):
        return _OMIT
    return value


def encode_json(data: dict) -> bytes:
    """A JSON channel's record as written: rotation matrices as a quaternion and roll/pitch/yaw
    (:func:`_with_attitudes`), numpy values as numbers, and only finite numbers (:func:`_finite`; the schemas
    require no member that can be left out). Raises for a value that does not convert."""
    record = _with_attitudes(data)
    try:
        return json.dumps(record, default=_jsonable, allow_nan=False).encode()
    except ValueError:  # a value not finite (rare: the first /mocap/stats rate, an unmeasured link), walked only then
        return json.dumps(_finite(record), default=_jsonable, allow_nan=False).encode()


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


MAX_NS = 2**64 - 1
"""MCAP times are unsigned 64-bit nanoseconds since the epoch (up to the year 2554)."""


def stamp_ns(t) -> int | None:
    """``t`` (s since the epoch) as an MCAP time (ns), or None if it is not one: NaN, infinite, negative, or beyond
    2^64 ns (a stamp in milliseconds, 1.7e12, is one)."""
    try:
        t = float(t)
    except (TypeError, ValueError):
        return None
    if not 0.0 <= t < 2**64 / 1e9:  # NaN compares false
        return None
    ns = int(t * 1e9)
    return ns if ns <= MAX_NS else None


def _stamp(t: float) -> Timestamp:
    """``t`` as a protobuf Timestamp; the epoch for a value that is not a time (the writer rejects the message's log
    time then: building the message must not raise in the flight process)."""
    if stamp_ns(t) is None:
        return Timestamp()
    return Timestamp(seconds=int(t), nanos=int((t % 1) * 1e9))


def being_written(path: str | Path) -> bool:
    """A log writer process holds ``path`` open now (its flight is under way, or its writer hung): the writer holds
    an ``flock`` on the file for its life, which the kernel drops however the process ends."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:  # a filesystem without flock: nothing to tell
        return False
    finally:
        os.close(fd)
    return False


def claim(path: str | Path) -> tuple[int, int]:
    """Create ``path`` empty, exclusively (``O_EXCL``): of two processes claiming one path only one succeeds, the
    other gets :class:`FileExistsError`; an existing file is never touched. The writer then opens the claimed file
    (it writes only into an empty one). Returns the file's identity (device, inode): the path may lead elsewhere
    later (the file removed and another put in its place)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
    try:
        st = os.fstat(fd)
    finally:
        os.close(fd)
    return st.st_dev, st.st_ino


WRITER_STALL_S = 2.0
"""The log watchdog's bound: a writer process that takes none of its input for this long while input waits for it
has hung (its write blocked on a frozen or dead disk, a pipe nobody reads, the process stopped), and
:attr:`FlightLog.error` says so; the flight, reading it every period, acts on it (``failsafe.on_log_failure``). Seen
within this plus :data:`WATCH_S` and one control period. A working writer takes what is sent within milliseconds
(it encodes and hands its writes to the page cache), s."""
WRITER_START_S = 10.0
"""The same bound while the writer process starts, before it has taken any input (a Python interpreter importing
the writer: 0.6 s of CPU, 2.8 s measured on a loaded 2-core machine), s."""
WATCH_S = 0.1
"""The feeder samples the writer's progress this often, s."""
SEND_SLICE = 16 * 1024
"""A frame goes down the pipe in writes of at most this many bytes, so the watchdog sees the writer take input
even while the feeder waits on a full pipe (a pipe holds 64 KiB)."""


def _unread(fd: int) -> int:
    """Bytes written into the pipe of ``fd`` that its reader has not taken yet (Linux ``FIONREAD``, either end)."""
    buf = array.array("i", [0])
    fcntl.ioctl(fd, termios.FIONREAD, buf, True)
    return buf[0]


class FlightLog:
    """Thread-safe, non-blocking logger: calls enqueue; a feeder thread hands batches to the writer process.

    Watchdog: the writer's progress is the bytes it has taken from its pipe (what the feeder wrote, less what the
    pipe still holds). A writer with input waiting that takes none for :data:`WRITER_STALL_S` has hung, and
    :attr:`error` says so (the check is a clock read per call; the pipe is sampled every :data:`WATCH_S` by the
    feeder, between control periods, and by :attr:`error` only once the bound has passed). A hung writer is neither
    waited for nor killed: if it resumes (a filesystem thawed) it finishes the file with what it was given."""

    def __init__(self, path: str | Path, metadata: dict[str, str] | None = None,
                 activity: LoopActivity | None = None, live_port: int | None = None) -> None:
        self.path = Path(path)
        # A session of its own: the operator's Ctrl-C (a signal to the terminal's process group) lands the flight
        # and must not kill the log; the writer ends when its input does, at close or when this process dies.
        self._process = subprocess.Popen([sys.executable, "-m", "groundstation.flightlog.mcap_log"],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True)
        self._stdin = self._process.stdin.fileno()
        """Frames are written to this descriptor directly (never through the buffered ``stdin`` object)."""
        self._written = 0
        """Bytes the feeder has written into the writer's pipe."""
        self._sending = False
        """The feeder is inside a write (it blocks while the pipe is full)."""
        self._progress = (time.monotonic(), 0)
        """(when the writer was last seen taking input, or with none waiting for it; the bytes it had taken)."""
        self._started = False
        """The writer has taken input: its start is over (:data:`WRITER_START_S` no longer applies)."""
        self._watched = 0.0
        self._watch_lock = threading.Lock()
        self._error: str | None = None
        self._finished = False
        """The feeder is done and the pipe closed: nothing left to watch."""
        self.hung = False
        """The watchdog found the writer hung (:attr:`error` says for how long)."""
        self.rejected: dict[str, int] = {}
        """Messages the writer did not write, by topic and why (``"/mocap/assembly publish time": 3``: a stamp that
        is not a time, a record that does not encode); known after :meth:`close`."""
        self._send([("open", str(self.path), {"metadata": dict(metadata or {}), "live_port": live_port}, 0.0)])
        # Producers append without waking anyone; the feeder runs between control periods (see LoopActivity).
        self._items: deque = deque()
        self._schemas: set[str] = set()
        """Protobuf schemas already sent to the writer (message classes do not pickle; descriptors do)."""
        self._activity = activity or LoopActivity()
        self._closed = False
        self.dropped = 0
        self.writer_pid = self._process.pid
        """The writer process (it outlives this one if this one is killed)."""
        self._thread = threading.Thread(target=self._feed, name="mcap-feeder", daemon=True)
        self._thread.start()

    @property
    def error(self) -> str | None:
        """Why the writer failed or hung (None while it works). Cheap: read it every control period."""
        if self._error is None and not self._finished and time.monotonic() - self._progress[0] > self._bound():
            self._check()
        return self._error

    # -- producer side (any thread) ------------------------------------------------------------------------------
    def protobuf(self, topic: str, message, t: float, static: bool = False) -> None:
        self.raw_protobuf(topic, type(message), message.SerializeToString(), t, static=static)

    def raw_protobuf(self, topic: str, message_type, payload: bytes, t: float,
                     publish_time: float | None = None, static: bool = False) -> None:
        """Log already-serialized protobuf bytes (e.g. a Zenoh payload) under ``message_type``'s schema, at log time
        ``t``; ``publish_time`` (default ``t``) is when the source produced it (s since the epoch). ``static``: the
        message holds for the whole flight (written once, sent again to live clients, see :class:`_Live`)."""
        name = message_type.DESCRIPTOR.full_name
        if name not in self._schemas:  # once per type, before its first message
            # Queued before the name is marked sent, so another thread's message of this type cannot overtake it
            # (two threads may both send it; the writer registers it once).
            self._put(("schema", name, build_file_descriptor_set(message_type).SerializeToString(), t))
            self._schemas.add(name)
        self._put(("static" if static else "pb", topic, (name, payload, t if publish_time is None else publish_time),
                   t))

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
            self.protobuf("/tf", tf, t, static=True)
        self.protobuf("/scene", scene(assembly, t, reference, geofence), t, static=True)

    def _put(self, item) -> None:
        if self._closed or self._error is not None:
            self.dropped += 1  # counted, not kept: a dead writer must not grow the queue for the rest of a flight
            return
        self._items.append(item)

    # -- the watchdog ------------------------------------------------------------------------------------------------
    def _bound(self) -> float:
        return WRITER_STALL_S if self._started else WRITER_START_S

    def _watch(self) -> float:
        """Sample the writer's progress; how long it has had input waiting without taking any, s (0: keeping up)."""
        now = time.monotonic()
        with self._watch_lock:
            try:
                unread = _unread(self._stdin)  # before the bytes written: a write between the two reads as progress
            except OSError:  # our end is closed: nothing waits
                return 0.0
            taken = self._written - unread
            at, before = self._progress
            if taken > before or (unread == 0 and not self._sending):
                self._progress = (now, max(taken, before))
                self._started = self._started or taken > 0
                return 0.0
            return now - at

    def _check(self) -> None:
        """Sample the writer's progress; beyond the bound, the writer has hung: say so in :attr:`error`."""
        if self._finished:
            return
        stalled, bound = self._watch(), self._bound()
        if stalled > bound and self._error is None:
            self.hung = True
            self._error = (f"the log writer has taken none of its input for {stalled:.1f} s > {bound:g} s: hung (its "
                           f"disk frozen or stalled, or the process stopped); it finishes the file if it resumes")

    # -- feeder thread ----------------------------------------------------------------------------------------------
    def _feed(self) -> None:
        try:
            while True:
                self._activity.wait_end(POLL_S)
                if self._process.poll() is not None:  # the writer died (a full disk, a crash, killed)
                    self._writer_gone()
                    return
                if time.monotonic() - self._watched >= WATCH_S:
                    self._watched = time.monotonic()
                    self._check()
                while self._items and (self._activity.may_work(FEED_BUDGET_S) or self._closed):
                    batch = [self._items.popleft() for _ in range(min(FEED_BATCH, len(self._items)))]
                    self._send(batch)
                    if batch[-1][0] == "stop":
                        return
        except OSError:  # the writer process is gone
            self._writer_gone()
        except Exception as exc:  # noqa: BLE001 - e.g. a record that does not pickle: nothing more reaches the file
            self._error = self._error or f"the log feeder stopped: {type(exc).__name__}: {exc}"

    def _writer_gone(self) -> None:
        """Record why the writer stopped (its last words, or its exit) and stop queueing: :attr:`error` is what
        the flight watches."""
        why = ""
        with contextlib.suppress(OSError, ValueError):
            self._process.wait(1.0)
            why = self._result(self._process.stdout.read())
        code = self._process.poll()
        self._error = self._error or (why or f"the writer process stopped (exit code {code})")
        self.dropped += len(self._items)
        self._items.clear()

    def _result(self, out: bytes) -> str:
        """The writer's last words (``{"error": ..., "rejected": {...}}``): its error ("" if none); keeps the
        rejections."""
        try:
            result = json.loads(out or b"{}")
        except ValueError:
            return ""
        self.rejected = result.get("rejected") or self.rejected
        return result.get("error") or ""

    def _send(self, batch: list) -> None:
        frame = pickle.dumps(batch, protocol=pickle.HIGHEST_PROTOCOL)
        data = memoryview(_FRAME.pack(len(frame)) + frame)
        self._sending = True
        try:
            for i in range(0, len(data), SEND_SLICE):
                piece = data[i:i + SEND_SLICE]
                while piece:
                    n = os.write(self._stdin, piece)
                    self._written += n
                    piece = piece[n:]
        finally:
            self._sending = False

    def close(self, timeout: float = CLOSE_TIMEOUT_S) -> None:
        """Write what is queued, finish the file (summary and footer) and close it. Idempotent. Waits for a writer
        that takes its input, however long the rest takes; a hung one (the watchdog's bound) is left to finish the
        file if it resumes."""
        if self._closed:
            return
        self._closed = True
        self._items.append(("stop", None, None, 0.0))
        self._activity.end()  # wake the feeder now (harmless to a loop: it has finished when we close)
        while self._thread.is_alive() and not self.hung:
            self._thread.join(WATCH_S)
            self._check()
        if self._thread.is_alive():  # blocked on a writer that takes nothing: do not wait for it, do not kill it
            return
        self._finished = True
        try:  # closes the writer's stdin: it finishes the file even if "stop" did not get through
            out, _ = self._process.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:  # it took everything but cannot finish (its disk hangs): not killed either
            self._error = self._error or (f"the log writer did not finish the file within {timeout:g} s (its disk "
                                          f"hangs?); it finishes it if it resumes")
            return
        except (OSError, ValueError):  # the writer died earlier and its pipes are gone (error already known)
            out = b""
        self._error = self._result(out) or self._error
        if self._process.returncode != 0 and self._error is None:
            self._error = f"the writer process exited with code {self._process.returncode}"

    def __enter__(self) -> FlightLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


LIBRARY = "groundstation"
"""The MCAP header's library field: how replay recognizes a flight log of this program."""


RESEND_S = 1.0
"""The live view sends the static messages (scene, module transforms) to every client this often, besides once to
each client that subscribes to their channel (one that missed that, or whose panel was cleared, gets them within
this), s."""
LIVE_STOP_S = 2.0
"""Longest wait for the live server to stop at the end of a log, s."""
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.sdk.v1.1")
"""The WebSocket subprotocols the live view speaks: foxglove-sdk 0.30.3's, fixed by it (its ``websocket/handshake.rs``
picks the newest of exactly these two names among those a client offers and answers a client that offers neither
with HTTP 400; ``start_server`` has no option for it). A client offering only the older ``foxglove.websocket.v1``
(``@foxglove/ws-protocol``'s default, Lichtblick before 1.22) is refused: README, "In Foxglove"."""


SDK_LOG_PER_S = 10
"""At most this many of the SDK's records a second go to ``/log``; the rest are counted, and the count follows."""


class _SdkLog(logging.Handler):
    """Records of the SDK's loggers (``foxglove.*``; written by its server's threads), kept for the writer to put on
    ``/log``. Without a handler of their own they reach Python's last-resort handler, which prints them on the
    terminal the flight shares with the writer process: over the pilot's status line. A client that retries a
    refused handshake in a loop makes one record per attempt: kept to :data:`SDK_LOG_PER_S` a second, then one
    record saying how many were left out, so neither the log nor the writer's memory grows with the attempts."""

    def __init__(self) -> None:
        super().__init__()
        self.records: deque[logging.LogRecord] = deque()
        self._second = (-math.inf, 0, 0)
        """(start of this second, monotonic s; records kept in it; records left out in it)."""

    def emit(self, record: logging.LogRecord) -> None:
        now = time.monotonic()
        start, kept, left_out = self._second
        if now - start >= 1.0:
            if left_out:
                self.records.append(logging.makeLogRecord({
                    "name": record.name, "levelname": "WARNING", "levelno": logging.WARNING,
                    "msg": f"{left_out} more messages of the live server in a second, not logged"}))
            start, kept, left_out = now, 0, 0
        if kept < SDK_LOG_PER_S:
            self.records.append(record)
            kept += 1
        else:
            left_out += 1
        self._second = (start, kept, left_out)


class _Live:
    """Every written record also served over the Foxglove WebSocket protocol (``foxglove-sdk``, subprotocols
    :data:`SUBPROTOCOLS`).

    The server starts with the first ``/control`` record, once the flight has created the channels a client
    subscribes to at once (mocap, transforms, scene, state, control): channels that exist when a client connects
    are advertised with the connection, while foxglove-sdk 0.30.3 can refuse a subscription sent the instant a
    channel is advertised to an already connected client (3 runs in 8 under a CPU hog: "Unknown channel ID"). The
    Foxglove app retries its connection until the server is up.

    Static messages (``static`` in :meth:`publish`) are written before the server starts, so a client would never
    get them: :meth:`serve` sends them again on each channel a client subscribed to (the SDK reports the
    subscription on its own thread, after registering it: the message reaches the new subscriber), and on all
    every :data:`RESEND_S`. Sent to a channel, they reach each of its subscribers; those that have them already
    replace them with the same (a scene entity by its id, a transform by its frames)."""

    START_TOPIC = "/control"

    def __init__(self, port: int) -> None:
        # Before the server starts: the SDK forwards its records through pyo3-log, which caches each Python
        # logger's level at its first record. Warnings and errors, as the last-resort handler printed them.
        self.log = _SdkLog()
        sdk_logger = logging.getLogger("foxglove")
        sdk_logger.addHandler(self.log)
        sdk_logger.setLevel(logging.WARNING)
        sdk_logger.propagate = False  # nor through a handler the root logger may have
        import foxglove

        self._foxglove = foxglove
        self.port = port
        self._server = None
        self._channels: dict[str, object] = {}
        self._static: dict[str, list[bytes]] = {}
        """topic -> the payloads of its static messages, in the order written."""
        self._subscribed: deque[str] = deque()
        """Topics a client subscribed to since the last :meth:`serve` (appended by the SDK's thread)."""
        self._resent = time.monotonic()

    def on_subscribe(self, client, channel) -> None:
        """The SDK's ``ServerListener`` callback (its thread): only noted, :meth:`serve` sends (the writer's thread
        does all the logging)."""
        self._subscribed.append(channel.topic)

    def on_unsubscribe(self, client, channel) -> None:
        """Nothing to do; defined because the SDK calls it at every unsubscription and disconnection and logs an
        error ("Callback failed") for a listener without it."""

    def publish(self, topic: str, encoding: str, schema_name: str, schema_encoding: str, schema: bytes,
                payload: bytes, ns: int, static: bool = False) -> None:
        """Raises what starting the server raises (a port in use) at the first ``/control`` record."""
        ch = self._channels.get(topic)
        if ch is None:
            fg = self._foxglove
            ch = self._channels[topic] = fg.Channel(topic, message_encoding=encoding,
                                                    schema=fg.Schema(name=schema_name, encoding=schema_encoding,
                                                                     data=schema))
        ch.log(payload, log_time=ns)
        if static:
            self._static.setdefault(topic, []).append(payload)
        if self._server is None and topic == self.START_TOPIC:
            self._server = self._foxglove.start_server(name="groundstation", host="127.0.0.1", port=self.port,
                                                       server_listener=self)

    def serve(self, ns: int) -> None:
        """Send the static messages of each channel subscribed to since the last call, or of all every
        :data:`RESEND_S`, at log time ``ns`` (the clients' clock is the log times they receive)."""
        topics = set()
        while self._subscribed:
            topics.add(self._subscribed.popleft())
        if self._server is not None and time.monotonic() - self._resent >= RESEND_S:
            self._resent = time.monotonic()
            topics = set(self._static)
        for topic in topics:
            for payload in self._static.get(topic, ()):
                self._channels[topic].log(payload, log_time=ns)

    def close(self) -> None:
        """Stop the server, waiting at most :data:`LIVE_STOP_S`: a client that subscribed and stopped reading held
        ``stop()`` 40-75 s (foxglove-sdk 0.30.3), and the log is finished before this is called; the writer
        process exits after its result whatever the server's threads do (:func:`_writer_main`)."""
        if self._server is not None:
            stopping = threading.Thread(target=self._server.stop, name="live-stop", daemon=True)
            stopping.start()
            stopping.join(LIVE_STOP_S)


class _Writer:
    """The MCAP file, in the writer process."""

    def __init__(self, path: str, metadata: dict[str, str], live_port: int | None = None) -> None:
        # The file was claimed (:func:`claim`) or is new: an existing log is never overwritten.
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        if os.fstat(fd).st_size:
            os.close(fd)
            raise FileExistsError(f"{path} is not empty: a flight log is never overwritten")
        with contextlib.suppress(OSError):  # held for the writer's life: :func:`being_written`
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        self._fh = os.fdopen(fd, "wb")
        self._witnesses: list[tuple[int, bytes]] = []
        """(offset, bytes) the last flush read back from the file, for the next to compare (:meth:`flush`)."""
        self._mcap = _mcap_writer(self._fh)
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
        self.rejected: dict[str, int] = {}
        """Messages not written, by topic and what was wrong (:meth:`_reject`)."""
        self._last_ns = 0

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

    def _add(self, topic: str, schema: str | None, payload: bytes, ns: int, publish_ns: int | None = None,
             static: bool = False) -> None:
        """One message; ``ns`` and ``publish_ns`` are valid MCAP times (:func:`stamp_ns`); ``static``: see
        :class:`_Live`."""
        cid, encoding, schema_name, schema_encoding, schema_data = self._channel(topic, schema)
        self._mcap.add_message(cid, log_time=ns, data=payload, publish_time=ns if publish_ns is None else publish_ns)
        self._last_ns = ns
        if self._live is not None:
            try:
                self._live.publish(topic, encoding, schema_name, schema_encoding, schema_data, payload, ns, static)
            except Exception as exc:  # noqa: BLE001 - a port in use must not cost the log
                port, self._live = self._live.port, None
                self._note(Log.WARNING, f"live view on port {port} unavailable: {exc}", ns)

    def _note(self, level: int, text: str, ns: int | None = None, name: str = "groundstation.log") -> None:
        """An event of the writer's own (or of ``name``, a library it uses) on ``/log`` (at ``ns``, default the last
        message's log time)."""
        ns = ns if ns is not None else self._last_ns or stamp_ns(time.time())
        msg = Log(timestamp=_stamp(ns * 1e-9), level=level, name=name, message=text)
        self._add("/log", Log.DESCRIPTOR.full_name, msg.SerializeToString(), ns)

    def _reject(self, topic: str, what: str, detail: str) -> None:
        """Count a message that is not written (``what``: which part of it is wrong), naming the first of each kind
        in the log: a bad stamp or record costs that message, never the writer."""
        key = f"{topic} {what}"
        self.rejected[key] = self.rejected.get(key, 0) + 1
        if self.rejected[key] == 1:
            self._note(Log.WARNING, f"a message on {topic} is not written: {detail}; every such message is counted "
                                    f"(the total is logged at the end)")

    def write(self, item) -> None:
        kind, topic, data, t = item
        if kind == "schema":
            self._schema(topic, data)
            return
        ns = stamp_ns(t)
        if ns is None:
            self._reject(topic, "log time", f"its log time {t!r} is not a time (finite, non-negative, before 2554)")
            return
        if kind in ("pb", "static"):
            publish_ns = stamp_ns(data[2])
            if publish_ns is None:
                self._reject(topic, "publish time",
                             f"its publish time {data[2]!r} is not a time (finite, non-negative, before 2554)")
                return
            self._add(topic, data[0], data[1], ns, publish_ns, static=kind == "static")
            return
        try:  # encoding: what fails here is the record's (a value that does not convert), not the disk's
            if kind == "pose":
                position, rotation = data
                msg = PoseInFrame(timestamp=_stamp(t), frame_id="world")
                msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
                o = msg.pose.orientation
                o.x, o.y, o.z, o.w = matrix_to_quat(rotation)
                tf = FrameTransform(timestamp=_stamp(t), parent_frame_id="world", child_frame_id="body")
                tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in position)
                tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = o.x, o.y, o.z, o.w
                messages = [(topic, PoseInFrame.DESCRIPTOR.full_name, msg.SerializeToString()),
                            ("/tf", FrameTransform.DESCRIPTOR.full_name, tf.SerializeToString())]
            else:
                messages = [(topic, None, encode_json(data))]
        except Exception as exc:  # noqa: BLE001 - no I/O above: whatever fails is the record's
            self._reject(topic, "encoding", f"it does not encode ({type(exc).__name__}: {exc})")
            return
        for topic_, schema, payload in messages:
            self._add(topic_, schema, payload, ns)

    def flush(self) -> None:
        """Flush, then check that the file is still ours: truncated in flight (``truncate``, ``> file``, a cleanup
        script), it went on growing past a hole where its start had been, a flight reported complete whose log no
        reader opens. Raises then, so the flight hears of it (``on_log_failure``) and its summary says so."""
        self._fh.flush()
        fd = self._fh.fileno()
        if os.pread(fd, len(MAGIC), 0) != MAGIC:
            raise OSError(f"the log file was truncated or overwritten by another process (its first "
                          f"{len(MAGIC)} bytes are no longer MCAP's): what was written before is lost")
        # Cut anywhere past its start, it grows on from where the writer was: the stretch cut away reads back as a
        # hole (no data), which a log written straight through never has. (A file system without holes, which
        # reports none, is not checked this way.)
        end = os.lseek(fd, 0, os.SEEK_CUR)
        try:
            hole = os.lseek(fd, 0, os.SEEK_HOLE)
        finally:
            os.lseek(fd, end, os.SEEK_SET)
        if hole < end:
            raise OSError(f"the log file was truncated by another process (its bytes from {hole} on were cut, the "
                          f"writer went on at {end}): what was written there is lost")
        # Written over in place (another log copied over it, zeros appended after a cut, bytes zeroed): what the
        # writer read back at its last flush (the file's start, the newest bytes) must still be there.
        for offset, data in self._witnesses:
            if os.pread(fd, len(data), offset) != data:
                raise OSError(f"the log file was overwritten by another process (bytes {offset}-{offset + len(data)} "
                              f"are no longer what the writer wrote): what was written there is lost")
        tail = max(end - WITNESS_BYTES, 0)
        self._witnesses = [(0, os.pread(fd, min(end, HEAD_WITNESS_BYTES), 0)), (tail, os.pread(fd, end - tail, tail))]

    def serve(self) -> None:
        """The live view's share of the writer's thread (called after every batch, and every :data:`POLL_S` without
        one): the static messages its clients need (:meth:`_Live.serve`) and the SDK's warnings, onto ``/log``."""
        if self._live is None:
            return
        try:
            self._live.serve(self._last_ns)
        except Exception as exc:  # noqa: BLE001 - as in _add: whatever the live view does must not cost the log
            port, self._live = self._live.port, None
            self._note(Log.WARNING, f"live view on port {port} stopped: {type(exc).__name__}: {exc}")
            return
        records = self._live.log.records
        while records:
            r = records.popleft()
            self._note(LEVELS.get(r.levelname.lower(), Log.FATAL), r.getMessage(), name=r.name)

    def note_unfinished(self) -> None:
        """The input ended without "stop": the flight process was killed or crashed (or could not hand over the
        rest), so the flight's end may be missing; say so in the log itself."""
        self._note(Log.ERROR, "the log ends without the flight's end: the flight process stopped handing over "
                              "records (killed, crashed, or blocked) before it finished the log")

    def finish(self) -> None:
        if self.rejected:
            self._note(Log.WARNING, "messages not written: " + "; ".join(f"{k}: {n}" for k, n in self.rejected.items()))
        self._mcap.finish()
        self._fh.close()
        if self._live is not None:
            self._live.close()

    def abandon(self) -> None:
        """Close without the summary (it cannot be written): every complete chunk stays readable. The file first:
        whatever the live server does, what was written is on disk."""
        self._fh.close()
        if self._live is not None:
            self._live.close()


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
    on "stop" or at end of input (the flight process died: noted in the log), and print ``{"error": ...,
    "rejected": {...}}`` for the flight process."""
    writer = None
    error = None
    stopped = False
    try:
        last_flush = time.monotonic()
        for batch in _frames(sys.stdin.fileno(), POLL_S):
            for item in batch or ():
                if item[0] == "open":
                    writer = _Writer(item[1], item[2]["metadata"], item[2]["live_port"])
                elif item[0] == "stop":
                    stopped = True
                else:
                    writer.write(item)
            if stopped:
                break
            if writer is None:
                continue
            writer.serve()
            if time.monotonic() - last_flush >= FLUSH_S:
                writer.flush()
                last_flush = time.monotonic()
    except Exception as exc:  # reported to the flight process (it watches for it in flight)
        error = f"{type(exc).__name__}: {exc}"
    finally:
        if writer is not None:
            try:
                if not stopped and error is None:
                    writer.note_unfinished()
                writer.finish()
            except Exception as exc:  # noqa: BLE001 - a full disk fails the footer too: what is written stays
                error = error or f"{type(exc).__name__}: {exc}"
                with contextlib.suppress(OSError):
                    writer.abandon()
    with contextlib.suppress(OSError):  # nobody left to tell
        print(json.dumps({"error": error, "rejected": writer.rejected if writer is not None else {}}), flush=True)


def _mcap_writer(fh) -> Writer:
    """An MCAP writer of flight logs: small zstd chunks, each with its CRC, and a CRC of the whole data section."""
    return Writer(fh, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD, enable_data_crcs=True)


SOURCE_LIVE = ("its flight is still writing it: the copy holds what was on disk when it was read, not the flight's "
               "end")
"""`recover`'s word on a source a log writer still holds."""
RECOVERED = "recovered"
"""Metadata record :func:`recover` adds to its copy: a JSON object with the source's path, whether it was complete
and the warnings naming what was dropped (the reader repeats them)."""


def recover(src: str | Path, dst: str | Path) -> dict:
    """Copy every intact record of a possibly truncated or damaged MCAP (e.g. after SIGKILL, or a flipped bit on
    the disk) into a finalized file at ``dst``, streamed (memory does not grow with the log).

    ``dst`` must not exist.
    Returns counts: messages and channels written, intact chunks read, whether the source was complete (finalized,
    nothing damaged), what was dropped (chunks and messages, in all and by reason; messages None where unknown)
    and the warnings naming each damaged stretch.
    """
    if Path(dst).exists() and os.path.samefile(src, dst):
        raise UsageError(f"{dst}: is the log to recover; write the recovered copy to another file")
    scan = LogScan(src)
    live = being_written(src)  # a flight still writing it: the copy is what was on disk now, not where it ended
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    kept = 0
    try:
        out = open(dst, "xb")  # noqa: SIM115 (closed below)  created exclusively: a log is never overwritten
    except FileExistsError:
        raise UsageError(f"{dst}: the file exists; a log is never overwritten (choose another file)") from None
    try:
        with out:
            w = _mcap_writer(out)
            w.start(profile="", library=f"{LIBRARY} recover")
            for rec in scan.records():  # an intact summary's schemas and channels come first, then the file's order
                if isinstance(rec, Schema) and rec.id not in schemas:
                    schemas[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
                elif isinstance(rec, Channel) and rec.id not in channels:
                    channels[rec.id] = w.register_channel(rec.topic, rec.message_encoding,
                                                          schemas.get(rec.schema_id, 0), dict(rec.metadata))
                elif isinstance(rec, Message):
                    w.add_message(channels[rec.channel_id], rec.log_time, rec.data, rec.publish_time, rec.sequence)
                    kept += 1
                elif isinstance(rec, Metadata):
                    w.add_metadata(rec.name, dict(rec.metadata))
                elif isinstance(rec, Attachment):
                    w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
            # What the copy is and what it lost, in the copy itself: without it a recovered log whose config record
            # was dropped read back as a complete flight with no word of the damage (only recover's output said so).
            w.add_metadata(RECOVERED, {"value": json.dumps({"source": str(src), "source_was_complete": scan.complete,
                                                            "source_being_written": live,
                                                            "warnings": scan.warnings()})})
            w.finish()
    except BaseException:
        # The copy is ours (created above): a full disk or an interruption must not leave a partial file that a
        # retry would then refuse to overwrite.
        with contextlib.suppress(OSError):
            os.unlink(dst)
        raise
    warnings = scan.warnings() + ([SOURCE_LIVE] if live else [])
    return {"messages": kept, "channels": len(channels), "chunks": scan.chunks, "source_was_complete": scan.complete,
            "source_being_written": live, "dropped": scan.dropped(), "warnings": warnings}


if __name__ == "__main__":
    _writer_main()
    # Its result printed, the process ends here: a live server's threads that will not stop (a client that stopped
    # reading) must not keep it, and the port, for the next flight.
    os._exit(0)
