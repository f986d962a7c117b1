"""The log writer's guards: a stamp that is not a time or a record that does not encode costs that message, never
the writer; a log file is claimed exclusively and never overwritten; a writer that hangs is noticed by the watchdog;
a log whose input ends without the flight's end says so."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.reader import make_reader

from groundstation.flightlog.mcap_log import WRITER_STALL_S, FlightLog, claim, stamp_ns

ROOT = Path(__file__).resolve().parents[2]
T0 = 1.7e9
"""A log time (s since the epoch)."""
NOT_TIMES = [float("nan"), float("inf"), -float("inf"), -1.0, 1.7e12, 1e30]
"""Stamps that are not MCAP times: non-finite, negative, and beyond 2^64 ns (1.7e12: a stamp in milliseconds)."""


def _messages(path: Path, topic: str) -> list:
    with open(path, "rb") as fh:
        return [m for _, _, m in make_reader(fh).iter_messages(topics=[topic])]


def _texts(path: Path) -> list[str]:
    from foxglove_schemas_protobuf.Log_pb2 import Log

    return [Log.FromString(m.data).message for m in _messages(path, "/log")]


def test_stamp_ns_takes_only_times():
    assert stamp_ns(0.0) == 0 and stamp_ns(T0) == int(T0 * 1e9) and stamp_ns(np.float64(1.5)) == 1_500_000_000
    assert all(stamp_ns(t) is None for t in NOT_TIMES + [None, "x", 2**64 / 1e9])


def test_stamps_that_are_not_times_are_rejected_counted_and_named(tmp_path):
    path = tmp_path / "stamps.mcap"
    payload = PoseInFrame(frame_id="world").SerializeToString()
    with FlightLog(path, {"config": "{}"}) as log:
        for k in range(100):
            t = T0 + k * 0.01
            log.record("/count", {"k": k}, t)
            log.raw_protobuf("/mocap/assembly", PoseInFrame, payload, t, publish_time=t - 0.005)
            bad = NOT_TIMES[k % len(NOT_TIMES)]
            log.raw_protobuf("/mocap/assembly", PoseInFrame, payload, t, publish_time=bad)  # the source's stamp
            log.record("/count", {"k": -1}, bad)  # a log time that is not one
            log.pose("/state/pose", np.zeros(3), np.eye(3), bad)
            log.event("warning", "an event at a log time that is not one", bad)
    assert log.error is None  # the writer went on
    assert log.rejected == {"/mocap/assembly publish time": 100, "/count log time": 100,
                            "/state/pose log time": 100, "/log log time": 100}
    with open(path, "rb") as fh:
        assert make_reader(fh).get_summary() is not None  # finalized
    assert [json.loads(m.data)["k"] for m in _messages(path, "/count")] == list(range(100))
    mocap = _messages(path, "/mocap/assembly")
    assert len(mocap) == 100 and all(abs(m.log_time - m.publish_time - 5_000_000) < 1000 for m in mocap)
    texts = _texts(path)
    assert sum("a message on /mocap/assembly is not written: its publish time nan is not a time" in t
               for t in texts) == 1  # named once per kind, then counted
    assert any(t.startswith("messages not written: /mocap/assembly publish time: 100") for t in texts)


def test_a_record_that_does_not_encode_costs_that_record(tmp_path):
    path = tmp_path / "enc.mcap"
    with FlightLog(path) as log:
        log.record("/count", {"k": 0}, T0)
        log.record("/count", {"k": {1, 2}}, T0 + 0.01)  # a set: not JSON
        log.pose("/state/pose", np.zeros(3), np.eye(2), T0 + 0.02)  # not a rotation matrix
        log.record("/count", {"k": 2}, T0 + 0.03)
    assert log.error is None and log.rejected == {"/count encoding": 1, "/state/pose encoding": 1}
    assert [json.loads(m.data)["k"] for m in _messages(path, "/count")] == [0, 2]


def test_claim_is_exclusive(tmp_path):
    path = tmp_path / "claimed.mcap"
    won, lost = [], []
    barrier = threading.Barrier(8)

    def race():
        barrier.wait()
        try:
            claim(path)
            won.append(1)
        except FileExistsError:
            lost.append(1)

    threads = [threading.Thread(target=race) for _ in range(8)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert len(won) == 1 and len(lost) == 7 and path.stat().st_size == 0


def test_the_writer_never_overwrites_a_log(tmp_path):
    path = tmp_path / "old.mcap"
    path.write_bytes(b"a flight log")
    log = FlightLog(path)
    log.record("/count", {"k": 0}, T0)
    log.close()
    assert log.error.startswith("FileExistsError") and "never overwritten" in log.error
    assert path.read_bytes() == b"a flight log"


def test_a_stopped_writer_is_noticed_and_left_to_finish_the_file(tmp_path):
    """The writer process stops (SIGSTOP: for the flight process the same as a write blocked on a frozen disk): it
    takes no more input, the watchdog says so within its bound, close does not wait for it; resumed, it finishes
    the file with what it was given. (A FIFO is no stand-in: the MCAP writer needs a file it can seek in, and fails
    at once on one, a failure the flight sees like any other.)"""
    path = tmp_path / "stopped.mcap"
    log = FlightLog(path)
    k = 0
    deadline = time.monotonic() + 120.0  # a cap for a loaded machine, not a timing assertion
    while k < 100 or (log.error is None and time.monotonic() < deadline):
        if k == 100:
            time.sleep(1.0)  # all of it taken (the writer started)
            os.kill(log.writer_pid, signal.SIGSTOP)
        log.record("/count", {"k": k}, T0 + k * 0.004)
        k += 1
        time.sleep(0.004)
    try:
        assert log.hung and log.error.startswith("the log writer has taken none of its input for ")
        assert f"> {WRITER_STALL_S:g} s: hung" in log.error
        log.close()  # returns: the hung writer is neither waited for nor killed
        assert log._process.poll() is None and log.error.startswith("the log writer has taken none")
    finally:
        os.kill(log.writer_pid, signal.SIGCONT)
    log._process.wait(60)
    with open(path, "rb") as fh:
        assert make_reader(fh).get_summary() is not None  # finalized after all
    ks = [json.loads(m.data)["k"] for m in _messages(path, "/count")]
    assert ks == list(range(len(ks))) and len(ks) >= 100  # what it was given before it hung, in order


CHILD = """
import os, sys, time
from groundstation.flightlog.mcap_log import FlightLog
log = FlightLog(sys.argv[1], {"config": "{}"})
for k in range(50):
    log.record("/count", {"k": k}, 1.7e9 + k * 0.01)
time.sleep(1.0)  # the feeder hands them over
print(log.writer_pid, flush=True)
os._exit(0)  # as if killed: the log is never closed
"""


def test_a_log_whose_input_ends_without_its_end_says_so(tmp_path):
    path = tmp_path / "cut.mcap"
    out = subprocess.run([sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, cwd=ROOT,
                         timeout=120)
    writer = int(out.stdout.split()[0])
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline and os.path.exists(f"/proc/{writer}"):
        time.sleep(0.05)  # the writer finishes the file at the end of its input, then exits
    assert [json.loads(m.data)["k"] for m in _messages(path, "/count")] == list(range(50))
    assert any(t.startswith("the log ends without the flight's end") for t in _texts(path))


@pytest.mark.parametrize("bad", [float("nan"), -1.0, 1e30])
def test_events_with_a_time_that_is_not_one_do_not_raise_in_the_flight_process(tmp_path, bad):
    with FlightLog(tmp_path / "e.mcap") as log:
        log.event("info", "x", bad)  # builds its protobuf Timestamp here, on the control thread
    assert log.error is None and log.rejected == {"/log log time": 1}
