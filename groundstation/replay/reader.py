"""Reading a flight log back, streamed: one record at a time, whatever the file's length.

The reader goes through the file front to back (:class:`~groundstation.flightlog.salvage.LogScan`: it needs no
summary section, so a log recovered after a crash, or cut short by a crash, reads too, up to its last complete
chunk; a damaged chunk or record is skipped and reading goes on with the next intact one, a ``config`` or
``assembly`` metadata record that is not the JSON object the flight wrote too) and decodes JSON
channels to dicts (a record of an older log in today's shape, :func:`upgraded`) and ``/log`` to (level, text).
Memory does not grow with the file: nothing is kept but the channel table.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.Log_pb2 import Log
from mcap.records import Channel, Header, Message, Metadata

from groundstation.errors import ConfigError
from groundstation.flightlog.mcap_log import LIBRARY, RECOVERED
from groundstation.flightlog.salvage import MAGIC, LogScan, log_file, read_header

LEVEL_NAMES = {Log.DEBUG: "debug", Log.INFO: "info", Log.WARNING: "warning", Log.ERROR: "error",
               Log.FATAL: "fatal"}


@dataclass(frozen=True, eq=False)
class LogRecord:
    topic: str
    log_time: float
    """When it was logged, s since the epoch (the flight's one clock)."""
    publish_time: float
    """When its source made it, s since the epoch (a mocap pose: its stamp, the publisher's clock)."""
    data: object
    """JSON channels: the decoded dict; ``/log``: (level, text); other protobuf channels: the raw bytes."""


@dataclass
class LogFile:
    """A flight log being read: its metadata (filled as the stream reaches it) and how it ended."""

    path: Path
    metadata: dict[str, str]
    complete: bool = False
    """Finalized with nothing damaged (known once :meth:`records` has been read through); False for a log cut
    short by a crash or damaged."""
    warnings: tuple[str, ...] = ()
    """What reading skipped, one line per damaged stretch and a line of totals (empty for an intact log)."""
    skipped: str = ""
    """The line of totals of what reading skipped as damaged (empty when nothing was)."""
    copied_live: bool = False
    """A `log recover` copy of a log its flight was still writing: it has no end because the flight had not ended
    (known once :meth:`records` has been read through)."""

    def records(self, topics: set[str] | None = None, progress=None) -> Iterator[LogRecord]:
        """Every intact message of ``topics`` (all if None), in file order (log time order); ``progress(fraction)``
        is called every few thousand records with the fraction of the file read."""
        channels: dict[int, Channel] = {}
        size = max(self.path.stat().st_size, 1)
        scan = LogScan(self.path)
        undecodable: dict[str, int] = {}
        recovered: list[str] = []
        for count, rec in enumerate(scan.records(), 1):
            if progress is not None and count % 5000 == 0:
                progress(scan.position / size)
            if isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Metadata):
                self.metadata[rec.name] = dict(rec.metadata).get("value", "")
                if rec.name == RECOVERED:  # one per recovery (a recovered log recovered again has two)
                    recovered += _recovered_from(self.metadata[rec.name])
                    self.copied_live = self.copied_live or \
                        json.loads(self.metadata[rec.name]).get("source_being_written") is True
            elif isinstance(rec, Message):
                ch = channels[rec.channel_id]  # the scan hands out no message before its channel
                if topics is None or ch.topic in topics:
                    try:
                        data = _decode(ch, rec.data)
                    except (ValueError, RecursionError):  # intact bytes (its CRC holds) that no writer of ours wrote
                        undecodable[ch.topic] = undecodable.get(ch.topic, 0) + 1
                        continue
                    yield LogRecord(ch.topic, rec.log_time * 1e-9, rec.publish_time * 1e-9, data)
        self.complete = scan.complete and not undecodable and not recovered
        self.skipped = scan.warnings()[-1] if scan.damage else ""
        self.warnings = (tuple(scan.warnings()) + tuple(recovered)
                         + tuple(f"{n} message(s) on {topic} are not what the topic holds (not a JSON object): skipped"
                                 for topic, n in undecodable.items()))


def _recovered_from(value: str) -> list[str]:
    """The warnings of a :data:`RECOVERED` record (its JSON checked by the scan): none for a copy of a complete log;
    else what its source lost, each line naming the source."""
    record = json.loads(value)
    source = record.get("source", "?")
    if record.get("source_was_complete") is True:
        return []
    if record.get("source_being_written") is True:  # its flight went on: the source has the rest
        return [f"recovered by `log recover` from {source} while its flight was still writing it: {source} holds "
                f"the rest of the flight"] + [f"recovered by `log recover` from {source}, which lost: {w}"
                                             for w in record.get("warnings", [])]
    lost = [str(w) for w in record.get("warnings", [])] or ["cut short (not finalized)"]
    return [f"recovered by `log recover` from {source}, which lost: {w}" for w in lost]


