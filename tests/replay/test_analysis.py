"""Replaying flight logs made by the suite's own flights: the figures match what the flight computed in flight,
recomputed independently where possible; recovered, cut-short and telemetry-less logs replay too."""

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import fields

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from groundstation.errors import ConfigError
from groundstation.flightlog.mcap_log import recover
from groundstation.replay.analysis import analyse
from groundstation.replay.export import export_csv
from groundstation.runtime.fly import fly
from groundstation.runtime.metrics import FlightFigures
from tests.peers import ROOT, peer_process
from tests.runtime.test_fly import config_with, sitl_config

FIGURES = [f.name for f in fields(FlightFigures)]


def same(a, b) -> bool:
    if isinstance(a, tuple):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and math.isnan(a):
        return math.isnan(b)
    return a == pytest.approx(b, rel=1e-9, abs=1e-12)


def test_replay_reproduces_the_flights_own_figures(sim_flight):
    res, log = sim_flight
    r = analyse(log)
    assert r.complete
    for key in FIGURES:
        a, b = getattr(r.metrics, key), getattr(res.metrics, key)
        assert same(a, b), (key, a, b)
    assert r.metrics.phase == "done" and r.metrics.overruns == res.metrics.loop.overruns
    assert [p for _, p in r.timeline] == ["takeoff", "settle", "track", "hold", "landing", "done"]
    flown = [text for _, _, text in res.events]  # the phase changes (and a "loop stalled" on a loaded machine)
    assert [text for _, _, text in r.events if text in flown] == flown and any("->" in text for text in flown)


def test_the_estimators_figures_recomputed_from_the_records(sim_flight):
    """Rejections, the largest position std and the innovations' 95th percentiles, straight from the /control
    records (read here with the mcap reader, not replay's)."""
    _, log = sim_flight
    r = analyse(log)
    with open(log, "rb") as f:
        est = [json.loads(m.data)["estimate"] for _, ch, m in make_reader(f).iter_messages(topics=["/control"])
               if "estimate" in json.loads(m.data)]
    assert len(est) > 1000
    assert r.metrics.estimator_rejected == est[-1]["rejected"]
    assert r.metrics.estimator_late == est[-1]["late"]
    assert r.metrics.position_sigma_max_m == max(e["position_sigma_m"] for e in est) < 0.01  # mocap throughout
    assert r.metrics.height_sigma_max_m == max(e["height_sigma_m"] for e in est) <= r.metrics.position_sigma_max_m
    p95 = np.percentile([np.linalg.norm(e["innovation_position_m"]) * 1e3 for e in est], 95)
    assert r.metrics.innovation_position_p95_mm == pytest.approx(p95) and 0.1 < p95 < 5.0  # 0.5 mm noise
    p95 = np.percentile([np.linalg.norm(e["innovation_attitude_deg"]) for e in est], 95)
    assert r.metrics.innovation_attitude_p95_deg == pytest.approx(p95) and 0.01 < p95 < 1.0  # 0.1 deg noise


def test_position_rmse_recomputed_from_the_csv(sim_flight, tmp_path):
    """An independent computation: numpy over the exported rows, not the metrics code."""
    res, log = sim_flight
    control, _, events = export_csv(log, tmp_path)
    with open(control) as fh:
        rows = [r for r in csv.DictReader(fh) if r["phase"] == "track"]
    p = np.array([[float(r[k]) for k in ("x_m", "y_m", "z_m")] for r in rows])
    ref = np.array([[float(r[k]) for k in ("x_ref_m", "y_ref_m", "z_ref_m")] for r in rows])
    e = np.linalg.norm(p - ref, axis=1)
    assert np.sqrt(np.mean(e**2)) == pytest.approx(res.metrics.pos_rmse_m, rel=1e-9)
    assert e.max() == pytest.approx(res.metrics.max_pos_error_m, rel=1e-9)
    roll_err = np.array([float(r["roll_deg"]) - float(r["roll_target_deg"]) for r in rows])
    assert abs(np.mean([float(r["roll_target_deg"]) for r in rows]) + 5.0) < 1e-9  # the -5 deg target is logged
    assert np.abs(roll_err).max() <= res.metrics.max_roll_error_deg + 1e-9
    with open(events) as fh:
        assert any("settle -> track" in r["text"] for r in csv.DictReader(fh))


