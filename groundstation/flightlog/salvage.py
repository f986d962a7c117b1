"""Reading a flight log that may be damaged: every intact record, and what was skipped, where and why.

An MCAP file guards its bytes with CRCs: each chunk's records (``uncompressed_crc``, set by the ``mcap`` writer),
the whole data section (the Data End record's ``data_section_crc``, set by this program's writers) and the summary
section with the footer (``summary_crc``). The ``mcap`` package reads front to back and stops at the first record
it cannot read (with ``validate_crcs``, at the first CRC mismatch), and without ``validate_crcs`` it hands out a
damaged record as if it were sound: one flipped bit crashed ``replay`` and was copied by ``log recover``, and 64
flipped bytes cost both every chunk after the first bad one.

:class:`LogScan` goes record by record instead. A chunk whose CRC does not match, that does not decompress, or a
record that does not parse exactly is skipped, and reading resumes at the next chunk whose CRC matches, found by
scanning forward for the chunk opcode: the damaged record's own length cannot be trusted. Each skipped stretch is
a :class:`Damage` naming its byte offsets, why, the chunks in it and, when the message index written after a chunk
survives, the messages lost per channel. When the summary section's CRC matches, its copy of the schemas and
channels is read first, so a damaged first chunk (where every channel is defined) does not orphan every later
message, and its message count makes the number of messages lost exact. A file cut short (both processes of
``fly`` killed) is damage too: the record the file ends in is lost.

A record outside the chunks (the header, a metadata record, a message index) that does not parse is skipped alone
when where it ends can be told (:func:`_resync`): at the end its length field gives, or, when that field is what
is damaged, at the end of its content; either way only if a sound record follows. A ``config`` or ``assembly``
metadata record whose value is not the JSON object the flight wrote is damage too, skipped and named: no CRC of
its own covers it (the data section's CRC says only that something outside the chunks changed), and one flipped
bit there made ``replay`` refuse the whole log and ``log recover`` copy it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import stat
import struct
import zlib
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import BinaryIO

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Header,
    McapRecord,
    Message,
    MessageIndex,
    Metadata,
    Schema,
    Statistics,
)
from mcap.stream_reader import CRCValidationError, breakup_chunk

from groundstation.errors import ConfigError

MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")
"""Every record's opcode and body length."""
_CHUNK_HEAD = struct.Struct("<QQQII")
"""A chunk body's start: message start and end time, uncompressed size, uncompressed CRC, compression name length."""
_FOOTER = struct.Struct("<BQQQI")
"""The footer record: opcode, length, summary start, summary offset start, summary CRC."""
_DATA_LENGTH = struct.Struct("<Q")
"""A chunk body's compressed data length, after the compression name."""
_CHUNK_OPCODE = bytes([Opcode.CHUNK])
MAX_RECORD_BYTES = 1 << 30
"""Largest record read: a damaged length field must not ask for the whole disk (a decompressed chunk:
:data:`MAX_CHUNK_BYTES`)."""
MAX_CHUNK_BYTES = 16 << 20
"""Largest decompressed chunk read: our writer closes a chunk past 32 KiB; a chunk declaring 64 MiB of tiny records
cost replay 59 s and 737 MB from 5.7 KB of file (hostile campaign 33)."""
MAX_COMPRESSION_NAME = 8
"""Longest compression name a chunk may carry ("zstd", "lz4" or none): a cheap test of a candidate chunk."""
SCAN_BLOCK = 1 << 16
"""Bytes read at a time when scanning for the next intact chunk."""
RESYNC_BYTES = 1 << 20
"""Most bytes of a damaged record outside the chunks parsed to find where its content ends."""
JSON_METADATA = frozenset({"config", "assembly", "recovered"})
"""Metadata records whose value is a JSON object (a flight's: ``runtime/fly.py``; ``log recover``'s:
:data:`groundstation.flightlog.mcap_log.RECOVERED`)."""
ORDER_SLACK_NS = 500_000_000
"""A chunk starting this much before the latest message of those read before it is out of order, ns."""
WARNING_LINES = 10
"""Damaged stretches described one by one in :meth:`LogScan.warnings`; the summary line counts them all."""

