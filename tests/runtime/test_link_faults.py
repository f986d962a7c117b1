"""Crazyflie flights through a loopback relay that delays, drops and reorders packets (``sim.udp_relay``, in its
own process, between the ground station and ``groundstation sim-peer``): a slow or lossy link ends in a logged
failsafe, never a flip, and a mildly lossy one flies."""

import subprocess
import sys
import time

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from groundstation.runtime.closed_loop import PreflightError
from groundstation.runtime.fly import fly
from tests.peers import ROOT
from tests.runtime.test_fly import read_log, sitl_config

PEER_PORT, RELAY_PORT, MOCAP = 19900, 19910, "tcp/127.0.0.1:7481"


def max_tilt_deg(log) -> float:
    """Largest angle between body z and world z over the whole logged flight (the state estimate), deg."""
    tilt = [0.0]
    with open(log, "rb") as fh:
        for _, _, _, pose in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/state/pose"]):
            q = pose.pose.orientation
            tilt.append(np.degrees(np.arccos(np.clip(1 - 2 * (q.x**2 + q.y**2), -1, 1))))
    return max(tilt)


@pytest.fixture
def relayed(tmp_path):
    """Start simulated modules and a relay with the given faults; yields a function that does so and returns the
    flight config pointing at the relay."""
    procs = []

    def start(**faults) -> object:
        procs.append(subprocess.Popen([sys.executable, "-m", "groundstation", "sim-peer",
                                       str(ROOT / "configs/assemblies/toy_v2.json"), "--port", str(PEER_PORT),
                                       "--mocap", MOCAP, "--params", str(ROOT / "firmware_params/crazyflie.toml")],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.PIPE))
        args = [f"--{k.replace('_', '-')}={v}" for k, v in faults.items()]
        procs.append(subprocess.Popen([sys.executable, "-m", "sim.udp_relay", "--listen", str(RELAY_PORT),
                                       "--target", str(PEER_PORT), "--links", "2", *args],
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE))
        time.sleep(2.0)  # imports, PyBullet and Zenoh start-up
        return sitl_config(tmp_path, "crazyflie", RELAY_PORT, MOCAP)

    yield start
    for p in procs:
        p.terminate()
        p.communicate(timeout=10)


def test_30ms_from_the_start_is_refused_in_preflight(relayed, tmp_path):
    cfg = relayed(delay_ms=30)
    log = tmp_path / "slow.mcap"
    with pytest.raises(PreflightError, match=r"module 0 \(udp://127.0.0.1:19910\) link round trip \d+ ms > 14 ms"):
        fly(cfg, log_path=log)
    counts, _, logs, _ = read_log(log)
    assert "/control" not in counts and any(b"link round trip" in d for _, d in logs)  # never armed


def test_30ms_in_flight_stops_the_motors_before_the_attitude_goes(relayed, tmp_path):
    cfg = relayed(delay_ms=30, after=6.0)  # ~1.5 s of preflight, then take-off: the link degrades in the air
    log = tmp_path / "late.mcap"
    res = fly(cfg, duration=8.0, log_path=log)
    # Round trips of 60 ms and more are too slow to land on: the motors stop at once, whatever the policy.
    assert res.phase == "emergency" and res.reason.startswith("link degraded: module")
    assert "> 20 ms" in res.reason
    assert max_tilt_deg(log) < 20.0  # stopped upright: no flip
    counts, _, logs, motors = read_log(log)
    assert motors[-1][1]["motors_off"] and any(b"link degraded" in d for _, d in logs)


def test_20_percent_reordering_in_flight_ends_in_a_failsafe(relayed, tmp_path):
    """A reordered command arrives after a newer one and the app drops it: the echoes lag (round trip up) and the
    module accepts fewer commands than were sent (loss up). Which bound trips first depends on the draw: a round
    trip over 20 ms stops the motors, anything less lands; either way the reason is logged and nothing flips.
    (From the start, preflight refuses it: the round trip shows there too.)"""
    cfg = relayed(reorder=0.2, reorder_ms=10, after=6.0)
    log = tmp_path / "reorder.mcap"
    res = fly(cfg, duration=8.0, log_path=log)
    assert res.phase in ("done", "emergency") and res.reason.startswith("link degraded: module")
    assert not res.nominal and max_tilt_deg(log) < 20.0
    _, _, logs, motors = read_log(log)
    assert motors[-1][1]["motors_off"] and any(b"link degraded" in d for _, d in logs)


def test_2_percent_loss_flies_the_figure8(relayed, tmp_path):
    cfg = relayed(loss=0.02)
    res = fly(cfg, duration=6.0, log_path=tmp_path / "lossy.mcap")
    assert res.phase == "done" and res.reason == "" and res.nominal
    assert res.metrics["pos_rmse_m"] < 0.03