def test_every_record_is_on_one_clock(sim_flight):
    _, log = sim_flight
    with open(log, "rb") as fh:
        reader = make_reader(fh)
        control = [(m.log_time * 1e-9, json.loads(m.data)["t_s"]) for _, _, m in reader.iter_messages(["/control"])]
    offsets = np.array([lt - t for lt, t in control])
    assert offsets.max() - offsets.min() < 1e-6  # log time = loop start + flight time, every period
    with open(log, "rb") as fh:
        mocap = [(m.log_time * 1e-9, m.publish_time * 1e-9) for _, _, m in make_reader(fh).iter_messages(
            ["/mocap/assembly"])]
    with open(log, "rb") as fh:
        events = [(m.log_time * 1e-9, m.data) for _, _, m in make_reader(fh).iter_messages(["/log"])]
    arrival_minus_stamp = np.array([a - s for a, s in mocap])
    # A pose is logged when it arrives, after the mocap measured it (5 ms simulated latency, one period of polling).
    assert np.all(arrival_minus_stamp > 0) and np.median(arrival_minus_stamp) < 0.02
    takeoff = [lt for lt, d in events if b"preflight -> takeoff" in d][0]
    assert abs(takeoff - control[0][0]) < 1e-3  # the transition is stamped in the first period, on the same clock


def test_rerun_matches_and_finds_gain_changes(sim_flight, tmp_path):
    _, log = sim_flight
    same_code = analyse(log, rerun=True).rerun
    assert same_code.periods > 1000 and same_code.max_motor_diff < 1e-9
    from groundstation.control.geometric import Gains

    stiffer = analyse(log, rerun=True, gains=Gains(attitude_hz=6.0)).rerun
    assert stiffer.max_motor_diff > 0.01 and stiffer.max_torque_diff_nm > 1e-3


def test_rerun_of_a_log_of_a_design_shipped_before_the_exact_rules(sim_flight, tmp_path):
    """A log is history: one whose assembly is the Fig. 1 design shipped before 2026-12-02 (2e-9 m inside 2 r,
    refused as an assembly file today) reruns on it, its design not judged again (the suite's flight, rewritten:
    that assembly's record and twelve modules' commands); a malformed record is still refused naming the key."""
    _, log = sim_flight
    legacy = json.loads((ROOT / "tests/assembly/data/legacy_paper_fig1_n12.json").read_text())

    def twelve(topic, d):
        if topic == "/control":
            d["modules"] = d["modules"][:1] * legacy["n"]
        return d

    fig1 = tmp_path / "fig1.mcap"
    copy_log(log, fig1, record=twelve, metadata={"assembly": json.dumps(legacy)})
    rerun = analyse(fig1, rerun=True).rerun
    assert rerun.periods > 1000 and math.isfinite(rerun.max_motor_diff)
    del legacy["angles_deg"]
    copy_log(log, fig1, record=twelve, metadata={"assembly": json.dumps(legacy)})
    with pytest.raises(ConfigError) as malformed:
        analyse(fig1, rerun=True)
    assert malformed.value.key == "angles_deg" and str(malformed.value).startswith(f"{fig1}: angles_deg: missing")


def test_window(sim_flight, tmp_path):
    _, log = sim_flight
    r = analyse(log, t_from=5.0, t_to=7.0)
    assert r.series.t.min() >= 5.0 and r.series.t.max() <= 7.0
    control, _, _ = export_csv(log, tmp_path)  # every period of the flight, counted without the window code
    with open(control) as fh:
        inside = sum(5.0 <= float(row["t_s"]) <= 7.0 for row in csv.DictReader(fh))
    # 250 Hz: at most 501 periods in 2 s; fewer when the loop skipped late periods (a loaded machine)
    assert r.metrics.periods == inside and 0 < inside <= 501


def copy_log(src, dst, drop: set[str] = frozenset(), record=None, metadata: dict[str, str] | None = None) -> None:
    """The log minus the channels ``drop`` and without the summary (as if written by an older writer), each JSON
    record through ``record(topic, record)`` when given (bytes it returns are written as they are), and the
    metadata values of ``metadata`` in place of the log's."""
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    with open(src, "rb") as fh, open(dst, "wb") as out:
        w = Writer(out)
        w.start(profile="", library="groundstation")
        schemas, channels = {}, {}
        for rec in StreamReader(fh).records:
            if isinstance(rec, Schema):
                schemas[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and rec.topic not in drop:
                channels[rec.id] = (w.register_channel(rec.topic, rec.message_encoding, schemas[rec.schema_id]),
                                    rec.topic, rec.message_encoding == "json")
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, {"value": metadata[rec.name]} if rec.name in (metadata or {})
                               else dict(rec.metadata))
            elif isinstance(rec, Message) and rec.channel_id in channels:
                cid, topic, is_json = channels[rec.channel_id]
                data = rec.data
                if is_json and record:  # a record hook may also hand back bytes: written as they are
                    data = record(topic, json.loads(rec.data))
                    data = data if isinstance(data, bytes) else json.dumps(data).encode()
                w.add_message(cid, rec.log_time, data, rec.publish_time)
        w.finish()