_READERS: dict[int, Callable[[ReadDataStream], McapRecord]] = {
    Opcode.HEADER: Header.read, Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read,
    Opcode.MESSAGE_INDEX: MessageIndex.read, Opcode.METADATA: Metadata.read, Opcode.ATTACHMENT: Attachment.read,
    Opcode.DATA_END: DataEnd.read, Opcode.STATISTICS: Statistics.read, Opcode.CHUNK_INDEX: ChunkIndex.read}
DATA_OPCODES = frozenset({Opcode.HEADER, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.CHUNK,
                          Opcode.MESSAGE_INDEX, Opcode.METADATA, Opcode.ATTACHMENT, Opcode.DATA_END})
"""The records of a data section; any other opcode there is damage."""
_SUMMARY_OPCODES = frozenset({Opcode.SCHEMA, Opcode.CHANNEL, Opcode.STATISTICS, Opcode.CHUNK_INDEX})
"""The summary records the scan uses: the channel table, the message count and where each chunk is."""
_SUMMARY_SECTION = _SUMMARY_OPCODES | {Opcode.METADATA_INDEX, Opcode.ATTACHMENT_INDEX, Opcode.SUMMARY_OFFSET}
"""Every record a summary section may hold."""
_DATA_END_BYTES = _RECORD.size + 4
"""The Data End record: its opcode, length and data section CRC."""

REASONS = {
    "crc": "CRC mismatch",
    "corrupt": "does not decompress or parse",
    "unreadable": "no readable record",
    "truncated": "the file ends inside a record (cut short)",
    "no channel": "their channel record was in a damaged chunk",
    "not listed": "an intact chunk the summary does not list (spliced in from another file): not this flight's",
    "copy": "an intact chunk that repeats one read before (a duplicate): read once",
    "moved": "an intact chunk of this flight out of its place (the summary lists it elsewhere): read",
    "summary": "the summary section or footer is damaged or missing; not used, the data section was read",
    "data crc": "the data section's CRC does not match though every chunk's does: a record outside the chunks "
                "(metadata, an index) is damaged",
    "metadata": "a metadata record is damaged",
    "record": "a record outside the chunks (the header, a message index) is damaged",
    "miscount": "the summary disagrees with the data section",
    "order": "an intact chunk earlier in flight time than the one before it (chunks moved): read",
    "appended": "a second log appended after this one's end: not read (split the file there to read it)",
}
"""Why something was skipped, by the key :meth:`LogScan.dropped` counts it under."""


class _Bad(Exception):
    """A record that is not what its header says (``reason``: a key of :data:`REASONS`)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class Damage:
    """One stretch of a log that was skipped."""

    reason: str
    """A key of :data:`REASONS`."""
    span: tuple[int, int] | None
    """Byte offsets [start, end) in the file (None for messages dropped for want of their channel)."""
    chunks: int
    """Chunk records found in the stretch."""
    lost: dict[str, int] | None
    """Messages lost per topic (``channel N`` when its record is lost too); None when unknown (no intact message
    index describes the stretch)."""
    note: str = ""
    """Which record and why, for a record outside the chunks skipped alone (reasons ``metadata`` and ``record``)."""

    @property
    def messages(self) -> int | None:
        return None if self.lost is None else sum(self.lost.values())

    def describe(self) -> str:
        """One line for the operator."""
        if self.reason == "no channel":
            return f"{self.messages} messages on {', '.join(sorted(self.lost))} skipped: {REASONS[self.reason]}"
        where = f"bytes {self.span[0]}-{self.span[1]}"
        if self.reason in ("summary", "data crc", "moved", "order", "appended"):
            return f"{where}: {REASONS[self.reason]}"
        if self.reason == "miscount":
            return f"{REASONS[self.reason]}: {self.note}"
        if self.reason in ("metadata", "record"):
            return f"{where}: {self.note}: skipped"
        lost = "messages unknown" if self.lost is None else _count(self.messages, "message") + (
            " (" + ", ".join(f"{t}: {n}" for t, n in sorted(self.lost.items(), key=lambda x: -x[1])) + ")"
            if self.lost else "")
        return f"{where}: {REASONS[self.reason]}: {_count(self.chunks, 'chunk')}, {lost}, skipped"


@dataclass(frozen=True)
class _Summary:
    """What an intact summary section gives the scan."""

    records: list[McapRecord]
    """Its schemas and channels."""
    messages: int | None
    """The file's message count (None without a Statistics record)."""
    data_end: int
    """Where the data section ends (the Data End record's end)."""
    chunks: dict[int, tuple[int, int, int]]
    """Each chunk's offset -> (record length, first and last message time), from its index."""


