"""Reading and recovering a real flight log after real damage to its bytes: every intact chunk is read, exactly
what the undamaged original held in them (worked out chunk by chunk with the ``mcap`` package's own reader), and
each damaged stretch is named with its bytes, its chunks and the messages lost."""

from __future__ import annotations

import json
from collections import Counter

import pytest
from mcap.reader import make_reader
from mcap.records import DataEnd, Message
from mcap.stream_reader import StreamReader

from groundstation.errors import ConfigError, UsageError
from groundstation.flightlog.mcap_log import recover
from groundstation.flightlog.salvage import LogScan
from tests.flightlog.damage import chunks_of, expected, flight_log, flipped, middle_of, spread, total_messages


def scan(path) -> tuple[LogScan, Counter]:
    """The scan after a full pass, and the messages it handed out per channel id."""
    s = LogScan(path)
    read = Counter(r.channel_id for r in s.records() if isinstance(r, Message))
    return s, read


def test_an_intact_log_reads_whole_with_its_data_section_crc():
    log = flight_log()
    s, read = scan(log)
    assert s.complete and s.damage == [] and s.warnings() == []
    assert sum(read.values()) == s.messages == total_messages(log) and s.chunks == len(chunks_of(log))
    with open(log, "rb") as fh:  # the writer sets the data section's CRC (the mcap writer leaves it 0 by default)
        data_end = [r for r in StreamReader(fh, validate_crcs=True).records if isinstance(r, DataEnd)]
    assert data_end[0].data_section_crc != 0