@pytest.mark.parametrize("key, value, why", [
    ("config", "[" * 100000, "its value is not JSON"),
    ("config", "[1]", "its value is not a JSON object"),
    ("assembly", "[" * 100000, "its value is not JSON"),
    ("assembly", '"x"', "its value is not a JSON object")])
def test_metadata_that_is_not_a_json_object_is_named(sim_flight, tmp_path, cli, key, value, why):
    """Nested too deep for the parser (a RecursionError traceback before), or JSON of the wrong shape (an
    AttributeError): the record is skipped as damage and named, everything else replayed, exit 0 (before: the
    whole log refused, exit 2, for one flipped bit in it)."""
    bad = tmp_path / "bad.mcap"
    copy_log(sim_flight[1], bad, metadata={key: value})
    code, out, err = cli("replay", str(bad), "--json")
    (d,) = json.loads(out)
    assert code == 0 and d["periods"] > 1000 and not d["complete"], err
    assert d["warnings"][0].endswith(f": the {key} metadata record is damaged ({why}): skipped"), d["warnings"]


def test_gyro_lag_of_a_config_whose_sections_are_not_tables(sim_flight, tmp_path, cli):
    bad = tmp_path / "bad.mcap"
    copy_log(sim_flight[1], bad, metadata={"config": '{"mocap": 5}'})
    code, _, err = cli("replay", str(bad), "--gyro-lag")
    assert code == 2 and err.count("\n") == 1 and "config: the log's config has no usable mocap" in err, err


@pytest.mark.parametrize("spoilt, why", [
    (b"[" * 100000, "(not a JSON object)"),  # not JSON
    (b"[1, 2]", "(not a JSON object)"),  # JSON, not an object
    (b'{"t_s": "soon", "phase": 3}', ""),  # an object, not the topic's
    (b'{"t_s": 1.0, "phase": "track", "state": {}, "modules": [[]]}', "")])
def test_a_record_that_is_not_the_topics_is_skipped_with_a_warning(sim_flight, tmp_path, spoilt, why):
    """Intact bytes (their CRC holds) that are not what the topic holds: skipped, counted in a warning, the log not
    complete; every other period read."""
    res, log = sim_flight
    bad, first = tmp_path / "bad.mcap", []

    def spoil(topic, rec):
        if topic == "/control" and len(first) < 3 and rec.get("phase") == "track":
            first.append(rec)
            return spoilt
        return rec

    copy_log(log, bad, record=spoil)
    r = analyse(bad)
    assert r.metrics.periods == analyse(log).metrics.periods - 3
    warning = "3 message(s) on /control are not what the topic holds" + (f" {why}" if why else "") + ": skipped"
    assert not r.complete and warning in r.warnings, r.warnings


def test_log_without_telemetry_channels(sim_flight, tmp_path):
    res, log = sim_flight
    bare = tmp_path / "bare.mcap"
    copy_log(log, bare, {"/backend/telemetry", "/mocap/stats", "/loop/timing", "/flight/summary"})
    r = analyse(bare)
    for key in FIGURES:
        assert same(getattr(r.metrics, key), getattr(res.metrics, key)), key
    assert r.metrics.battery_v_min == () and r.metrics.mocap_rate_hz == analyse(log).metrics.mocap_rate_hz  # the
    # poses themselves are counted


RATE_TOLERANCE = 0.02
"""A simulated stream's measured rate is its configured one within 2 %: a pose is timed when a period polls it, so
over the seconds of a window or a flight the span of its arrivals is off by a period at most (0.3 % of 3 s at
250 Hz); the preflight that once stepped the physics 20 ms every ~10 ms turn put the whole stream 4 % high."""