class LogScan:
    """One pass over the intact records of a log, noting each stretch it skips (:attr:`damage`)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.damage: list[Damage] = []
        self.complete = False
        """Finalized (an intact summary and footer) with nothing damaged; known once :meth:`records` has run."""
        self.chunks = 0
        """Intact chunks read."""
        self.messages = 0
        """Messages handed out."""
        self.position = 0
        """Byte offset reached, for progress."""
        self._size = 0
        self._expected: int | None = None
        self._topics: dict[int, str] = {}
        self._orphans: Counter[str] = Counter()
        self._chunk_index: dict[int, tuple[int, int, int]] = {}
        """An intact summary's chunk index (see :class:`_Summary`); empty without one."""
        self._seen_chunks: set = set()
        """Every chunk read so far: its index key and CRC."""
        self._chunk_starts: set[int] = set()
        """Where each chunk read begins (file offset)."""
        self._last_time = 0
        """The latest message time of the chunks read so far, ns."""

    def records(self) -> Iterator[McapRecord]:
        """Schema, Channel, Metadata, Attachment and Message records in file order (an intact summary's schemas
        and channels first); never a message whose channel is unknown. A file that is not an MCAP file, or cannot
        be read, is a :class:`ConfigError` naming it."""
        log_file(self.path)  # never opened if it is not a regular file: a FIFO would block, /dev/zero never end
        try:
            with open(self.path, "rb") as fh:
                yield from self._records(fh)
        except OSError as exc:  # a read error: the caller's own errors (writing) are not raised in here
            raise ConfigError(f"cannot read: {exc.strerror or exc}", path=str(self.path)) from None

    @property
    def messages_lost(self) -> int | None:
        """Messages the file had that were not handed out: exact when the summary is intact (its count), else the
        sum over the damage, None when some of it is unknown."""
        if self._expected is not None:
            return self._expected - self.messages
        counts = [d.messages for d in self.damage]
        return None if None in counts else sum(counts)

    def dropped(self) -> dict:
        """Chunks and messages dropped, in all and by reason (messages None where unknown)."""
        by_reason: dict[str, dict] = {}
        for d in self.damage:
            entry = by_reason.setdefault(d.reason, {"chunks": 0, "messages": 0})
            entry["chunks"] += d.chunks
            entry["messages"] = None if entry["messages"] is None or d.messages is None else \
                entry["messages"] + d.messages
        return {"chunks": sum(d.chunks for d in self.damage), "messages": self.messages_lost, "by_reason": by_reason}

    def warnings(self) -> list[str]:
        """One line per damaged stretch (the first :data:`WARNING_LINES`), then one line of totals."""
        if not self.damage:
            return []
        lines = [d.describe() for d in self.damage[:WARNING_LINES]]
        more = len(self.damage) - WARNING_LINES
        lost = self.messages_lost
        lines.append(_count(len(self.damage), "damaged stretch", "es") + (f" ({more} not listed)" if more > 0 else "")
                     + f": {_count(sum(d.chunks for d in self.damage), 'chunk')} and "
                     + ("an unknown number of messages" if lost is None else _count(lost, "message"))
                     + f" skipped; {_count(self.messages, 'message')} in {_count(self.chunks, 'intact chunk')} read")
        return lines

    # -- the pass ---------------------------------------------------------------------------------------------------
    def _records(self, fh: BinaryIO) -> Iterator[McapRecord]:
        self._size = os.fstat(fh.fileno()).st_size
        magic = fh.read(len(MAGIC))
        if magic != MAGIC:
            raise ConfigError("not an MCAP file" if magic else "empty file, not an MCAP flight log",
                              path=str(self.path))
        summary = _summary(fh, self._size)
        end = self._size
        if summary is not None:
            self._expected, end = summary.messages, summary.data_end
            self._chunk_index = summary.chunks
            yield from self._handed_out(summary.records)
        pos, crc, ended = len(MAGIC), zlib.crc32(MAGIC), False
        while pos < end and not ended:
            self.position = pos
            try:
                opcode, raw, found = _record(fh, pos, end)
            except _Bad as bad:
                resync = _resync(fh, pos, end, bad.reason)
                if resync is None:
                    pos = self._skip(fh, pos, end, bad.reason)
                else:
                    resume, _, reason, note = resync
                    self.damage.append(Damage(reason, (pos, resume), 0, {}, note))
                    pos = resume
                continue
            placed = self._misplaced(pos, raw, found) if opcode == Opcode.CHUNK else None
            if placed == "moved":
                self.damage.append(Damage(placed, (pos, pos + len(raw)), 0, {}))  # read: the file is damaged, not
                # what it holds
            elif placed is not None:
                # A duplicate was read twice and a chunk of another flight as this one's, each "intact" (hostile
                # campaign 30); their messages are not lost, they were never this flight's record.
                self.damage.append(Damage(placed, (pos, pos + len(raw)), 1, {}))
                pos += len(raw)
                continue
            if opcode == Opcode.METADATA and (why := _metadata_fault(found[0])) is not None:
                self.damage.append(Damage("metadata", (pos, pos + len(raw)), 0, {},
                                          f"the {found[0].name} metadata record is damaged ({why})"))
                pos += len(raw)
                continue
            if opcode == Opcode.CHUNK:
                self._note_chunk(pos, raw, found)
            if opcode == Opcode.DATA_END:
                self._check_data_crc(found[0], crc, pos)
                ended = True
            elif not self.damage:  # the data section's CRC is only worth checking while nothing else is damaged
                crc = zlib.crc32(raw, crc)
            self.chunks += opcode == Opcode.CHUNK
            pos += len(raw)
            yield from self._handed_out(r for r in found if not isinstance(r, Header | MessageIndex | DataEnd))
        self.position = pos
        if summary is None and ended:
            appended = _appended_log(fh, pos, self._size)
            if appended is None:
                self.damage.append(Damage("summary", (pos, self._size), 0, {}))
            else:
                self.damage += [Damage("summary", (pos, appended), 0, {}),
                                Damage("appended", (appended, self._size), 0, None)]
        if self._orphans:
            self.damage.append(Damage("no channel", None, 0, dict(self._orphans)))
        if summary is not None and not self.damage:
            self._check_summary(summary, ended)
        self.complete = summary is not None and not self.damage

    def _check_summary(self, summary: _Summary, ended: bool) -> None:
        """An intact summary (its CRC may be recomputed by whoever edited it) against the data section read
        without damage: its message count and its chunks; a summary that lies is damage, never "complete" (a count
        of 20000 for 14753 messages, a chunk index listing chunks that are not there, replayed complete)."""
        said = []
        if not ended:
            said.append("its data section ends without a Data End record")
        if summary.messages is not None and summary.messages != self.messages:
            said.append(f"it counts {summary.messages} messages, {self.messages} were read")
        unread = len(set(summary.chunks) - self._chunk_starts)
        if unread:
            said.append(f"{_count(unread, 'chunk')} it lists were not found")
        if said:
            self.damage.append(Damage("miscount", (0, self._size), 0, None, "; ".join(said)))

    def _note_chunk(self, pos: int, raw: bytes, found: list[McapRecord]) -> None:
        """Where a chunk read begins (for :meth:`_check_summary`); and, read in file order, whether its first
        message comes well before the previous chunks' last (our writer closes chunks in flight time; its threads'
        stamps interleave by milliseconds): named, read. The timeline ran backwards and forwards unremarked, and
        with a footer added the log replayed complete."""
        self._chunk_starts.add(pos)
        times = [r.log_time for r in found if isinstance(r, Message)]
        if not times:
            return
        if min(times) < self._last_time - ORDER_SLACK_NS:
            self.damage.append(Damage("order", (pos, pos + len(raw)), 0, {}))
        self._last_time = max(self._last_time, max(times))

    def _handed_out(self, records) -> Iterator[McapRecord]:
        """``records`` but messages whose channel is unknown (counted instead)."""
        for rec in records:
            if isinstance(rec, Channel):
                self._topics[rec.id] = rec.topic
            elif isinstance(rec, Message):
                if rec.channel_id not in self._topics:
                    self._orphans[f"channel {rec.channel_id}"] += 1
                    continue
                self.messages += 1
            yield rec

    def _misplaced(self, pos: int, raw: bytes, found: list[McapRecord]) -> str | None:
        """None for a sound chunk (``raw``, its records ``found``) where it was written; else a key of
        :data:`REASONS`: ``copy`` (it repeats one read before), ``not listed`` (an intact summary does not list
        it), ``moved`` (it lists it elsewhere). Its message times are taken from its messages: its header's copy
        of them is under no CRC, and damage there is not a chunk of another file."""
        times = [r.log_time for r in found if isinstance(r, Message)]
        key = (len(raw), min(times, default=0), max(times, default=0))
        whole = (key, raw[_RECORD.size + 24:_RECORD.size + 28])  # and its uncompressed CRC
        if whole in self._seen_chunks:
            return "copy"
        self._seen_chunks.add(whole)
        if not self._chunk_index or self._chunk_index.get(pos) == key:
            return None
        return "moved" if key in self._chunk_index.values() else "not listed"  # rare: a scan of the index

    def _check_data_crc(self, data_end: DataEnd, crc: int, pos: int) -> None:
        """Damage no chunk CRC covers (the header, metadata, message indexes) shows only here; 0 means the writer
        computed no CRC (logs written before this program set ``enable_data_crcs``)."""
        if data_end.data_section_crc not in (0, crc) and not self.damage:
            self.damage.append(Damage("data crc", (0, pos), 0, {}))

    def _skip(self, fh: BinaryIO, start: int, end: int, reason: str) -> int:
        """Note the damaged stretch from ``start`` to the next intact chunk (or ``end``) and return where that is.
        A record running past the end of the file is a truncation only if no intact chunk follows and the file has
        no intact footer; else its length field is what is damaged."""
        resume = _next_chunk(fh, start + 1, end)
        if reason == "truncated" and (resume < end or end < self._size):
            reason = "unreadable"
        chunks, lost = self._tally(fh, start, resume)
        self.damage.append(Damage(reason, (start, resume), chunks, lost))
        return resume

    def _tally(self, fh: BinaryIO, start: int, stop: int) -> tuple[int, dict[str, int] | None]:
        """The chunks between ``start`` and ``stop`` (from an intact summary's chunk index, else those whose records
        can be walked from ``start``) and, from the message indexes written after them, the messages they held per
        topic; None for the messages as soon as a record there does not parse."""
        chunks, lost = self._walk(fh, start, stop)
        if self._chunk_index:
            chunks = sum(start <= at < stop for at in self._chunk_index)
        return chunks, lost

    def _walk(self, fh: BinaryIO, start: int, stop: int) -> tuple[int, dict[str, int] | None]:
        lost: Counter[str] = Counter()
        chunks, pos = 0, start
        while pos < stop:
            fh.seek(pos)
            head = fh.read(_RECORD.size)
            if len(head) < _RECORD.size:
                return chunks, None
            opcode, length = _RECORD.unpack(head)
            chunks += opcode == Opcode.CHUNK
            if opcode not in DATA_OPCODES or pos + _RECORD.size + length > stop:
                return chunks, None
            if opcode == Opcode.MESSAGE_INDEX:
                try:
                    index = _parse(opcode, fh.read(length))
                except _Bad:
                    return chunks, None
                lost[self._topics.get(index.channel_id, f"channel {index.channel_id}")] += len(index.records)
            pos += _RECORD.size + length
        return chunks, (dict(lost) if lost or not chunks else None)