_UNITS = {"position": "position_m", "velocity": "velocity_mps", "acceleration": "acceleration_mps2",
          "omega": "omega_radps", "force": "force_n", "torque": "torque_nm"}
"""Fields of ``/control``'s objects before the names said their units, and their names since."""


def upgraded(topic: str, d: dict) -> dict:
    """A ``/control`` or ``/backend/telemetry`` record of a log written before fields named their units and values
    per module and rotor became per-module objects (``"t"``, ``"motors": [[...], ...]``) in today's shape
    (:mod:`groundstation.flightlog.schemas`), so that replay reads old logs too; any other record as it is. A
    module's unmeasured value (NaN, or null) becomes an absent member, as the writer leaves it out now."""
    if "t" not in d or topic not in ("/control", "/backend/telemetry"):
        return d
    out = {"t_s": d["t"]} | {k: v for k, v in d.items() if k not in ("t", "motors", "applied", "battery_v",
                                                                    "link_latency_s", "link_loss", "gyro")}
    if topic == "/control":
        for part in ("state", "truth", "setpoint", "wrench"):
            if part in d:
                out[part] = {_UNITS.get(k, k): v for k, v in d[part].items()}
        out["modules"] = [{"command_frac_umax": m} for m in d["motors"]]
        for module, applied in zip(out["modules"], d.get("applied", ()), strict=False):
            module["applied_frac_umax"] = applied
        return out
    motors = d.get("motors", [])
    out["modules"] = [{"rotor_speed_sq_rad2_s2": motors[i:i + 4]} for i in range(0, len(motors), 4)]
    for old, new in (("battery_v", "battery_v"), ("link_latency_s", "link_latency_s"),
                     ("link_loss", "link_loss_frac")):
        for module, v in zip(out["modules"], d.get(old, ()), strict=False):
            if v is not None and math.isfinite(v):
                module[new] = v
    if d.get("gyro"):
        out["gyro_radps"] = d["gyro"]
    return out


def is_mocap_pose(topic: str) -> bool:
    """``topic`` is the channel of the raw mocap poses (``/mocap/<body>``: every pose of the body's source, logged
    as it arrived; ``/mocap/stats`` holds the subscriber's counters)."""
    return topic.startswith("/mocap/") and topic != "/mocap/stats"


def commands(d: dict) -> np.ndarray:
    """The rotor commands of a ``/control`` record, (n, 4), fractions of u_max."""
    return np.array([m["command_frac_umax"] for m in d["modules"]], float)


def _decode(ch: Channel, data: bytes) -> object:
    if ch.message_encoding == "json":
        d = json.loads(data)
        if not isinstance(d, dict):  # every JSON record of ours is an object
            raise ValueError("not a JSON object")
        return upgraded(ch.topic, d)
    if ch.topic == "/log":
        msg = Log()
        msg.ParseFromString(data)
        return LEVEL_NAMES.get(msg.level, "info"), msg.message
    return data


def open_log(path: str | Path) -> LogFile:
    """A flight log of this program; a file that is not one is a :class:`ConfigError` naming it and saying what it
    is (one line): not found, not a regular file, empty, not an MCAP file, another program's, or an MCAP file whose
    header record (which names the program) does not read, which ``log recover`` may salvage."""
    p = log_file(path)
    try:
        with open(p, "rb") as fh:
            magic = fh.read(len(MAGIC))
            first = read_header(fh) if magic == MAGIC else None
    except OSError as exc:
        raise ConfigError(f"cannot read: {exc.strerror or exc}", path=str(p)) from None
    if not magic:
        raise ConfigError("empty file, not an MCAP flight log", path=str(p))
    if magic != MAGIC:
        raise ConfigError("not an MCAP file", path=str(p))
    if first is None:
        raise ConfigError("damaged: an MCAP file whose header record (which names the program that wrote it) does "
                          "not read; groundstation log recover may salvage its intact records into a new log",
                          path=str(p))
    if not isinstance(first, Header) or not first.library.startswith(LIBRARY):
        library = first.library if isinstance(first, Header) else "?"
        raise ConfigError(f"an MCAP file, but not a flight log of groundstation (written by {library!r})",
                          path=str(p))
    return LogFile(p, {})
