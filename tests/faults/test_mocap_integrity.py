"""Fault-table rows: mocap samples that lie about their source or their time, and authenticated mocap.

A hostile publisher in another process (``tests.faults.hostile_mocap``) reads the genuine stream, copies its
source id and sends forged, mis-stamped or replayed samples into a dry run whose ground station listens."""

from __future__ import annotations

import json

import pytest

from groundstation.mocap.auth import write_key_file
from groundstation.runtime.flight_config import load_flight_config
from groundstation.runtime.fly import Faults, fly
from tests.faults.table import Fault, bad_input, lying_mocap, rows
from tests.faults.test_fault_table import _hostile_flight, _records
from tests.faults.test_state_estimation import (
    _touched_down_upright,
    _touched_down_upright_within,
    _truth,
    touchdown_speed,
)
from tests.peers import ROOT, host_freezes, peer_process, raise_if_stopped_by_host
from tests.runtime.test_fly import SITL, TRACK_START_S, config_with, sitl_config

ENDPOINT = "tcp/127.0.0.1:8494"


def _attacked(tmp_path, mode: str, keyed: bool):
    """A dry run attacked by ``mode``; with ``keyed`` the flight and its simulated mocap share a key (the attacker
    has none). Returns the result and the last /mocap/stats record."""
    key = write_key_file(tmp_path / "mocap.key") if keyed else None
    res, log = _hostile_flight(tmp_path, mode, key_file=key)
    return res, json.loads(_records(log, "/mocap/stats")[-1][1])


@lying_mocap("mocap: a publisher copying the genuine source id, dragging the genuine pose off at 0.5 m/s, mid-flight "
             "(no key)",
             "the interleaved sequences named, no pose fused from then on: a blind landing, upright on the "
             "ground, exit 1")
def f_mocap_copied_source_id(cli, tmp_path):
    res, log = _hostile_flight(tmp_path, "copy-id")
    stats = json.loads(_records(log, "/mocap/stats")[-1][1])
    assert stats["foreign"] == 0 and stats["conflicts"] >= 3  # the one-publisher rule alone sees nothing
    named = [text for _, _, text in res.events
             if text.endswith("-> landing: mocap fault: two sequences under one source id on mocap/assembly/pose "
                              f"({text.split('(')[-1]}")]
    assert named, res.events  # measured: 44 ms after the first forged sample
    # Landing on the samples at the stream's own rate it tilted 20-22 deg (27-65 deg before samples off the
    # stream's cadence were refused), and one run in six tipped past the tilt bound; blind, it lands upright.
    assert res.phase == "done" and res.reason.startswith("mocap fault: two sequences"), (res.phase, res.reason)
    _touched_down_upright_within(log, 15.0)


@lying_mocap("mocap: a publisher copying the genuine source id, dragging the genuine pose down at 0.5 m/s, in "
             "tracking (no key)",
             "the interleaved sequences named, what the poses since the first conflict taught the estimate taken "
             "back, no pose fused from then on: a blind landing, upright, on the ground, exit 1")
def f_mocap_copied_source_id_sinking(cli, tmp_path):
    """Landing on the samples at the stream's own rate, the forger held the estimate on the ground while the
    assembly was 0.5 m up: "landed", motors off, a 3 m/s fall (hostile campaign). Blind but with what the forged
    samples had taught the estimate (a 0.4 m/s^2 sink), the motors stopped 0.6 m up: a 2.2 m/s touchdown.
    Measured since: 0.65-0.76 m/s (the blind landing's 0.5 m/s, aimed below the ground)."""
    res, log = _hostile_flight(tmp_path, "sink", after=3.5)
    assert res.phase == "done" and res.reason.startswith("mocap fault: two sequences under one source id"), \
        (res.phase, res.reason)
    assert any(text.endswith("poses fused since the first sequence conflict taken back; no pose is fused from now "
                             "on") for _, _, text in res.events), res.events
    _touched_down_upright_within(log, 15.0)
    truth = _truth(log)
    z = [height for _, _, height, _ in truth]
    landed = next(i for i in range(len(z)) if i > z.index(max(z)) and z[i] - z[0] < 0.005)
    before = next(i for i in range(landed, -1, -1) if truth[landed][0] - truth[i][0] >= 0.03)
    speed = (z[before] - z[landed]) / (truth[landed][0] - truth[before][0])
    assert speed < 1.2, speed  # 2.2 m/s with the forged lesson kept


@lying_mocap("mocap: a publisher copying the genuine source id, sending bursts of 5 consistent samples 1000 ahead in "
             "sequence, 3 cm low, 10 a second, mid-flight (no key)",
             "each burst resynchronises the stream, and the genuine track going on beside it is a second sender: "
             "named, a blind landing, upright on the ground, exit 1 (followed 50-82 times a flight, never named, "
             "it flew on 3 cm low, 'done', exit 0)")
def f_mocap_copied_source_id_resync_bursts(cli, tmp_path):
    res, log = _hostile_flight(tmp_path, "resync")
    stats = json.loads(_records(log, "/mocap/stats")[-1][1])
    assert stats["resyncs"] >= 1 and stats["conflicts"] >= 3, stats
    assert res.phase == "done" and res.reason.startswith("mocap fault: two sequences under one source id"), \
        (res.phase, res.reason)
    _touched_down_upright_within(log, 15.0)


@lying_mocap("mocap: samples stamped NaN, infinite or negative under the copied source id, mid-flight",
             "counted as malformed, never used or logged; the flight completes")
def f_mocap_nan_stamps(cli, tmp_path):
    res, stats = _attacked(tmp_path, "nan-stamp", keyed=False)
    assert res.phase == "done" and res.nominal, res.reason
    assert stats["malformed"] > 50 and stats["conflicts"] == 0