def _count(n: int, noun: str, plural: str = "s") -> str:
    return f"{n} {noun}{plural * (n != 1)}"


def _parse(opcode: int, body: bytes) -> McapRecord:
    """The record in ``body``; one its reader does not consume exactly, or an attachment whose CRC does not match,
    is damage (a record that is not what its header says)."""
    stream = ReadDataStream(BytesIO(body))
    try:
        record = Message.read(stream, len(body)) if opcode == Opcode.MESSAGE else _READERS[opcode](stream)
    except Exception:  # noqa: BLE001 - the record readers raise several types on garbage
        raise _Bad("unreadable") from None
    if stream.count != len(body):
        raise _Bad("unreadable")
    if isinstance(record, Attachment) and int.from_bytes(body[-4:], "little") not in (0, zlib.crc32(body[:-4])):
        raise _Bad("crc")
    return record


def _chunk_records(body: bytes) -> list[McapRecord]:
    """The records of the chunk in ``body``, its CRC checked (``mcap``'s own check, after decompression)."""
    stream = ReadDataStream(BytesIO(body))
    try:
        chunk = Chunk.read(stream)
    except Exception:  # noqa: BLE001 - as in _parse
        raise _Bad("corrupt") from None
    if stream.count != len(body) or chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise _Bad("corrupt")
    try:
        return breakup_chunk(_decompressed(chunk), validate_crc=True)
    except CRCValidationError:
        raise _Bad("crc") from None
    except Exception:  # noqa: BLE001 - zstd, lz4, struct and the record readers raise their own types
        raise _Bad("corrupt") from None