def test_one_flipped_bit_costs_its_chunk_only(tmp_path):
    log = flight_log()
    chunk = chunks_of(log)[len(chunks_of(log)) // 2]
    bad = flipped(log, tmp_path / "bit.mcap", [middle_of(chunk)], mask=0x10)
    s, _ = scan(bad)
    want = expected(log, [middle_of(chunk)], mask=0x10)
    assert (s.messages, s.chunks) == (want.messages, want.chunks) == (total_messages(log) - sum(chunk.topics.values()),
                                                                      len(chunks_of(log)) - 1)
    [d] = s.damage
    assert d.reason in ("crc", "corrupt") and d.span[0] == chunk.start and d.chunks == 1
    assert d.lost == dict(chunk.topics)  # from the message index after the chunk
    assert s.messages_lost == sum(chunk.topics.values()) and not s.complete
    assert f"bytes {chunk.start}-" in s.warnings()[0] and "/control: " in s.warnings()[0]


def test_64_flipped_bytes_spread_over_the_file(tmp_path):
    log = flight_log()
    offsets = spread(log)
    s, _ = scan(flipped(log, tmp_path / "spread.mcap", offsets))
    want = expected(log, offsets)
    assert 0 < want.chunks < len(chunks_of(log)) - 30  # many chunks lost, many intact
    assert (s.messages, s.chunks) == (want.messages, want.chunks)
    assert s.messages_lost == total_messages(log) - want.messages
    dropped = s.dropped()
    # A flipped byte in a record outside the chunks (a message index) costs that record alone ("record")
    assert dropped["chunks"] <= len(chunks_of(log)) - want.chunks and set(dropped["by_reason"]) <= {"crc", "corrupt",
                                                                                                   "unreadable",
                                                                                                   "record"}
    assert len(s.warnings()) == 11 and "not listed" in s.warnings()[-1]  # 10 stretches named, then the totals


def test_a_damaged_record_header_is_resynchronised_past(tmp_path):
    """The opcode of one chunk and the length of another are damaged: their lengths cannot be trusted, the scan
    finds the next intact chunk by its opcode and CRC."""
    log = flight_log()
    chunks = chunks_of(log)
    offsets = [chunks[40].start, chunks[60].start + 3]
    s, _ = scan(flipped(log, tmp_path / "headers.mcap", offsets, mask=0x01))
    want = expected(log, offsets, mask=0x01)
    assert (s.messages, s.chunks) == (want.messages, want.chunks) and want.chunks == len(chunks) - 2
    assert [d.span[0] for d in s.damage] == [chunks[40].start, chunks[60].start]
    assert [d.span[1] for d in s.damage] == [chunks[41].start, chunks[61].start]
    assert s.messages_lost == sum(chunks[40].topics.values()) + sum(chunks[60].topics.values())  # the summary's count


def test_a_log_cut_inside_a_chunk_and_one_cut_between_chunks(tmp_path):
    log = flight_log()
    chunks = chunks_of(log)
    k = len(chunks) // 2
    assert k > 10  # a flight's worth of chunks
    cut = middle_of(chunks[k])
    path = tmp_path / "cut.mcap"
    path.write_bytes(log.read_bytes()[:cut])
    s, _ = scan(path)
    want = expected(log, cut=cut, summary_intact=False)
    assert (s.messages, s.chunks) == (want.messages, want.chunks) and want.chunks == k
    [d] = s.damage
    assert d.reason == "truncated" and d.span == (chunks[k].start, cut) and d.chunks == 1 and d.lost is None
    assert s.messages_lost is None and not s.complete
    path.write_bytes(log.read_bytes()[:chunks[k].start])  # the writer killed between chunks: nothing damaged
    s, _ = scan(path)
    assert s.messages == want.messages and s.damage == [] and not s.complete


@pytest.mark.parametrize("where", ["footer", "summary"])
def test_a_damaged_footer_or_summary_loses_nothing(tmp_path, where):
    log = flight_log()
    size = log.stat().st_size
    offset = size - 20 if where == "footer" else (chunks_of(log)[-1].end + size) // 2
    s, _ = scan(flipped(log, tmp_path / f"{where}.mcap", [offset]))
    assert s.messages == total_messages(log) and s.chunks == len(chunks_of(log))
    [d] = s.damage
    assert d.reason == "summary" and d.span[1] == size and d.messages == 0 and not s.complete


def test_the_first_chunk_and_the_summary_damaged(tmp_path):
    """The channels defined in the first chunk are gone with it and with the summary: their later messages cannot
    be told apart, and are counted as dropped for want of a channel."""
    log = flight_log()
    first = chunks_of(log)[0]
    offsets = [middle_of(first), log.stat().st_size - 20]
    s, _ = scan(flipped(log, tmp_path / "first.mcap", offsets))
    want = expected(log, offsets, summary_intact=False)
    assert want.orphans > 0 and (s.messages, s.chunks) == (want.messages, want.chunks)
    assert [d.reason for d in s.damage][-1] == "no channel" and s.damage[-1].messages == want.orphans


def test_damage_outside_the_chunks_is_found_by_the_data_section_crc(tmp_path):
    log = flight_log()
    at = log.read_bytes().index(b"code_version") + 2  # in the metadata, which no chunk CRC covers
    s, _ = scan(flipped(log, tmp_path / "meta.mcap", [at], mask=0x01))
    assert s.messages == total_messages(log)
    [d] = s.damage
    assert d.reason == "data crc" and d.messages == 0 and "metadata" in d.describe()


def test_recover_writes_every_intact_message_to_a_valid_finalized_file(tmp_path):
    log = flight_log()
    offsets = spread(log)
    out = tmp_path / "recovered.mcap"
    counts = recover(flipped(log, tmp_path / "spread.mcap", offsets), out)
    want = expected(log, offsets)
    assert counts["messages"] == want.messages and counts["chunks"] == want.chunks
    assert not counts["source_was_complete"] and counts["dropped"]["messages"] == total_messages(log) - want.messages
    with open(out, "rb") as fh:  # every CRC of the copy checks, and a seeking reader finds its summary
        assert sum(isinstance(r, Message) for r in StreamReader(fh, validate_crcs=True).records) == want.messages
    with open(out, "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_summary().statistics.message_count == want.messages
        assert {m.name for m in reader.iter_metadata()} >= {"config", "code_version", "assembly"}
    again = recover(out, tmp_path / "again.mcap")
    assert again["source_was_complete"] and again["messages"] == want.messages and again["warnings"] == []
    assert json.dumps(counts)  # the command prints it


def test_recover_never_overwrites_its_source_or_another_file_and_a_foreign_file_is_named(tmp_path):
    log = tmp_path / "log.mcap"
    log.write_bytes(flight_log().read_bytes())
    with pytest.raises(UsageError, match="is the log to recover"):
        recover(log, log)
    assert log.read_bytes() == flight_log().read_bytes()
    text = tmp_path / "notes.mcap"
    text.write_text("not a log")
    with pytest.raises(ConfigError, match="notes.mcap: not an MCAP file"):
        recover(text, tmp_path / "out.mcap")
    good = tmp_path / "good.mcap"  # another log, where the recovered copy was asked to go
    good.write_bytes(flight_log().read_bytes())
    with pytest.raises(UsageError, match="good.mcap: the file exists; a log is never overwritten"):
        recover(log, good)
    assert good.read_bytes() == flight_log().read_bytes()


def test_a_zeroed_stretch_counts_every_chunk_the_summary_lists_there(tmp_path):
    """64 kB zeroed over five chunks: the stretch is one, and it counts the five (it said one: only the first
    could be walked; hostile campaign 30)."""
    log = flight_log()
    cs = chunks_of(log)
    k = len(cs) // 2
    start, end = middle_of(cs[k]), middle_of(cs[k + 4])
    data = bytearray(log.read_bytes())
    data[start:end] = bytes(end - start)
    bad = tmp_path / "zeroed.mcap"
    bad.write_bytes(bytes(data))
    s, _ = scan(bad)
    [d] = s.damage
    assert d.span == (cs[k].start, cs[k + 5].start) and d.chunks == 5 and s.chunks == len(cs) - 5
    assert s.messages == total_messages(log) - sum(sum(c.topics.values()) for c in cs[k:k + 5])


def test_a_repeated_chunk_is_read_once(tmp_path):
    """A copy of a chunk put after it (the file's offsets shift: the summary no longer fits): read once, named
    (it was read twice: its periods and events counted twice)."""
    log = flight_log()
    cs = chunks_of(log)
    c, after = cs[len(cs) // 2], cs[len(cs) // 2 + 1]
    data = log.read_bytes()
    bad = tmp_path / "repeated.mcap"
    bad.write_bytes(data[:after.start] + data[c.start:c.end] + data[after.start:])
    s, read = scan(bad)
    assert s.messages == sum(read.values()) == total_messages(log) and not s.complete
    copies = [d for d in s.damage if d.reason == "copy"]
    assert [(d.span, d.chunks) for d in copies] == [((after.start, after.start + c.end - c.start), 1)]


def test_two_chunks_that_traded_places_are_read_and_named(tmp_path):
    """Both chunks are this flight's (the summary lists them, elsewhere): every message read, the file named
    damaged."""
    log = flight_log()
    cs = chunks_of(log)
    a, b = cs[len(cs) // 2], cs[len(cs) // 2 + 1]
    data = log.read_bytes()
    between = data[a.end:b.start]  # a's message indexes
    bad = tmp_path / "traded.mcap"
    bad.write_bytes(data[:a.start] + data[b.start:b.end] + between + data[a.start:a.end] + data[b.end:])
    s, read = scan(bad)
    assert s.messages == sum(read.values()) == total_messages(log) and not s.complete
    assert [d.reason for d in s.damage] == ["moved", "moved"] and s.dropped()["chunks"] == 0


def _written(path, t0: int) -> None:
    """An MCAP file of 200 alike messages from ``t0`` (ns), uncompressed: two such files have their chunks at the
    same offsets, of the same lengths."""
    from mcap.writer import CompressionType, Writer

    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=2000, compression=CompressionType.NONE)
        w.start()
        schema = w.register_schema("x", "jsonschema", b"{}")
        channel = w.register_channel("/x", "json", schema)
        for i in range(200):
            w.add_message(channel, log_time=t0 + i * 10**6, data=b'{"i": %03d}' % i, publish_time=t0 + i * 10**6)
        w.finish()


def test_a_chunk_of_another_file_in_its_place_is_not_this_files(tmp_path):
    """A sound chunk (its CRC matches) of another recording, spliced in where one of this file's was: not read as
    this one's (it was, "0 chunks skipped"), its place's messages counted lost."""
    ours, theirs = tmp_path / "ours.mcap", tmp_path / "theirs.mcap"
    _written(ours, 10**18)
    _written(theirs, 2 * 10**18)
    with open(ours, "rb") as fh:
        index = sorted(make_reader(fh).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    third = index[2]
    span = slice(third.chunk_start_offset, third.chunk_start_offset + third.chunk_length)
    data = bytearray(ours.read_bytes())
    data[span] = theirs.read_bytes()[span]
    spliced = tmp_path / "spliced.mcap"
    spliced.write_bytes(bytes(data))
    s, read = scan(spliced)
    [d] = s.damage
    assert d.reason == "not listed" and d.span == (span.start, span.stop) and d.chunks == 1
    with open(ours, "rb") as fh:  # the messages the third chunk held, by their times
        held = sum(third.message_start_time <= m.log_time <= third.message_end_time
                   for _, _, m in make_reader(fh).iter_messages())
    assert 0 < held < 200 and s.messages == sum(read.values()) == 200 - held and s.messages_lost == held
    assert not s.complete


def _footer_edited(data: bytes, summary_start: int | None = None, statistics_count: int | None = None,
                   crc_zero: bool = False) -> bytes:
    """``data`` with its footer pointing at ``summary_start`` and/or its Statistics counting ``statistics_count``
    messages, the summary's CRC recomputed as an editor would (or zeroed): every CRC checks."""
    import struct
    import zlib

    footer = struct.Struct("<BQQQI")
    footer_at = len(data) - footer.size - 8
    opcode, length, start, offsets, _ = footer.unpack_from(data, footer_at)
    body = bytearray(data[start:footer_at])
    if statistics_count is not None:
        pos = 0
        while pos < len(body):
            op, n = struct.unpack_from("<BQ", body, pos)
            if op == 0x0B:  # Statistics: its message count first
                struct.pack_into("<Q", body, pos + 9, statistics_count)
            pos += 9 + n
    start = start if summary_start is None else summary_start
    head = data[:footer_at] if summary_start is not None else data[:start] + bytes(body)
    summary = head[start:]
    record = struct.pack("<BQQQ", opcode, length, start, 0 if summary_start is not None else offsets)
    crc = 0 if crc_zero else zlib.crc32(record, zlib.crc32(summary))
    return head + record + struct.pack("<I", crc) + data[-8:]


@pytest.mark.parametrize("lie", ["count", "start at a chunk", "no summary"])
def test_a_summary_that_lies_is_never_complete(tmp_path, lie):
    """A summary edited with its CRC recomputed: a message count that is not the file's, a footer that starts the
    summary at a chunk in the middle (the chunks after it went unread, the end of flight called missing), or one
    that says there is none (start 0, CRC 0). Each was read complete, and ``log recover`` called its source
    complete next to the messages it dropped (hostile campaign 34)."""
    log = flight_log()
    data = log.read_bytes()
    cs = chunks_of(log)
    bad = tmp_path / f"{lie}.mcap"
    if lie == "count":
        bad.write_bytes(_footer_edited(data, statistics_count=total_messages(log) + 5247))
    elif lie == "start at a chunk":
        bad.write_bytes(_footer_edited(data, summary_start=cs[len(cs) // 2].start))
    else:
        bad.write_bytes(_footer_edited(data, summary_start=0, crc_zero=True))
    s, read = scan(bad)
    assert not s.complete and s.warnings(), lie
    assert s.messages == sum(read.values()) == total_messages(log)  # every message read all the same
    if lie == "count":
        assert [d.note for d in s.damage] == [f"it counts {total_messages(log) + 5247} messages, "
                                              f"{total_messages(log)} were read"]


def test_chunks_far_out_of_flight_time_order_are_named(tmp_path):
    """Two chunks seconds apart in flight time traded places in a log without its summary (a writer killed): read,
    named (the timeline ran backwards unremarked)."""
    log = flight_log()
    cs = chunks_of(log)
    a, b = cs[10], cs[-10]
    data = log.read_bytes()
    bad = tmp_path / "shuffled.mcap"
    bad.write_bytes(data[:a.start] + data[b.start:b.end] + data[a.end:b.start] + data[a.start:a.end] + data[b.end:])
    s, read = scan(bad)
    assert s.messages == sum(read.values()) == total_messages(log) and not s.complete
    assert "order" in [d.reason for d in s.damage], s.warnings()


def test_a_second_log_appended_is_named_not_dropped_silently(tmp_path):
    """``cat a.mcap b.mcap``: the first flight read, the second named as appended and unread (its messages
    unknown), never "0 messages lost"."""
    log = flight_log()
    bad = tmp_path / "two.mcap"
    bad.write_bytes(log.read_bytes() * 2)
    s, read = scan(bad)
    assert s.messages == sum(read.values()) == total_messages(log) and not s.complete
    appended = [d for d in s.damage if d.reason == "appended"]
    assert len(appended) == 1 and appended[0].span == (log.stat().st_size, 2 * log.stat().st_size)
    assert s.messages_lost is None and "second log appended" in " ".join(s.warnings())
