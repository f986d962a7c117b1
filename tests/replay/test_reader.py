"""Replaying a damaged flight log: every control period of the intact chunks is analysed (counted independently,
chunk by chunk, from the undamaged original), and what was skipped is said."""

from __future__ import annotations

import csv

from groundstation.replay.analysis import analyse
from groundstation.replay.export import export_csv
from tests.flightlog.damage import chunks_of, expected, flight_log, flipped, middle_of, spread


def test_an_intact_log_has_no_warnings():
    r = analyse(flight_log())
    assert r.complete and r.warnings == () and r.metrics.periods == expected(flight_log()).periods


def test_a_flipped_bit_loses_the_periods_of_one_chunk(tmp_path):
    log = flight_log()
    at = middle_of(chunks_of(log)[len(chunks_of(log)) // 2])
    r = analyse(flipped(log, tmp_path / "bit.mcap", [at], mask=0x01))
    whole = analyse(log)
    assert r.metrics.periods == expected(log, [at]).periods < whole.metrics.periods
    assert [p for _, p in r.timeline] == [p for _, p in whole.timeline] and r.metrics.phase == "done"
    assert not r.complete and len(r.warnings) == 2 and "1 chunk" in r.warnings[0]


def test_64_flipped_bytes_and_the_csv_of_what_is_left(tmp_path):
    log = flight_log()
    offsets = spread(log)
    bad = flipped(log, tmp_path / "spread.mcap", offsets)
    want = expected(log, offsets)
    r = analyse(bad)
    assert r.metrics.periods == want.periods > 0 and not r.complete
    control, _ = export_csv(bad, tmp_path)
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