def _decompressed(chunk: Chunk) -> Chunk:
    """``chunk`` with its data decompressed, never past the size its header declares: a zstd frame that names its
    own size, or lz4, had ``mcap`` decompress 98 KiB to 3 GiB whatever the header said (hostile campaign 32)."""
    if chunk.compression == "":
        return chunk
    limit = chunk.uncompressed_size
    if chunk.compression == "zstd":
        data = zstandard.ZstdDecompressor().stream_reader(BytesIO(chunk.data)).read(limit + 1)
    elif chunk.compression == "lz4":
        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=limit + 1)
    else:
        raise _Bad("corrupt")
    if len(data) != limit:
        raise _Bad("corrupt")
    return dataclasses.replace(chunk, compression="", data=data)


def _record(fh: BinaryIO, pos: int, end: int) -> tuple[int, bytes, list[McapRecord]]:
    """The data-section record at ``pos``: its opcode, its bytes, and its records (a chunk's, checked, or itself).
    Raises :class:`_Bad`."""
    fh.seek(pos)
    head = fh.read(_RECORD.size)
    if len(head) < _RECORD.size:
        raise _Bad("truncated")
    opcode, length = _RECORD.unpack(head)
    if opcode not in DATA_OPCODES or length > MAX_RECORD_BYTES:
        raise _Bad("unreadable")
    if pos + _RECORD.size + length > end:
        raise _Bad("truncated")
    body = fh.read(length)
    found = _chunk_records(body) if opcode == Opcode.CHUNK else [_parse(opcode, body)]
    return opcode, head + body, found