def test_the_simulated_mocap_keeps_its_rate(sim_flight):
    """What the dry run's virtual mocap sent, preflight included (the poses' stamps in the log), and the rate
    replay measures are the configured rate within :data:`RATE_TOLERANCE`."""
    _, log = sim_flight
    with open(log, "rb") as fh:
        stamps = np.array([m.publish_time * 1e-9 for _, _, m in make_reader(fh).iter_messages(["/mocap/assembly"])])
    r = analyse(log)
    configured = r.metadata["config"]["mocap"]["rate_hz"]
    assert (len(stamps) - 1) / (stamps[-1] - stamps[0]) == pytest.approx(configured, rel=RATE_TOLERANCE)
    assert r.metrics.mocap_rate_hz == pytest.approx(configured, rel=RATE_TOLERANCE)


LATE_EVERY, LATE_AT = 7, 3
REJECTED_EVERY, REJECTED_AT = 11, 5
PREFLIGHT_REJECTED, PREFLIGHT_ESTIMATOR_REJECTED = 5, 3
"""Poses the subscriber and the estimator rejected in preflight, planted (a dry run's preflight once rejected 5)."""


def _with_known_counts(log, out) -> np.ndarray:
    """``log`` copied with counts the test knows: period k (the k-th record with a state) ran late when
    ``k % LATE_EVERY == LATE_AT`` (a record holds the loop's count before its period ran, the loop's summary the
    total), and a pose was rejected in it, by the subscriber and by the estimator, when ``k % REJECTED_EVERY ==
    REJECTED_AT`` (a record's count includes its period's), after the preflight's ``PREFLIGHT_REJECTED`` and
    ``PREFLIGHT_ESTIMATOR_REJECTED`` (``/flight/start``, and every period's count since the stream began). Returns
    the periods' flight times, s."""
    times, started = [], []

    def record(topic, d):
        if topic == "/control" and "state" in d:
            k = len(times)
            times.append(d["t_s"])
            d["loop"]["overruns"] = (k + LATE_EVERY - LATE_AT - 1) // LATE_EVERY
            rejected = (k + REJECTED_EVERY - REJECTED_AT) // REJECTED_EVERY
            d["mocap"]["rejected"] = PREFLIGHT_REJECTED + rejected
            d["estimate"]["rejected"] = PREFLIGHT_ESTIMATOR_REJECTED + rejected
        elif topic == "/loop/timing":
            d["overruns"] = (len(times) + LATE_EVERY - LATE_AT - 1) // LATE_EVERY
        elif topic == "/flight/start":
            started.append(len(times))
            d["mocap"]["rejected"] = PREFLIGHT_REJECTED
            d["estimate"]["rejected"] = PREFLIGHT_ESTIMATOR_REJECTED
        return d

    copy_log(log, out, record=record)
    assert started == [0]  # the flight logged its counts as preflight passed, once, before its first period
    return np.array(times)