@lying_mocap("mocap: a pose 1 m off stamped 100 s ahead under the copied source id, mid-flight",
             "rejected by the ground station's own clock (counted); the flight completes")
def f_mocap_future_stamps(cli, tmp_path):
    res, stats = _attacked(tmp_path, "future-stamp", keyed=False)
    assert res.phase == "done" and res.nominal, res.reason
    assert stats["bad_stamps"] > 50 and res.metrics.pos_rmse_m < 0.03


@lying_mocap("authenticated mocap: a publisher without the key copying the source id, mid-flight",
             "its samples counted as unauthenticated and never used; the flight completes")
def f_mocap_keyed_forger(cli, tmp_path):
    res, stats = _attacked(tmp_path, "copy-id", keyed=True)
    assert res.phase == "done" and res.nominal, res.reason
    assert stats["unauthenticated"] > 50 and stats["conflicts"] == 0 and res.metrics.pos_rmse_m < 0.03
    assert stats["unechoed"] == 0  # the genuine samples, each echoing a fresh challenge


@lying_mocap("authenticated mocap: the genuine samples captured and re-sent 0.1 s later (valid MACs), mid-flight",
             "rejected (old sequence numbers), no fault; the flight completes")
def f_mocap_keyed_replay(cli, tmp_path):
    res, stats = _attacked(tmp_path, "replay-captured", keyed=True)
    assert res.phase == "done" and res.nominal, res.reason
    assert stats["rejected"] > 50 and stats["unauthenticated"] == 0 and res.metrics.pos_rmse_m < 0.03


@lying_mocap("authenticated mocap: the genuine samples captured and, once the bridge has been silent 0.55 s, re-sent "
             "by a publisher of its own (valid MACs; hovering, the bridge gone for good)",
             "not taken for a restarted bridge (their stamps stale on its clock): bad stamps, never used; "
             "the blind landing touches down on the ground, upright, under 0.85 m/s, exit 1 (before: taken, the "
             "landing flew on old poses and the V hit the ground at 3.5 m/s)")
def f_mocap_keyed_replay_after_the_silence(cli, tmp_path):
    faults = Faults()
    lost_at = TRACK_START_S + 0.5
    res, log = _hostile_flight(tmp_path, "handover-replay", after=1.0, key_file=write_key_file(tmp_path / "k.key"),
                               changes={'kind = "figure8"': 'kind = "hover"'}, faults=faults,
                               on_period=lambda t: setattr(faults, "mocap_paused", t >= lost_at))
    stats = json.loads(_records(log, "/mocap/stats")[-1][1])
    assert stats["handovers"] == 0 and stats["bad_stamps"] >= 20 and stats["unauthenticated"] == 0, stats
    assert res.phase == "done" and "landing blind" in res.reason, res.reason
    truth = _truth(log)
    assert max(z for t, _, z, _ in truth if t < lost_at) > truth[0][2] + 0.9  # lost at hover height
    _touched_down_upright(log)
    assert touchdown_speed(log, lost_at) < 0.85


@bad_input("mocap on a network endpoint without key_file or TLS",
           "one line naming mocap, exit 2, nothing opened")
def f_mocap_network_without_key(cli, tmp_path):
    cfg = config_with(tmp_path, endpoint="tcp/192.168.1.10:7448")
    code, out, err = cli("fly", str(cfg), "--log", str(tmp_path / "x.mcap"))
    assert code == 2 and err.count("\n") == 1 and "mocap" in err and "key_file" in err, err
    assert not (tmp_path / "x.mcap").exists()


def _keyed_flight_with_modules(tmp_path, kind: str, port: int, mocap: str):
    """A keyed flight against ``sim-peer`` modules of ``kind`` (its own process, publishing the pose with the key):
    their preflight (1.3 s for Crazyflie links) and arming (over a second for PX4) block the ground station."""
    key = write_key_file(tmp_path / "mocap.key")
    cfg = sitl_config(tmp_path, kind, port, mocap)
    cfg.write_text(cfg.read_text().replace("[mocap]\n", f'[mocap]\nkey_file = "{key}"\n'))
    params = load_flight_config(cfg)[0].backend.firmware_params
    peer = peer_process(tmp_path, str(ROOT / "configs/assemblies/toy_v2.json"), "--protocol", SITL[kind][1],
                        "--port", str(port), "--mocap", mocap, "--params", params, "--mocap-key-file", str(key))
    try:
        with host_freezes() as seen:
            res = fly(cfg, duration=2.0, log_path=tmp_path / f"{kind}-keyed.mcap")
    finally:
        peer.terminate()
        peer.wait(10)
    raise_if_stopped_by_host(res.phase, res.reason, seen)
    assert res.nominal and res.reason == "", (res.phase, res.reason)


for _kind, _port, _mocap in (("crazyflie", 22994, "tcp/127.0.0.1:8715"), ("mavlink", 22996, "tcp/127.0.0.1:8716")):
    def _keyed_case(cli, tmp_path, kind=_kind, port=_port, mocap=_mocap):
        _keyed_flight_with_modules(tmp_path, kind, port, mocap)
    _keyed_case.__name__ = f"f_mocap_keyed_with_{_kind}_modules"
    lying_mocap(f"authenticated mocap with simulated {_kind} modules (sim-peer): the modules' preflight and "
                f"arming block the ground station for a second or more",
                "the stream is read, and challenged, meanwhile: fresh poses at take-off, the flight completes, exit 0 "
                "(before: every keyed flight with modules took off on a pose 1.04 s old and landed blind from the "
                "ground)")(_keyed_case)


@pytest.mark.parametrize("row", rows(__name__), ids=[f.id for f in rows(__name__)])
def test_fault(row: Fault, cli, tmp_path):
    row.run(cli, tmp_path)
