"""Fault-table rows for the flight log on a bad disk: a real flight log (``fly``, simulated) damaged for real (bits
flipped, cut short, its footer or summary broken) and read back through ``groundstation replay`` and
``groundstation log recover``; and output files of the commands on a full disk (``/dev/full``, a tiny tmpfs).

What must survive is worked out independently from the undamaged original, chunk by chunk, with the ``mcap``
package's own reader (:mod:`tests.flightlog.damage`).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader

from tests.disks import full, tiny_disk
from tests.faults.table import Fault, process_fault, rows
from tests.flightlog.damage import Expected, chunks_of, expected, flight_log, flipped, middle_of, spread, total_messages
from tests.replay.test_reader import config_bit_flipped, leading_records, totals

ROOT = Path(__file__).resolve().parents[2]


def _warned(err: str, log: str) -> list[str]:
    """The warning lines of ``err`` about ``log`` (as the command names it); anything else on stderr (a traceback)
    fails the row."""
    lines = err.splitlines()
    assert all(line.startswith(f"groundstation: warning: {log}: ") for line in lines), err
    return lines


def _replayed(cli, log: Path, want: Expected) -> list[str]:
    """``replay --json``: exit 0, every intact control period analysed, the damage said; its warning lines."""
    code, out, err = cli("replay", str(log), "--json")
    assert code == 0, err
    (figures,) = json.loads(out)  # a list, one object per log
    assert figures["periods"] == want.periods and not figures["complete"]
    lines = _warned(err, log.name)
    assert [f"groundstation: warning: {log.name}: {w}" for w in figures["warnings"]] == lines
    return lines


def _recovered(cli, tmp_path: Path, log: Path, want: Expected) -> dict:
    """``log recover``: exit 0, a valid finalized copy holding every intact message, never called complete."""
    out = tmp_path / "recovered.mcap"
    code, stdout, err = cli("log", "recover", str(log), str(out))
    assert code == 0, err
    counts = json.loads(stdout)
    assert counts["messages"] == want.messages and counts["chunks"] == want.chunks
    assert not counts["source_was_complete"]
    assert _warned(err.removesuffix(f"recovered: {out}\n"), str(log))
    with open(out, "rb") as fh:  # every CRC of the copy checks, through to its footer
        assert sum(isinstance(r, Message) for r in StreamReader(fh, validate_crcs=True).records) == want.messages
    return counts


@process_fault("one bit flipped in the middle of a chunk of a flight log",
               "replay: one line naming the chunk's bytes and the messages it held per channel, every other period "
               "analysed, exit 0; log recover: every other message in a valid finalized copy, the chunk and its "
               "messages counted as dropped (CRC), the source not called complete")
def f_log_one_bit_flipped(cli, tmp_path):
    log = flight_log()
    chunk = chunks_of(log)[len(chunks_of(log)) // 2]
    bad = flipped(log, tmp_path / "bit.mcap", [middle_of(chunk)], mask=0x01)
    want = expected(log, [middle_of(chunk)], mask=0x01)
    lines = _replayed(cli, bad, want)
    assert f"bytes {chunk.start}-" in lines[0] and f"{sum(chunk.topics.values())} messages (" in lines[0]
    dropped = _recovered(cli, tmp_path, bad, want)["dropped"]
    assert dropped["chunks"] == 1 and dropped["messages"] == sum(chunk.topics.values())


@process_fault("64 bytes flipped, spread evenly over the middle 90 % of a flight log",
               "replay analyses every period of the intact chunks, exit 0, ten damaged stretches named and a line of "
               "totals; log recover writes every message of the intact chunks and counts the rest by reason")
def f_log_64_bytes_flipped(cli, tmp_path):
    log = flight_log()
    offsets = spread(log)
    bad = flipped(log, tmp_path / "spread.mcap", offsets)
    want = expected(log, offsets)
    lines = _replayed(cli, bad, want)
    assert len(lines) == 11 and "not listed" in lines[-1]
    dropped = _recovered(cli, tmp_path, bad, want)["dropped"]
    assert dropped["messages"] == total_messages(log) - want.messages


@process_fault("a flight log cut short in the middle of a chunk (no summary, no footer)",
               "replay and log recover read every chunk before the cut; the cut chunk named as truncated, messages "
               "unknown; exit 0")
def f_log_truncated(cli, tmp_path):
    log = flight_log()
    cut = middle_of(chunks_of(log)[len(chunks_of(log)) // 3])
    bad = tmp_path / "cut.mcap"
    bad.write_bytes(log.read_bytes()[:cut])
    want = expected(log, cut=cut, summary_intact=False)
    assert "the file ends inside a record" in _replayed(cli, bad, want)[0]
    assert _recovered(cli, tmp_path, bad, want)["dropped"]["by_reason"] == {"truncated": {"chunks": 1,
                                                                                          "messages": None}}


def _zstd_bomb(declared: int, gib: int) -> bytes:
    """A chunk record whose header declares ``declared`` uncompressed bytes (CRC 0: "not computed") and whose zstd
    frame, naming its own size, holds ``gib`` GiB of zeros in a few hundred KiB."""
    import struct

    import zstandard

    z = zstandard.ZstdCompressor(level=1).compressobj(size=gib << 30)
    block = bytes(1 << 24)
    data = b"".join([z.compress(block) for _ in range(gib << 6)] + [z.flush()])
    body = struct.pack("<QQQI", 1, 2, declared, 0) + struct.pack("<I", 4) + b"zstd" + struct.pack("<Q", len(data))
    return struct.pack("<BQ", 6, len(body) + len(data)) + body + data


@process_fault("a chunk that decompresses to 1 GiB of zeros from 1 MiB (its header declaring 1000 bytes) put "
               "before a flight log's second chunk",
               "replay reads no more than the header declares: the chunk named (does not decompress), every period "
               "of the flight analysed, exit 0 (before: mcap decompressed what the zstd frame said, gigabytes, and "
               "walked the zeros as records for minutes)")
def f_log_decompression_bomb(cli, tmp_path):
    log = flight_log()
    second = chunks_of(log)[1].start
    bad = tmp_path / "bomb.mcap"
    data = log.read_bytes()
    bomb = _zstd_bomb(1000, 1)
    bad.write_bytes(data[:second] + bomb + data[second:])
    code, out, err = cli("replay", str(bad), "--json")
    (figures,) = json.loads(out)
    assert code == 0 and figures["periods"] == expected(log).periods and not figures["complete"], err
    assert figures["warnings"][0].startswith(f"bytes {second}-{second + len(bomb)}: does not decompress or parse: "
                                             f"1 chunk"), figures["warnings"]


def _summary_or_footer(cli, tmp_path, where: str) -> None:
    log = flight_log()
    size = log.stat().st_size
    offset = size - 20 if where == "footer" else (chunks_of(log)[-1].end + size) // 2
    bad = flipped(log, tmp_path / f"{where}.mcap", [offset])
    want = expected(log)
    assert "summary section or footer is damaged" in _replayed(cli, bad, want)[0]
    assert _recovered(cli, tmp_path, bad, want)["dropped"] == {"chunks": 0, "messages": 0, "by_reason": {
        "summary": {"chunks": 0, "messages": 0}}}


@process_fault("a byte of a flight log's footer flipped",
               "every message read from the data section; the summary named as damaged and not used; log recover: "
               "nothing dropped, the source not called complete")
def f_log_footer_damaged(cli, tmp_path):
    _summary_or_footer(cli, tmp_path, "footer")


@process_fault("a byte of a flight log's summary section flipped",
               "as for the footer: every message read, the summary named as damaged, nothing dropped")
def f_log_summary_damaged(cli, tmp_path):
    _summary_or_footer(cli, tmp_path, "summary")


def _said(cli, log: Path, want: Expected) -> list[str]:
    """What ``replay`` warned of (:func:`_replayed`), each line without its prefix."""
    return [line.removeprefix(f"groundstation: warning: {log.name}: ") for line in _replayed(cli, log, want)]


def _metadata_names(log: Path) -> set[str]:
    with open(log, "rb") as fh:
        return {m.name for m in make_reader(fh).iter_metadata()}


@process_fault("one bit flipped inside the JSON of a flight log's config metadata (which no CRC of its own covers)",
               "replay: every message read, one line naming the config record as damaged and skipped, --rerun says "
               "it cannot get the gains (--rerun-with gives them), exit 0; log recover: every message copied, the "
               "record dropped and named, the copy replays")
def f_log_config_metadata_bit_flipped(cli, tmp_path):
    """Before: replay refused the whole log ("config: the log's config metadata is not JSON", exit 2) and log
    recover copied the record, so its copy was refused the same way."""
    log = flight_log()
    bad, (start, end) = config_bit_flipped(log, tmp_path / "config.mcap")
    named = [f"bytes {start}-{end}: the config metadata record is damaged (its value is not JSON): skipped",
             totals(log)]
    assert _said(cli, bad, expected(log)) == named
    code, out, err = cli("replay", str(bad), "--rerun", "--json")
    assert code == 0 and "rerun" not in json.loads(out)[0] and err.splitlines()[-1] == (
        f"groundstation: warning: {bad.name}: not re-run: the log has no intact config metadata (its record skipped "
        f"as damaged, or never written): the gains and allocation it flew with are unknown; --rerun-with FLIGHT.toml "
        f"gives them"), err
    with open(log, "rb") as fh:
        flown = next(m.metadata["value"] for m in make_reader(fh).iter_metadata() if m.name == "config_path")
    code, out, err = cli("replay", str(bad), "--rerun-with", flown, "--json")
    assert code == 0 and json.loads(out)[0]["rerun"]["periods"] == expected(log).periods, err
    counts = _recovered(cli, tmp_path, bad, expected(log))
    assert counts["warnings"] == named and counts["dropped"] == {"chunks": 0, "messages": 0, "by_reason": {
        "metadata": {"chunks": 0, "messages": 0}}}
    copy = tmp_path / "recovered.mcap"
    assert _metadata_names(copy) == _metadata_names(log) - {"config"} | {"recovered"}  # what it lost, said
    code, out, err = cli("replay", str(copy), "--json")
    copied = json.loads(out)[0]
    assert code == 0 and copied["periods"] == expected(log).periods and not copied["complete"], err
    assert copied["warnings"] == [f"recovered by `log recover` from {bad}, which lost: {w}" for w in named], err


def _header_damaged(tmp_path: Path, how: str) -> Path:
    log = flight_log()
    start, end = leading_records(log)["header"]
    data = bytearray(log.read_bytes())
    if how == "length":
        data[start + 1:start + 9] = (1 << 62).to_bytes(8, "little")
    else:
        data[start:end] = bytes(end - start)
    bad = tmp_path / f"header_{how}.mcap"
    bad.write_bytes(bytes(data))
    return bad


@process_fault("a flight log's header record with its length field damaged (2^62)",
               "replay: every message read, one line naming the header as damaged, exit 0; log recover: every "
               "message and every metadata record copied")
def f_log_header_length_damaged(cli, tmp_path):
    """Before: replay said "not an MCAP file" (exit 2), though log recover salvaged every message."""
    log = flight_log()
    bad = _header_damaged(tmp_path, "length")
    named = [f"bytes 8-{leading_records(log)['header'][1]}: the header record is damaged (its length field is "
             f"wrong): skipped", totals(log)]
    assert _said(cli, bad, expected(log)) == named
    assert _recovered(cli, tmp_path, bad, expected(log))["warnings"] == named
    assert _metadata_names(tmp_path / "recovered.mcap") == _metadata_names(log) | {"recovered"}


@process_fault("a flight log's header record zeroed (it names the program that wrote the file)",
               "replay: one line saying the file is damaged and that log recover may salvage it, exit 2; log "
               "recover: every message copied, the copy replays")
def f_log_header_zeroed(cli, tmp_path):
    """Before: replay said "not an MCAP file"."""
    bad = _header_damaged(tmp_path, "zeroed")
    code, out, err = cli("replay", str(bad), "--json")
    assert code == 2 and out == "" and err == (
        f"groundstation: error: {bad}: damaged: an MCAP file whose header record (which names the program that "
        f"wrote it) does not read; groundstation log recover may salvage its intact records into a new log\n"), err
    want = expected(flight_log())
    counts = _recovered(cli, tmp_path, bad, want)
    assert counts["messages"] == total_messages(flight_log()) and counts["dropped"]["chunks"] == 0
    code, out, err = cli("replay", str(tmp_path / "recovered.mcap"), "--json")
    assert code == 0 and json.loads(out)[0]["periods"] == want.periods, err


@process_fault("a flight log with every chunk damaged (one bit flipped in each)",
               "replay: one line saying there is no control period because the log is damaged, with the chunks "
               "and messages skipped, exit 2; log recover: nothing to recover, exit 1, no output file")
def f_log_every_chunk_damaged(cli, tmp_path):
    """Before: replay said only "the log has no control period to analyse"."""
    log = flight_log()
    bad = flipped(log, tmp_path / "every.mcap", [middle_of(c) for c in chunks_of(log)], mask=0x01)
    code, out, err = cli("replay", str(bad), "--json")
    chunks, messages = len(chunks_of(log)), total_messages(log)
    assert code == 2 and out == "" and err == (
        f"groundstation: error: {bad}: the log has no control period to analyse (the log is damaged: 1 damaged "
        f"stretch: {chunks} chunks and {messages} messages skipped; 0 messages in 0 intact chunks read)\n"), err
    out_file = tmp_path / "r.mcap"
    code, stdout, err = cli("log", "recover", str(bad), str(out_file))
    counts = json.loads(stdout)
    assert code == 1 and counts["messages"] == 0 and not out_file.exists(), err
    assert counts["dropped"] == {"chunks": chunks, "messages": messages, "by_reason": {
        "crc": {"chunks": chunks, "messages": messages}}}


@process_fault("log recover of a file with no intact message: an MCAP header alone, then garbage",
               "the counts on stdout, one line saying nothing was recovered, exit 1, no output file left behind")
def f_log_recover_nothing(cli, tmp_path):
    bad = tmp_path / "header_only.mcap"
    bad.write_bytes(flight_log().read_bytes()[:8] + bytes(range(256)) * 4)
    out = tmp_path / "r.mcap"
    code, stdout, err = cli("log", "recover", str(bad), str(out))
    assert code == 1 and json.loads(stdout)["messages"] == 0 and not out.exists(), err
    assert err.endswith(f"groundstation: {bad}: no intact message to recover; {out} not written\n"), err


@process_fault("log recover onto a path that exists (a link to /dev/full; a good log alike)",
               "one line naming the output file, exit 2, nothing written there (a log is never overwritten; a full "
               "disk: the next row)")
def f_log_recover_onto_an_existing_path(cli, tmp_path):
    code, out, err = cli("log", "recover", str(flight_log()), str(full(tmp_path / "r.mcap")))
    assert code == 2 and out == "" and err == f"groundstation: error: {tmp_path / 'r.mcap'}: the file exists; a " \
                                              f"log is never overwritten (choose another file)\n", err


@process_fault("log recover onto a 64 KiB tmpfs that fills up part way through the copy",
               "one line naming the output file, exit 2, no traceback")
def f_log_recover_tiny_disk(cli, tmp_path):
    with tiny_disk(tmp_path / "disk") as disk:
        code, out, err = cli("log", "recover", str(flight_log()), str(disk / "r.mcap"))
    assert code == 2 and out == "" and err.endswith("r.mcap: cannot write: No space left on device\n")
    assert err.count("\n") == 1, err


@process_fault("replay --csv and --plot onto a full disk (/dev/full)",
               "one line naming the file, exit 2, no traceback")
def f_replay_outputs_full_disk(cli, tmp_path):
    log = flight_log()
    full(tmp_path / f"{log.stem}_control.csv")
    code, _, err = cli("replay", str(log), "--csv", str(tmp_path))
    assert code == 2 and err.count("\n") == 1 and "_control.csv: cannot write: No space left on device" in err, err
    code, _, err = cli("replay", str(log), "--plot", str(full(tmp_path / "fig9.png")))
    assert code == 2 and err.count("\n") == 1 and "fig9.png: cannot write: No space left on device" in err, err


@process_fault("enumerate --out onto a full disk (/dev/full)",
               "one line naming the file, exit 2, no traceback")
def f_enumerate_out_full_disk(cli, tmp_path):
    code, _, err = cli("enumerate", "4", "--out", str(full(tmp_path / "c.json")))
    assert code == 2 and err == f"groundstation: error: {tmp_path / 'c.json'}: cannot write: No space left on " \
                                f"device\n", err


@process_fault("an output (replay --plot, enumerate --out, optimize --out, simulate --plot) named as a flight log "
               "renamed (a.png, a.json), the input log among them",
               "one line naming it, exit 2, the log as it was (before: `replay a.png --plot a.png` wrote the plot over "
               "the log it read, exit 0)")
def f_outputs_never_written_over_a_log(cli, tmp_path):
    log = flight_log()
    for name, args in (("a.png", lambda p: ("replay", str(p), "--plot", str(p))),
                       ("b.json", lambda p: ("enumerate", "3", "--out", str(p))),
                       ("c.json", lambda p: ("optimize", str(ROOT / "configs/tasks/toy_push_y.toml"), "--topology",
                                             "oS", "--out", str(p))),
                       ("d.png", lambda p: ("simulate", str(ROOT / "configs/assemblies/toy_v2.json"), "--plot",
                                            str(p)))):
        renamed = tmp_path / name
        renamed.write_bytes(log.read_bytes())
        code, out, err = cli(*args(renamed))
        assert code == 2 and err == f"groundstation: error: {renamed}: is a flight log (MCAP); no output is ever " \
                                    f"written over one\n", (name, err)
        assert renamed.read_bytes() == log.read_bytes()


@process_fault("a log whose summary lies, its CRC recomputed: a message count that is not the file's, a footer "
               "starting the summary at a chunk mid-flight, a footer saying there is none; two logs `cat` together",
               "every message read, not complete, named (replay's warnings; log recover: source not complete) "
               "(before: replayed complete with no warning; recover said the source was complete and dropped the "
               "second flight, '0 messages')")
def f_log_summary_that_lies(cli, tmp_path):
    from tests.flightlog.test_salvage import _footer_edited

    log = flight_log()
    data = log.read_bytes()
    cs = chunks_of(log)
    for name, bad, said in (
            ("count", _footer_edited(data, statistics_count=total_messages(log) + 5247), "the summary disagrees"),
            ("start", _footer_edited(data, summary_start=cs[len(cs) // 2].start), "summary section or footer"),
            ("none", _footer_edited(data, summary_start=0, crc_zero=True), "summary section or footer"),
            ("two", data * 2, "a second log appended")):
        path = tmp_path / f"{name}.mcap"
        path.write_bytes(bad)
        code, out, err = cli("replay", str(path), "--json")
        row = json.loads(out)[0]
        assert code == 0 and row["complete"] is False and any(said in w for w in row["warnings"]), (name, row)
        code, out, err = cli("log", "recover", str(path), str(tmp_path / f"{name}-r.mcap"))
        assert code == 0 and json.loads(out)["source_was_complete"] is False, (name, out, err)
        assert json.loads(out)["messages"] == total_messages(log), (name, out)


@pytest.mark.parametrize("row", rows(__name__), ids=[f.id for f in rows(__name__)])
def test_fault(row: Fault, cli, tmp_path):
    row.run(cli, tmp_path)