@pytest.mark.parametrize("t_from, t_to", [(1.0, 4.0), (5.5, None)])
def test_a_window_recomputed_from_its_csv(sim_flight, tmp_path, t_from, t_to):
    """Every figure of a window equals the same figure computed with numpy from the CSV rows of that window (not
    the analysis code): periods, flight time and tracking time, position RMSE over the tracking periods, the mocap
    rate from the arrival times of the poses that arrived over the periods (and, within the polling's 1 %, from
    their capture stamps, the publisher's clock), the late periods and the events; the late periods and rejected
    poses also equal the counts planted in the log. The first window starts in the take-off and ends in the
    tracking; the second runs from the tracking to past the end."""
    _, log = sim_flight
    counted = tmp_path / "counted.mcap"
    times = _with_known_counts(log, counted)
    r = analyse(counted, t_from, t_to)
    control, mocap, events = export_csv(counted, tmp_path, t_from, t_to)
    with open(control) as fh:
        rows = list(csv.DictReader(fh))
    t = np.array([float(row["t_s"]) for row in rows])
    hi = math.inf if t_to is None else t_to
    assert t_from <= t.min() and t.max() <= hi and r.metrics.periods == len(rows)
    assert r.metrics.duration_s == pytest.approx(t[-1] - t[0], rel=1e-12)
    track = np.array([row["phase"] == "track" for row in rows])
    assert track.any() and r.metrics.tracked_s == pytest.approx(np.ptp(t[track]), rel=1e-12)
    xyz = np.array([[float(row[k]) for k in ("x_m", "y_m", "z_m", "x_ref_m", "y_ref_m", "z_ref_m")] for row in rows])
    error = np.linalg.norm(xyz[track, :3] - xyz[track, 3:], axis=1)
    assert r.metrics.pos_rmse_m == pytest.approx(np.sqrt(np.mean(error**2)), rel=1e-9)
    with open(mocap) as fh:
        poses = np.array([[float(row["t_s"]), float(row["capture_t_s"])] for row in csv.DictReader(fh)])
    arrived, captured = poses[(poses[:, 0] >= t[0]) & (poses[:, 0] <= t[-1])].T
    assert r.metrics.mocap_rate_hz == pytest.approx(1.0 / np.mean(np.diff(arrived)), rel=1e-9)  # mean interval
    assert r.metrics.mocap_rate_hz == pytest.approx(1.0 / np.mean(np.diff(np.sort(captured))), rel=0.01)
    assert r.metrics.mocap_rate_hz == pytest.approx(r.metadata["config"]["mocap"]["rate_hz"], rel=RATE_TOLERANCE)
    k = np.flatnonzero((times >= t_from) & (times <= hi))  # the window's periods, by their index in the flight
    late = np.array([int(row["late"]) for row in rows])
    assert r.metrics.overruns == late.sum() == np.count_nonzero(k % LATE_EVERY == LATE_AT) > 0
    planted = np.count_nonzero(k % REJECTED_EVERY == REJECTED_AT)
    assert r.metrics.mocap_rejected == r.metrics.estimator_rejected == planted > 0
    with open(events) as fh:
        logged = list(csv.DictReader(fh))
    assert [(float(e["t_s"]), e["level"], e["text"]) for e in logged] == r.events and logged
    assert all(t_from <= t_s <= hi for t_s, _, _ in r.events)
    assert r.metrics.stalls == sum("loop stalled" in e["text"] for e in logged)
    phases = [row["phase"] for row in rows]
    changes = [p for i, p in enumerate(phases) if i == 0 or p != phases[i - 1]]
    assert [p for _, p in r.timeline] == changes + (["done"] if t_to is None else [])  # the end: a motors-off record


def test_a_window_from_the_first_period_leaves_the_preflight_out(sim_flight, tmp_path):
    """The first period's record counts the preflight's rejections too (5 by the subscriber, 3 by the estimator,
    planted): a window from the first period counts from ``/flight/start`` (the counts as preflight passed), so
    its first three periods rejected nothing (it said 5 and 3); unwindowed, the counts run from the stream's start,
    like the events. A log written before ``/flight/start`` cannot tell a window from its first period which
    counts are the window's: null there, and the same figures as before elsewhere."""
    _, log = sim_flight
    counted = tmp_path / "counted.mcap"
    times = _with_known_counts(log, counted)
    planted = np.count_nonzero(np.arange(len(times)) % REJECTED_EVERY == REJECTED_AT)
    first = analyse(counted, None, times[2]).metrics
    assert first.periods == 3 and (first.mocap_rejected, first.estimator_rejected) == (0, 0)
    assert None not in (first.mocap_malformed, first.mocap_missed, first.estimator_late)
    flight = analyse(counted, times[0], None).metrics
    assert (flight.mocap_rejected, flight.estimator_rejected) == (planted, planted)
    whole = analyse(counted).metrics
    assert whole.mocap_rejected == PREFLIGHT_REJECTED + planted
    assert whole.estimator_rejected == PREFLIGHT_ESTIMATOR_REJECTED + planted
    older = tmp_path / "older.mcap"
    copy_log(counted, older, {"/flight/start"})
    first = analyse(older, None, times[2]).metrics
    assert {first.mocap_rejected, first.mocap_malformed, first.mocap_missed, first.estimator_rejected,
            first.estimator_late} == {None}
    later, later_older = analyse(counted, 1.0, 4.0).metrics, analyse(older, 1.0, 4.0).metrics
    assert (later_older.mocap_rejected, later_older.estimator_rejected) == (
        later.mocap_rejected, later.estimator_rejected) != (None, None)
    assert analyse(older).metrics.mocap_rejected == whole.mocap_rejected