def _chunk_at(fh: BinaryIO, pos: int, end: int) -> bool:
    """Whether an intact chunk starts at ``pos``: its opcode says so, its header adds up (cheap, rules out nearly
    every stray chunk opcode byte) and its CRC matches."""
    fh.seek(pos)
    if fh.read(1) != _CHUNK_OPCODE:
        return False
    length = _chunk_shaped(fh, pos, end)
    if length is None:
        return False
    fh.seek(pos + _RECORD.size)
    try:
        _chunk_records(fh.read(length))
    except _Bad:
        return False
    return True


def _chunk_shaped(fh: BinaryIO, pos: int, end: int) -> int | None:
    """The body length of the record at ``pos`` if its header adds up as a chunk's, whatever its opcode (a chunk
    whose opcode byte is damaged is still one); else None."""
    fh.seek(pos)
    head = fh.read(_RECORD.size + _CHUNK_HEAD.size + MAX_COMPRESSION_NAME + _DATA_LENGTH.size)
    if len(head) < _RECORD.size + _CHUNK_HEAD.size:
        return None
    _, length = _RECORD.unpack_from(head)
    name_length = _CHUNK_HEAD.unpack_from(head, _RECORD.size)[-1]
    at = _RECORD.size + _CHUNK_HEAD.size + name_length
    if (name_length > MAX_COMPRESSION_NAME or len(head) < at + _DATA_LENGTH.size
            or length > MAX_RECORD_BYTES or pos + _RECORD.size + length > end
            or length != at - _RECORD.size + _DATA_LENGTH.size + _DATA_LENGTH.unpack_from(head, at)[0]):
        return None
    return length


