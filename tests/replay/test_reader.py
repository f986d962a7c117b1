"""Replaying a damaged flight log: every control period of the intact chunks is analysed (counted independently,
chunk by chunk, from the undamaged original), and what was skipped is said; a log of the records' older shape
replays as it did."""

from __future__ import annotations

import csv

from groundstation.replay.analysis import analyse
from groundstation.replay.export import export_csv
from groundstation.replay.reader import upgraded
from tests.flightlog.damage import chunks_of, expected, flight_log, flipped, middle_of, spread
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
