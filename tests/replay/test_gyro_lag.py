"""``replay --gyro-lag`` on logs written here with a known gyro delay: a pitch oscillation whose poses and gyro
readings are made from one closed-form angle, the readings ``delay`` late."""

import json
import math

import pytest
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.writer import Writer

from groundstation.flightlog.mcap_log import LIBRARY
from groundstation.replay.gyro_lag import gyro_lag
from groundstation.rotations import matrix_to_quat, rotvec_to_matrix
from groundstation.runtime.fly import fly
from tests.runtime.test_fly import config_with

T0 = 1.7e9
"""Log time of flight time 0, s since the epoch."""


def _log(path, delay: float, amplitude_deg: float = 60.0, latency: float = 0.005, transport: float = 0.002):
    """4 s of tracking at 250 Hz, poses at 100 Hz captured ``latency + transport`` before they arrive (stamped at
    capture, on a clock 3.2 s off the log's), gyro readings ``delay`` old."""
    a, w = math.radians(amplitude_deg), 2 * math.pi * 2.0
    angle = lambda t: a / w * (1.0 - math.cos(w * t))  # noqa: E731  (rate a sin(w t))
    with open(path, "wb") as f:
        mcap = Writer(f)
        mcap.start(library=LIBRARY)
        mcap.add_metadata("config", {"value": json.dumps({"mocap": {"body": "assembly", "latency_s": latency},
                                                          "backend": {"kind": "sim", "gyro_delay_s": 0.004}})})
        js = mcap.register_schema("control", "jsonschema", b"{}")
        pb = mcap.register_schema("foxglove.PoseInFrame", "protobuf", b"")
        control = mcap.register_channel("/control", "json", js)
        poses = mcap.register_channel("/mocap/assembly", "protobuf", pb)
        events = []
        for k in range(1000):
            t = k / 250
            events.append((t, "c", {"t_s": t, "phase": "track", "modules": [{"command_frac_umax": [0.4] * 4}],
                                    "state": {"omega_radps": [0.0, a * math.sin(w * (t - delay)), 0.0]}}))
        for k in range(400):
            tc = k / 100
            p = PoseInFrame()
            stamp = tc + T0 - 3.2
            p.timestamp.seconds, p.timestamp.nanos = int(stamp), round((stamp % 1) * 1e9)
            q = matrix_to_quat(rotvec_to_matrix([0.0, angle(tc), 0.0]))
            p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z, p.pose.orientation.w = q
            events.append((tc + latency + transport, "p", p.SerializeToString()))
        for t, kind, data in sorted(events, key=lambda e: e[0]):
            ns = round((T0 + t) * 1e9)
            if kind == "c":
                mcap.add_message(control, ns, json.dumps(data).encode(), ns)
            else:
                mcap.add_message(poses, ns, data, ns)
        mcap.finish()
    return path


@pytest.mark.parametrize("delay", [0.0, 0.012, 0.025])
def test_the_delay_the_readings_were_made_with(tmp_path, delay):
    lag = gyro_lag(_log(tmp_path / "g.mcap", delay))
    # less the poses' 2 ms of transport beyond the configured latency (they are timed that much late, so the gyros
    # look that much less late): the estimator times the poses the same way, so this is the delay to tell it
    assert lag.found and lag.delay_s == pytest.approx(delay - 0.002, abs=0.0015)
    assert lag.configured_s == 0.004 and lag.samples > 300
    assert math.degrees(lag.rate_rms) > 30.0 and lag.rms_at_delay < 0.1 * max(lag.rms_at_zero, 1e-9) + 1e-3


def test_a_flight_that_hardly_turns_has_no_delay_to_find(tmp_path):
    lag = gyro_lag(_log(tmp_path / "calm.mcap", 0.012, amplitude_deg=2.0))
    assert not lag.found and math.degrees(lag.rate_rms) < 5.0


def test_cli_on_a_calm_dry_run(cli, tmp_path):
    """A figure-8 of the V barely turns (its pitch follows the slow force): the rates match about as well at any
    delay, so through the command an operator runs, none is claimed, and the operator is told why."""
    log = tmp_path / "dry.mcap"
    assert fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:7537"), duration=3.0, log_path=log).phase == "done"
    code, out, err = cli("replay", str(log), "--gyro-lag", "--json")
    assert code == 0, err
    (replay,) = json.loads(out)  # a list, one object per log
    d = replay["gyro_lag"]
    assert not d["found"] and d["configured_s"] == 0.004 and d["sharpness"] < 1.25, d
    code, out, err = cli("replay", str(log), "--gyro-lag")
    assert code == 0 and "no gyro delay found: the body turned at " in out, out