def _next_chunk(fh: BinaryIO, start: int, end: int) -> int:
    """The offset of the first intact chunk at or after ``start`` (``end`` if there is none)."""
    pos = start
    while pos < end:
        fh.seek(pos)
        block = fh.read(min(SCAN_BLOCK, end - pos))
        if not block:
            break
        i = block.find(_CHUNK_OPCODE)
        while i >= 0:
            if _chunk_at(fh, pos + i, end):
                return pos + i
            i = block.find(_CHUNK_OPCODE, i + 1)
        pos += len(block)
    return end


_KINDS = {Opcode.HEADER: "header", Opcode.SCHEMA: "schema", Opcode.CHANNEL: "channel",
          Opcode.MESSAGE_INDEX: "message index", Opcode.METADATA: "metadata", Opcode.ATTACHMENT: "attachment"}
"""The records outside the chunks that :func:`_resync` skips alone, by what the operator is told they are."""


def _resync(fh: BinaryIO, pos: int, end: int, reason: str) -> tuple[int, McapRecord | None, str, str] | None:
    """Where reading goes on after the damaged record at ``pos`` (why: ``reason``, a key of :data:`REASONS`) when
    it is a record outside the chunks and where it ends can be told: at the end its length field gives, or, when
    that field is what is damaged, at the end of its content (which parses then); either way only if a sound
    record, or the data section's end, follows there. Returns that offset, the record's content when it parsed,
    the damage's reason and its note; None otherwise (a chunk, a record shaped as one whose opcode byte is
    damaged, an unknown opcode: reading resumes at the next intact chunk)."""
    fh.seek(pos)
    head = fh.read(_RECORD.size)
    if len(head) < _RECORD.size:
        return None
    opcode, length = _RECORD.unpack(head)
    if opcode not in _KINDS or _chunk_shaped(fh, pos, end) is not None:  # a chunk whose opcode is damaged
        return None
    fh.seek(pos + _RECORD.size)
    body = fh.read(max(min(length, RESYNC_BYTES, end - pos - _RECORD.size), 0))
    if opcode == Opcode.METADATA:
        name = _metadata_name(body)
        what, kind = ("a metadata record" if name is None else f"the {name} metadata record"), "metadata"
    else:
        what, kind = f"the {_KINDS[opcode]} record", "record"
    at = pos + _RECORD.size + length
    if at <= end and _sound_at(fh, at, end):
        why = "its CRC does not match" if reason == "crc" else "it does not parse"
        return at, None, kind, f"{what} is damaged ({why})"
    stream = ReadDataStream(BytesIO(body))
    try:
        record = _READERS[opcode](stream)
    except Exception:  # noqa: BLE001 - as in _parse
        return None
    at = pos + _RECORD.size + stream.count
    if not _sound_at(fh, at, end):
        return None
    return at, record, kind, f"{what} is damaged (its length field is wrong)"


def _sound_at(fh: BinaryIO, pos: int, end: int) -> bool:
    """Whether the data section ends at ``pos`` or a record that reads (a chunk: its CRC matches) starts there."""
    if pos == end:
        return True
    try:
        _record(fh, pos, end)
    except _Bad:
        return False
    return True


def _metadata_name(body: bytes) -> str | None:
    """The name at the start of a metadata record's ``body``, if it reads as one (a short printable string)."""
    n = int.from_bytes(body[:4], "little")
    try:
        name = body[4:4 + n].decode("ascii")
    except UnicodeDecodeError:
        return None
    return name if 0 < n <= 64 and len(name) == n and name.isprintable() else None


def _metadata_fault(rec: Metadata) -> str | None:
    """Why a metadata record of :data:`JSON_METADATA` is not what the flight wrote (None: it is, or it is another
    record): its value must be a JSON object."""
    if rec.name not in JSON_METADATA:
        return None
    value = rec.metadata.get("value")
    if value is None:
        return "it has no value"
    try:
        parsed = json.loads(value)
    except (ValueError, RecursionError):
        return "its value is not JSON"
    return None if isinstance(parsed, dict) else "its value is not a JSON object"


