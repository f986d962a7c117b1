"""Reading a flight log back, streamed: one record at a time, whatever the file's length.

The reader goes through the file front to back (:class:`~groundstation.flightlog.salvage.LogScan`: it needs no
summary section, so a log recovered after a crash, or cut short by a crash, reads too, up to its last complete
chunk; a damaged chunk or record is skipped and reading goes on with the next intact chunk) and decodes JSON
channels to dicts and ``/log`` to (level, text). Memory does not grow with the file: nothing is kept but the
channel table.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from foxglove_schemas_protobuf.Log_pb2 import Log
from mcap.records import Channel, Header, Message, Metadata
from mcap.stream_reader import StreamReader

from groundstation.errors import ConfigError
from groundstation.flightlog.mcap_log import LIBRARY
from groundstation.flightlog.salvage import LogScan

LEVEL_NAMES = {Log.DEBUG: "debug", Log.INFO: "info", Log.WARNING: "warning", Log.ERROR: "error",
               Log.FATAL: "fatal"}


@dataclass(frozen=True, eq=False)
class LogRecord:
    topic: str
    log_time: float
    """When it was logged, s since the epoch (the flight's one clock)."""
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

    def records(self, topics: set[str] | None = None, progress=None) -> Iterator[LogRecord]:
        """Every intact message of ``topics`` (all if None), in file order (log time order); ``progress(fraction)``
        is called every few thousand records with the fraction of the file read."""
        channels: dict[int, Channel] = {}
        size = max(self.path.stat().st_size, 1)
        scan = LogScan(self.path)
        for count, rec in enumerate(scan.records(), 1):
            if progress is not None and count % 5000 == 0:
                progress(scan.position / size)
            if isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Metadata):
                self.metadata[rec.name] = dict(rec.metadata).get("value", "")
            elif isinstance(rec, Message):
                ch = channels[rec.channel_id]  # the scan hands out no message before its channel
                if topics is None or ch.topic in topics:
                    yield LogRecord(ch.topic, rec.log_time * 1e-9, _decode(ch, rec.data))
        self.complete, self.warnings = scan.complete, tuple(scan.warnings())


def _decode(ch: Channel, data: bytes) -> object:
    if ch.message_encoding == "json":
        return json.loads(data)
    if ch.topic == "/log":
        msg = Log()
        msg.ParseFromString(data)
        return LEVEL_NAMES.get(msg.level, "info"), msg.message
    return data


def open_log(path: str | Path) -> LogFile:
    """A flight log of this program; a file that is not one is a :class:`ConfigError` naming it (one line)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError("file not found", path=str(p))
    with open(p, "rb") as fh:
        try:
            first = next(StreamReader(fh, skip_magic=False).records)
        except StopIteration:
            raise ConfigError("empty file, not an MCAP flight log", path=str(p)) from None
        except Exception:  # noqa: BLE001 - the mcap reader raises several types for a foreign file
            raise ConfigError("not an MCAP file", path=str(p)) from None
    if not isinstance(first, Header) or not first.library.startswith(LIBRARY):
        library = first.library if isinstance(first, Header) else "?"
        raise ConfigError(f"an MCAP file, but not a flight log of groundstation (written by {library!r})",
                          path=str(p))
    return LogFile(p, {})
