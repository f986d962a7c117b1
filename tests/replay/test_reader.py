"""Replaying a damaged flight log: every control period of the intact chunks is analysed (counted independently,
chunk by chunk, from the undamaged original), and what was skipped is said; a log of the records' older shape
replays as it did; a file that is no log is one line saying what it is."""

from __future__ import annotations

import csv
import io
import json
import os
import struct
from pathlib import Path

import pytest
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Metadata

from groundstation.control.geometric import Gains
from groundstation.errors import ConfigError
from groundstation.flightlog.mcap_log import recover
from groundstation.replay.analysis import analyse
from groundstation.replay.export import export_csv
from groundstation.replay.reader import open_log, upgraded
from tests.flightlog.damage import chunks_of, expected, flight_log, flipped, middle_of, spread, total_messages
from tests.replay.test_analysis import copy_log


def test_an_intact_log_has_no_warnings():
    r = analyse(flight_log())
    assert r.complete and r.warnings == () and r.metrics.periods == expected(flight_log()).periods


def test_a_flipped_bit_loses_the_periods_of_one_chunk(tmp_path):
    log = flight_log()
    at = middle_of(chunks_of(log)[len(chunks_of(log)) // 2])
    r = analyse(flipped(log, tmp_path / "bit.mcap", [at], mask=0x01))
    whole = analyse(log)
    assert r.metrics.periods == expected(log, [at], mask=0x01).periods < whole.metrics.periods
    assert [p for _, p in r.timeline] == [p for _, p in whole.timeline] and r.metrics.phase == "done"
    assert not r.complete and len(r.warnings) == 2 and "1 chunk" in r.warnings[0]


def test_64_flipped_bytes_and_the_csv_of_what_is_left(tmp_path):
    log = flight_log()
    offsets = spread(log)
    bad = flipped(log, tmp_path / "spread.mcap", offsets)
    want = expected(log, offsets)
    r = analyse(bad)
    assert r.metrics.periods == want.periods > 0 and not r.complete
    control, _, _ = export_csv(bad, tmp_path)
    with open(control) as fh:
        assert sum(1 for _ in csv.reader(fh)) == want.periods + 1  # a header and one row per intact period


def test_a_log_cut_inside_a_chunk(tmp_path):
    log = flight_log()
    cut = middle_of(chunks_of(log)[60])
    path = tmp_path / "cut.mcap"
    path.write_bytes(log.read_bytes()[:cut])
    r = analyse(path)
    assert r.metrics.periods == expected(log, cut=cut, summary_intact=False).periods
    assert "the file ends inside a record" in r.warnings[0] and not r.complete


_OLD_NAMES = {"position_m": "position", "velocity_mps": "velocity", "acceleration_mps2": "acceleration",
              "omega_radps": "omega", "force_n": "force", "torque_nm": "torque"}


def _old_shape(topic: str, d: dict) -> dict:
    """A record as the writer wrote it before fields named their units and per-module values became per-module
    objects (flat ``/control.motors[i][q]``, ``/backend/telemetry.motors[4 i + q]``)."""
    if topic == "/control":
        out = {("t" if k == "t_s" else k): v for k, v in d.items()
               if k not in ("modules", "position_error_m", "command_max_frac_umax", "command_min_frac_umax")}
        for part in ("state", "truth", "setpoint", "wrench"):
            if part in d:
                out[part] = {_OLD_NAMES.get(k, k): v for k, v in d[part].items()}
        out["motors"] = [m["command_frac_umax"] for m in d["modules"]]
        if "applied_frac_umax" in d["modules"][0]:
            out["applied"] = [m["applied_frac_umax"] for m in d["modules"]]
        return out
    if topic == "/backend/telemetry":
        return {"t": d["t_s"], "link_ok": d["link_ok"], "battery_v": [], "link_latency_s": [], "link_loss": [],
                "motors": [x for m in d["modules"] for x in m["rotor_speed_sq_rad2_s2"]], "gyro": d["gyro_radps"]}
    return d


def test_a_log_of_the_old_shape_replays_the_same(tmp_path):
    """Logs written before the per-module records (the nested arrays Foxglove refused) replay as they did: the
    reader reads their records in today's shape."""
    log = flight_log()
    old = tmp_path / "old.mcap"
    copy_log(log, old, record=_old_shape)
    then, now = analyse(old, rerun=True), analyse(log, rerun=True)
    assert (then.metrics, then.rerun, then.timeline, then.events) == (now.metrics, now.rerun, now.timeline, now.events)
    assert [p.read_text() for p in export_csv(old, tmp_path)] == [p.read_text() for p in export_csv(log, tmp_path)]


def test_an_old_telemetry_record_in_todays_shape():
    d = {"t": 2.0, "link_ok": True, "motors": list(range(8)), "battery_v": [3.9, 4.0],
         "link_latency_s": [float("nan"), 0.004], "link_loss": [None, 0.0], "gyro": []}
    assert upgraded("/backend/telemetry", d) == {"t_s": 2.0, "link_ok": True, "modules": [
        {"rotor_speed_sq_rad2_s2": [0, 1, 2, 3], "battery_v": 3.9},
        {"rotor_speed_sq_rad2_s2": [4, 5, 6, 7], "battery_v": 4.0, "link_latency_s": 0.004, "link_loss_frac": 0.0}]}
    assert upgraded("/mocap/stats", {"received": 1}) == {"received": 1}


# -- damage outside the chunks, which no chunk CRC covers -----------------------------------------------------------
def leading_records(path: Path) -> dict[str, tuple[int, int]]:
    """The byte ranges [start, end) of the records before a log's first chunk, read with the ``mcap`` package's
    record reader: ``header``, then each metadata record by its name (``config``, ``config_path``, ...)."""
    data = path.read_bytes()
    out, pos = {}, 8
    while data[pos] != Opcode.CHUNK:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        body = data[pos + 9:pos + 9 + length]
        name = "header" if opcode == Opcode.HEADER else Metadata.read(ReadDataStream(io.BytesIO(body))).name
        out[name] = (pos, pos + 9 + length)
        pos += 9 + length
    assert pos == chunks_of(path)[0].start
    return out


def config_bit_flipped(log: Path, dst: Path) -> tuple[Path, tuple[int, int]]:
    """A copy of ``log`` with one bit of its config metadata's JSON flipped (the quote that opens ``"rate_hz"``
    becomes a control character: still UTF-8, no longer JSON), and that record's byte range."""
    start, end = leading_records(log)["config"]
    at = log.read_bytes().index(b'"rate_hz"', start)
    assert at < end
    return flipped(log, dst, [at], mask=0x20), (start, end)


def totals(log: Path, chunks: int | None = None, messages: int = 0, stretches: int = 1) -> str:
    """The line of totals of a log of which ``messages`` and every chunk but ``chunks`` were skipped."""
    read = total_messages(log) - messages
    kept = len(chunks_of(log)) - (chunks or 0)
    return (f"{stretches} damaged stretch{'es' * (stretches != 1)}: {chunks or 0} chunk{'s' * ((chunks or 0) != 1)} "
            f"and {messages} message{'s' * (messages != 1)} skipped; {read} messages in {kept} intact chunks read")


def test_a_flipped_bit_in_the_config_metadata_costs_the_config_alone(tmp_path):
    """One bit flipped in the config metadata's JSON (no CRC covers that record alone): the record is skipped and
    named, every message read; the config is empty, the other metadata intact; a re-run says it cannot get the
    gains, unless they are given. Before: "config: the log's config metadata is not JSON", exit 2, nothing read."""
    log = flight_log()
    bad, (start, end) = config_bit_flipped(log, tmp_path / "config.mcap")
    whole = analyse(log)
    r = analyse(bad, rerun=True)
    assert r.metrics == whole.metrics and r.timeline == whole.timeline and r.events == whole.events
    assert r.metrics.periods == expected(log).periods and not r.complete
    assert r.warnings == (f"bytes {start}-{end}: the config metadata record is damaged (its value is not JSON): "
                          f"skipped", totals(log),
                          "not re-run: the log has no intact config metadata (its record skipped as damaged, or "
                          "never written): the gains and allocation it flew with are unknown; --rerun-with "
                          "FLIGHT.toml gives them")
    assert r.rerun is None and r.metadata["config"] == {}
    assert {k: v for k, v in r.metadata.items() if k != "config"} == {k: v for k, v in whole.metadata.items()
                                                                      if k != "config"}
    gains = Gains(**whole.metadata["config"]["gains"])
    again = analyse(bad, rerun=True, gains=gains, allocation=whole.metadata["config"]["allocation"])
    assert again.rerun == analyse(log, rerun=True).rerun and again.rerun.periods == whole.metrics.periods
    assert again.warnings == r.warnings[:2]


def test_a_recovered_log_says_what_its_source_lost(tmp_path):
    """``log recover``'s copy of the log above is whole by its own bytes; its replay still names what the source lost
    (the config record), and is not complete. Before: "complete", no warning (only recover's output had said it).
    A copy of an intact log (and a copy of that copy) replays complete, with no warning."""
    log = flight_log()
    bad, (start, end) = config_bit_flipped(log, tmp_path / "config.mcap")
    copy = tmp_path / "recovered.mcap"
    recover(bad, copy)
    r = analyse(copy)
    lost = (f"bytes {start}-{end}: the config metadata record is damaged (its value is not JSON): skipped",
            totals(log))
    assert not r.complete and r.warnings == tuple(f"recovered by `log recover` from {bad}, which lost: {w}"
                                                  for w in lost)
    assert r.metrics == analyse(log).metrics and r.metadata["config"] == {}
    recover(copy, tmp_path / "again.mcap")  # the copy's copy: the first recovery's word is kept
    assert analyse(tmp_path / "again.mcap").warnings == r.warnings
    recover(log, tmp_path / "whole.mcap")
    recover(tmp_path / "whole.mcap", tmp_path / "whole2.mcap")
    for whole in ("whole.mcap", "whole2.mcap"):
        w = analyse(tmp_path / whole)
        assert w.complete and w.warnings == () and w.metrics == analyse(log).metrics


def test_a_metadata_record_that_does_not_parse_is_skipped_alone(tmp_path):
    """A byte of the config's value that is not UTF-8: the record does not parse, its length still holds and a
    sound record follows it, so only it is skipped; before, reading resumed at the first chunk and every metadata
    record after it (the assembly, the code version) was lost with it."""
    log = flight_log()
    start, end = leading_records(log)["config"]
    bad = flipped(log, tmp_path / "utf8.mcap", [log.read_bytes().index(b'{"', start + 9)])  # '{' -> 0x84
    r = analyse(bad)
    assert r.warnings == (f"bytes {start}-{end}: the config metadata record is damaged (it does not parse): skipped",
                          totals(log))
    assert r.metrics.periods == expected(log).periods and r.metadata["assembly"] == analyse(log).metadata["assembly"]


def test_a_damaged_header_length_is_read_past(tmp_path):
    """The header record's length field damaged (2^62): its content (which names the writer) still reads and a
    metadata record follows where it ends, so the log replays whole with the header named. Before: "not an MCAP
    file", exit 2, though ``log recover`` salvaged every message."""
    log = flight_log()
    start, end = leading_records(log)["header"]
    data = bytearray(log.read_bytes())
    struct.pack_into("<Q", data, start + 1, 1 << 62)
    bad = tmp_path / "header.mcap"
    bad.write_bytes(bytes(data))
    r = analyse(bad)
    assert r.warnings == (f"bytes {start}-{end}: the header record is damaged (its length field is wrong): skipped",
                          totals(log))
    assert r.metrics == analyse(log).metrics and r.metadata == analyse(log).metadata and not r.complete


def test_a_header_that_does_not_read_is_damage_that_log_recover_may_salvage(tmp_path):
    log = flight_log()
    start, end = leading_records(log)["header"]
    data = bytearray(log.read_bytes())
    data[start:end] = bytes(end - start)
    bad = tmp_path / "header.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(ConfigError) as refused:
        open_log(bad)
    assert str(refused.value) == (f"{bad}: damaged: an MCAP file whose header record (which names the program that "
                                  f"wrote it) does not read; groundstation log recover may salvage its intact "
                                  f"records into a new log")


def test_a_log_with_every_chunk_damaged_says_so(tmp_path):
    """Nothing left to analyse: the error says it is for damage, and how much was skipped. Before: only "the log
    has no control period to analyse"."""
    log = flight_log()
    bad = flipped(log, tmp_path / "every.mcap", [middle_of(c) for c in chunks_of(log)], mask=0x01)
    assert expected(log, [middle_of(c) for c in chunks_of(log)], mask=0x01).chunks == 0
    with pytest.raises(ConfigError) as refused:
        analyse(bad)
    assert str(refused.value) == (f"{bad}: the log has no control period to analyse (the log is damaged: "
                                  f"{totals(log, len(chunks_of(log)), total_messages(log))})")


@pytest.mark.parametrize("path, what", [
    ("/dev/zero", "not a regular file (a character device), not an MCAP flight log"),
    ("/dev/null", "not a regular file (a character device), not an MCAP flight log"),
    ("fifo", "not a regular file (a FIFO), not an MCAP flight log"),
    ("empty.mcap", "empty file, not an MCAP flight log"),
    ("notes.mcap", "not an MCAP file"),
    ("none.mcap", "file not found")])
def test_a_file_that_is_no_log_says_what_it_is(tmp_path, path, what):
    """Never opened unless a regular file (a FIFO would block, /dev/zero never end). Before: "file not found" for
    /dev/zero and /dev/null."""
    p = Path(path) if path.startswith("/") else tmp_path / path
    if path == "fifo":
        os.mkfifo(p)
    elif path in ("empty.mcap", "notes.mcap"):
        p.write_text("" if path == "empty.mcap" else json.dumps({"not": "a log"}))
    with pytest.raises(ConfigError) as refused:
        open_log(p)
    assert str(refused.value) == f"{p}: {what}"