_FILE_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
               (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"))


def log_file(path: str | Path) -> Path:
    """``path``, a regular file to read a log from; else a :class:`ConfigError` naming it and saying what it is
    (never opened: a FIFO would block, ``/dev/zero`` never end)."""
    p = Path(path)
    try:
        mode = p.stat().st_mode
    except FileNotFoundError:
        raise ConfigError("file not found", path=str(p)) from None
    except OSError as exc:
        raise ConfigError(f"cannot read: {exc.strerror or exc}", path=str(p)) from None
    if not stat.S_ISREG(mode):
        kind = next((name for test, name in _FILE_KINDS if test(mode)), "an unknown kind")
        raise ConfigError(f"not a regular file ({kind}), not an MCAP flight log", path=str(p))
    return p


def read_header(fh: BinaryIO) -> McapRecord | None:
    """The first record of the MCAP file open in ``fh`` (past its magic, checked by the caller): a flight log's
    :class:`Header`, which names the program that wrote it. A header whose length field alone is damaged is read
    from its content (:func:`_resync`; :class:`LogScan` names the damage); None when it does not read, or the first
    record is a chunk."""
    end = os.fstat(fh.fileno()).st_size
    try:
        opcode, _, found = _record(fh, len(MAGIC), end)
    except _Bad as bad:
        resync = _resync(fh, len(MAGIC), end, bad.reason)
        return None if resync is None else resync[1]
    return None if opcode == Opcode.CHUNK else found[0]


def _summary(fh: BinaryIO, size: int) -> _Summary | None:
    """The summary section, if the footer is intact and the summary's CRC matches (else None: the scan reads the
    data section to its end without it)."""
    footer_at = size - _FOOTER.size - len(MAGIC)
    if footer_at < len(MAGIC):
        return None
    fh.seek(footer_at)
    tail = fh.read(_FOOTER.size + len(MAGIC))
    opcode, length, start, _, crc = _FOOTER.unpack_from(tail)
    # Our writer always writes a summary, right after the Data End record, and its CRC: a footer saying none
    # (start 0, or CRC 0), or pointing elsewhere (at a chunk: the 180 after it went unread), is not trusted.
    if (tail[_FOOTER.size:] != MAGIC or opcode != Opcode.FOOTER or length != _FOOTER.size - _RECORD.size
            or not len(MAGIC) + _DATA_END_BYTES <= start <= footer_at or crc == 0):
        return None
    fh.seek(start - _DATA_END_BYTES)
    if fh.read(_RECORD.size) != _RECORD.pack(Opcode.DATA_END, _DATA_END_BYTES - _RECORD.size):
        return None
    data_end = start
    fh.seek(data_end)
    body = fh.read(footer_at - data_end)
    if zlib.crc32(tail[:_FOOTER.size - 4], zlib.crc32(body)) != crc:
        return None
    try:
        records = list(_split(body))
        if any(op not in _SUMMARY_SECTION for op, _ in records):
            return None  # a data record, or another log, where the summary should be
        found = [_parse(op, rec) for op, rec in records if op in _SUMMARY_OPCODES]
    except _Bad:
        return None
    messages = [r.message_count for r in found if isinstance(r, Statistics)]
    chunks = {r.chunk_start_offset: (r.chunk_length, r.message_start_time, r.message_end_time)
              for r in found if isinstance(r, ChunkIndex)}
    return _Summary([r for r in found if not isinstance(r, Statistics | ChunkIndex)],
                    messages[0] if messages else None, data_end, chunks)


def _appended_log(fh: BinaryIO, start: int, end: int) -> int | None:
    """Where a second log begins after this one's end (``start``: past its Data End), if one does: its magic
    followed by a Header record (``cat a.mcap b.mcap``: the second flight was dropped, "0 messages lost")."""
    fh.seek(start)
    rest = fh.read(min(end - start, RESYNC_BYTES))
    at = rest.find(MAGIC + bytes([Opcode.HEADER]))
    return None if at < 0 else start + at


def _split(body: bytes) -> Iterator[tuple[int, bytes]]:
    """The (opcode, body) of each record in ``body``; raises :class:`_Bad` if the last one overruns it."""
    pos = 0
    while pos < len(body):
        if pos + _RECORD.size > len(body):
            raise _Bad("unreadable")
        opcode, length = _RECORD.unpack_from(body, pos)
        pos += _RECORD.size + length
        if pos > len(body):
            raise _Bad("unreadable")
        yield opcode, body[pos - length:pos]