def test_the_mocap_rate_of_a_short_window(sim_flight, tmp_path):
    """Three periods (8 ms) hold a pose or two of a 100 Hz stream: their count over the periods' span read 125 or
    250 Hz. Under 0.5 s of arrivals (``RATE_MIN_SPAN_S``) the rate is NaN, too short to say; from there on it is
    the stream's, from the intervals between the arrivals."""
    _, log = sim_flight
    for t_to in (6.01, 6.3):
        r = analyse(log, 6.0, t_to)
        assert r.metrics.periods > 0 and math.isnan(r.metrics.mocap_rate_hz), t_to
    r = analyse(log, 6.0, 6.7)
    control, mocap, _ = export_csv(log, tmp_path, 6.0, 6.7)
    with open(control) as fh:
        t = np.array([float(row["t_s"]) for row in csv.DictReader(fh)])
    with open(mocap) as fh:
        arrived = np.array([float(row["t_s"]) for row in csv.DictReader(fh)])
    arrived = arrived[(arrived >= t[0]) & (arrived <= t[-1])]
    assert r.metrics.mocap_rate_hz == pytest.approx(1.0 / np.mean(np.diff(arrived)), rel=1e-9)
    assert r.metrics.mocap_rate_hz == pytest.approx(r.metadata["config"]["mocap"]["rate_hz"], rel=RATE_TOLERANCE)


def test_a_log_cut_short_and_its_recovered_copy(sim_flight, tmp_path):
    """Both processes killed: the file ends mid-chunk. The stream reader reads up to the cut; `log recover`
    rewrites it whole, metadata (config, code version, assembly) included, and what the source lost."""
    _, log = sim_flight
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: int(log.stat().st_size * 0.6)])
    partial = analyse(cut)
    full = analyse(log)
    assert not partial.complete and 0 < partial.metrics.periods < full.metrics.periods
    assert partial.metadata["config"]["trajectory"]["roll_deg"] == -5.0
    recovered = tmp_path / "recovered.mcap"
    counts = recover(cut, recovered)
    assert not counts["source_was_complete"]
    again = analyse(recovered)
    # whole by its own bytes, yet not the whole flight: the copy says what its source lost
    assert not again.complete and again.metrics.periods == partial.metrics.periods
    assert again.warnings and all(w.startswith(f"recovered by `log recover` from {cut}, which lost: ")
                                  for w in again.warnings), again.warnings
    assert again.metadata == partial.metadata and again.metadata["code_version"]
    with open(recovered, "rb") as fh:
        names = {m.name for m in make_reader(fh).iter_metadata()}
    assert {"config", "code_version", "assembly"} <= names


def test_sigkill_of_a_flight_and_its_writer_then_replay(tmp_path):
    cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:7486")
    log = tmp_path / "killed.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "groundstation", "fly", str(cfg), "--log", str(log)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT, start_new_session=True)
    time.sleep(8.0)  # in the air
    writers = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True)  # its log writer
    for pid in [int(p) for p in writers.stdout.split()] + [proc.pid]:
        os.kill(pid, signal.SIGKILL)
    proc.wait(10)
    recovered = tmp_path / "recovered.mcap"
    recover(log, recovered)
    r = analyse(recovered)
    assert r.metrics.periods > 250 and r.metadata["config"]["rate_hz"] == 250
    assert r.timeline[0][1] == "takeoff" and r.timeline[-1][1] != "done"  # it never landed


def test_a_hardware_backend_flight_replays_with_battery_and_link(tmp_path):
    # The modules in a process of their own, as an operator runs them: as a thread of this one they competed with
    # the flight loop for the interpreter and their poses and states came late.
    peer = peer_process(tmp_path, str(ROOT / "configs/assemblies/toy_v2.json"), "--port", "19930", "--mocap",
                        "tcp/127.0.0.1:7487", "--params", str(ROOT / "firmware_params/crazyflie.toml"))
    try:
        cfg = sitl_config(tmp_path, "crazyflie", 19930, "tcp/127.0.0.1:7487")
        log = tmp_path / "cf.mcap"
        res = fly(cfg, duration=3.0, log_path=log)
        assert res.phase == "done"
    finally:
        peer.terminate()
        peer.wait(10)
    r = analyse(log)
    for key in FIGURES:
        assert same(getattr(r.metrics, key), getattr(res.metrics, key)), key
    assert r.metrics.battery_v_min == pytest.approx((4.0, 4.0))
    # measured for both modules (their size under load is not the point here: the link failsafes have their rows)
    assert all(v > 0 for v in r.metrics.link_latency_ms_max) and r.metrics.link_loss_max == (0.0, 0.0)


def test_not_a_flight_log(tmp_path):
    with pytest.raises(ConfigError, match="not an MCAP file"):
        analyse(ROOT / "README.md")
    other = tmp_path / "other.mcap"
    with open(other, "wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="someone-else")
        w.finish()
    with pytest.raises(ConfigError, match="not a flight log of groundstation"):
        analyse(other)
