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
"""

from __future__ import annotations

import os
import struct
import zlib
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
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
"""Largest record (and decompressed chunk) read: a damaged length field must not ask for the whole disk."""
MAX_COMPRESSION_NAME = 8
"""Longest compression name a chunk may carry ("zstd", "lz4" or none): a cheap test of a candidate chunk."""
SCAN_BLOCK = 1 << 16
"""Bytes read at a time when scanning for the next intact chunk."""
WARNING_LINES = 10
"""Damaged stretches described one by one in :meth:`LogScan.warnings`; the summary line counts them all."""

_READERS: dict[int, Callable[[ReadDataStream], McapRecord]] = {
    Opcode.HEADER: Header.read, Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read,
    Opcode.MESSAGE_INDEX: MessageIndex.read, Opcode.METADATA: Metadata.read, Opcode.ATTACHMENT: Attachment.read,
    Opcode.DATA_END: DataEnd.read, Opcode.STATISTICS: Statistics.read}
DATA_OPCODES = frozenset({Opcode.HEADER, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.CHUNK,
                          Opcode.MESSAGE_INDEX, Opcode.METADATA, Opcode.ATTACHMENT, Opcode.DATA_END})
"""The records of a data section; any other opcode there is damage."""
_SUMMARY_OPCODES = frozenset({Opcode.SCHEMA, Opcode.CHANNEL, Opcode.STATISTICS})
"""The summary records the scan uses: the channel table and the message count."""

REASONS = {
    "crc": "CRC mismatch",
    "corrupt": "does not decompress or parse",
    "unreadable": "no readable record",
    "truncated": "the file ends inside a record (cut short)",
    "no channel": "their channel record was in a damaged chunk",
    "summary": "the summary section or footer is damaged or missing; not used, the data section was read",
    "data crc": "the data section's CRC does not match though every chunk's does: a record outside the chunks "
                "(metadata, an index) is damaged",
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

    @property
    def messages(self) -> int | None:
        return None if self.lost is None else sum(self.lost.values())

    def describe(self) -> str:
        """One line for the operator."""
        if self.reason == "no channel":
            return f"{self.messages} messages on {', '.join(sorted(self.lost))} skipped: {REASONS[self.reason]}"
        where = f"bytes {self.span[0]}-{self.span[1]}"
        if self.reason in ("summary", "data crc"):
            return f"{where}: {REASONS[self.reason]}"
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

    def records(self) -> Iterator[McapRecord]:
        """Schema, Channel, Metadata, Attachment and Message records in file order (an intact summary's schemas
        and channels first); never a message whose channel is unknown. A file that is not an MCAP file, or cannot
        be read, is a :class:`ConfigError` naming it."""
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
        if fh.read(len(MAGIC)) != MAGIC:
            raise ConfigError("not an MCAP file", path=str(self.path))
        summary = _summary(fh, self._size)
        end = self._size
        if summary is not None:
            self._expected, end = summary.messages, summary.data_end
            yield from self._handed_out(summary.records)
        pos, crc, ended = len(MAGIC), zlib.crc32(MAGIC), False
        while pos < end and not ended:
            self.position = pos
            try:
                opcode, raw, found = _record(fh, pos, end)
            except _Bad as bad:
                pos = self._skip(fh, pos, end, bad.reason)
                continue
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
            self.damage.append(Damage("summary", (pos, self._size), 0, {}))
        if self._orphans:
            self.damage.append(Damage("no channel", None, 0, dict(self._orphans)))
        self.complete = summary is not None and not self.damage

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
        """The chunks between ``start`` and ``stop`` and, from the message indexes written after them, the messages
        they held per topic; None for the messages as soon as a record there does not parse."""
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
    if stream.count != len(body) or chunk.uncompressed_size > MAX_RECORD_BYTES:
        raise _Bad("corrupt")
    try:
        return breakup_chunk(chunk, validate_crc=True)
    except CRCValidationError:
        raise _Bad("crc") from None
    except Exception:  # noqa: BLE001 - zstd, lz4, struct and the record readers raise their own types
        raise _Bad("corrupt") from None


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
    """Whether an intact chunk starts at ``pos``: its header adds up (cheap, rules out nearly every stray chunk
    opcode byte) and its CRC matches."""
    fh.seek(pos)
    head = fh.read(_RECORD.size + _CHUNK_HEAD.size + MAX_COMPRESSION_NAME + _DATA_LENGTH.size)
    if len(head) < _RECORD.size + _CHUNK_HEAD.size:
        return False
    opcode, length = _RECORD.unpack_from(head)
    name_length = _CHUNK_HEAD.unpack_from(head, _RECORD.size)[-1]
    at = _RECORD.size + _CHUNK_HEAD.size + name_length
    if (opcode != Opcode.CHUNK or name_length > MAX_COMPRESSION_NAME or len(head) < at + _DATA_LENGTH.size
            or length > MAX_RECORD_BYTES or pos + _RECORD.size + length > end
            or length != at - _RECORD.size + _DATA_LENGTH.size + _DATA_LENGTH.unpack_from(head, at)[0]):
        return False
    fh.seek(pos + _RECORD.size)
    try:
        _chunk_records(fh.read(length))
    except _Bad:
        return False
    return True


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


def _summary(fh: BinaryIO, size: int) -> _Summary | None:
    """The summary section, if the footer is intact and the summary's CRC matches (else None: the scan reads the
    data section to its end without it)."""
    footer_at = size - _FOOTER.size - len(MAGIC)
    if footer_at < len(MAGIC):
        return None
    fh.seek(footer_at)
    tail = fh.read(_FOOTER.size + len(MAGIC))
    opcode, length, start, _, crc = _FOOTER.unpack_from(tail)
    if (tail[_FOOTER.size:] != MAGIC or opcode != Opcode.FOOTER or length != _FOOTER.size - _RECORD.size
            or not (start == 0 or len(MAGIC) < start <= footer_at)):
        return None
    data_end = start or footer_at
    fh.seek(data_end)
    body = fh.read(footer_at - data_end)
    if crc and zlib.crc32(tail[:_FOOTER.size - 4], zlib.crc32(body)) != crc:
        return None
    try:
        found = [_parse(op, rec) for op, rec in _split(body) if op in _SUMMARY_OPCODES]
    except _Bad:
        return None
    messages = [r.message_count for r in found if isinstance(r, Statistics)]
    return _Summary([r for r in found if not isinstance(r, Statistics)], messages[0] if messages else None, data_end)


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
