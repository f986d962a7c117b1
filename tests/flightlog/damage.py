"""A real flight log to damage, damage done to its bytes, and what must survive it, worked out independently.

The log is made once per test run by ``fly`` (a 1 s hover of the two-module V, simulated: ~150 chunks). The oracle
reads the undamaged original with the ``mcap`` package's own reader and its chunk index, chunk by chunk: what is
in each chunk (messages per topic, control periods, the channels it defines) and where it lies. A chunk survives
damage when none of its bytes changed; a channel's messages are readable when its channel record is in a surviving
chunk or the summary (which repeats every channel) is intact.
"""

from __future__ import annotations

import atexit
import functools
import io
import json
import shutil
import tempfile
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from tests.runtime.test_fly import config_with

ENDPOINT = "tcp/127.0.0.1:7563"
UNPROTECTED = range(9, 33)
"""Bytes of a chunk record no CRC covers (its message times and uncompressed size, after the 9-byte record
header): damage there may leave the chunk readable, so the tests never put it there."""


@functools.cache
def flight_log() -> Path:
    """The log of a real simulated flight through ``fly`` (made once, removed at exit)."""
    from groundstation.runtime.fly import fly

    tmp = Path(tempfile.mkdtemp(prefix="gs-log-damage-"))
    atexit.register(shutil.rmtree, tmp, True)
    cfg = config_with(tmp, endpoint=ENDPOINT, **{'kind = "figure8"': 'kind = "hover"'})
    log = tmp / "flight.mcap"
    res = fly(cfg, duration=2.5, log_path=log)  # 5 s in all: damage spread over it leaves >10 damaged stretches
    assert res.phase == "done", res.reason
    return log


@dataclass(frozen=True)
class ChunkContents:
    start: int
    end: int
    """Byte range of the chunk record."""
    topics: Counter
    """Messages per topic."""
    periods: int
    """``/control`` records with a state (what replay analyses)."""
    defines: frozenset[str]
    """Topics whose channel record is in this chunk."""


@functools.cache
def chunks_of(path: Path) -> tuple[ChunkContents, ...]:
    """Every chunk of an intact log, from its chunk index, in file order."""
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
        topic = {c.id: c.topic for c in summary.channels.values()}
        out = []
        for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            fh.seek(index.chunk_start_offset)
            chunk = next(StreamReader(fh, skip_magic=True, emit_chunks=True).records)
            records = breakup_chunk(chunk, validate_crc=True)
            messages = [r for r in records if isinstance(r, Message)]
            out.append(ChunkContents(
                index.chunk_start_offset, index.chunk_start_offset + index.chunk_length,
                Counter(topic[m.channel_id] for m in messages),
                sum(topic[m.channel_id] == "/control" and "state" in json.loads(m.data) for m in messages),
                frozenset(r.topic for r in records if isinstance(r, Channel))))
    return tuple(out)


def total_messages(path: Path) -> int:
    with open(path, "rb") as fh:
        return make_reader(fh).get_summary().statistics.message_count


@dataclass(frozen=True)
class Expected:
    chunks: int
    """Chunks that survive."""
    messages: int
    """Messages that must be read back."""
    periods: int
    orphans: int
    """Messages of surviving chunks whose channel record is lost."""


def expected(path: Path, damaged: list[int] = (), cut: int | None = None, summary_intact: bool = True,
             mask: int = 0xFF) -> Expected:
    """What survives XORing the bytes at ``damaged`` with ``mask`` and cutting the file at ``cut``."""
    chunks = chunks_of(path)
    for offset in damaged:
        assert not any(offset - c.start in UNPROTECTED for c in chunks), f"byte {offset} is not covered by a CRC"
    alive = [c for c in chunks if _reads_intact(path, c, damaged, mask) and (cut is None or c.end <= cut)]
    known = {t for c in chunks for t in c.topics} if summary_intact else {t for c in alive for t in c.defines}
    messages = sum(n for c in alive for t, n in c.topics.items() if t in known)
    orphans = sum(n for c in alive for t, n in c.topics.items() if t not in known)
    periods = sum(c.periods for c in alive) if "/control" in known else 0
    return Expected(len(alive), messages, periods, orphans)


def _reads_intact(path: Path, chunk: ChunkContents, damaged: list[int], mask: int) -> bool:
    """Whether ``chunk`` with its bytes at ``damaged`` flipped still reads, CRC checked, as exactly the original's
    records with the ``mcap`` package's own reader. Almost every flip breaks the chunk, but not all: a flip in a
    part of the zstd frame header that the decoder does not need leaves the data, and its CRC, as they were (seen
    in 1 of 64 spread flips, 2026-12-02)."""
    hits = [o - chunk.start for o in damaged if chunk.start <= o < chunk.end]
    if not hits:
        return True
    data = bytearray(path.read_bytes()[chunk.start:chunk.end])
    for o in hits:
        data[o] ^= mask
    try:
        original = _chunk_records(bytes(path.read_bytes()[chunk.start:chunk.end]))
        return _chunk_records(bytes(data)) == original
    except Exception:  # any failure of the reader (CRC, zstd, lengths) means the chunk is lost
        return False


def _chunk_records(data: bytes) -> list:
    chunk = next(StreamReader(io.BytesIO(data), skip_magic=True, emit_chunks=True).records)
    return breakup_chunk(chunk, validate_crc=True)


def flipped(src: Path, dst: Path, offsets: list[int], mask: int = 0xFF) -> Path:
    """A copy of ``src`` with the bytes at ``offsets`` XORed with ``mask``."""
    data = bytearray(src.read_bytes())
    for o in offsets:
        data[o] ^= mask
    dst.write_bytes(bytes(data))
    return dst


def spread(path: Path, count: int = 64) -> list[int]:
    """``count`` offsets evenly over the middle 90 % of the file (past the header, the metadata and the first
    chunk, short of the summary), each moved off the few bytes of a chunk header no CRC covers."""
    size = path.stat().st_size
    starts = [c.start for c in chunks_of(path)]
    offsets = []
    for k in range(count):
        o = int(size * (0.05 + 0.9 * k / (count - 1)))
        while any(o - s in UNPROTECTED for s in starts):
            o += 1
        offsets.append(o)
    assert starts[1] <= offsets[0] and offsets[-1] < chunks_of(path)[-1].end  # the first chunk and summary intact
    return offsets


def middle_of(chunk: ChunkContents) -> int:
    return (chunk.start + chunk.end) // 2
