import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from groundstation.cli import main
from groundstation.flightlog.mcap_log import FlightLog, being_written, recover

ROOT = Path(__file__).resolve().parents[2]

WRITER = """
import sys, time, numpy as np
from groundstation.flightlog.mcap_log import FlightLog
log = FlightLog(sys.argv[1], {"config": "{}"})
print("writer", log.writer_pid, flush=True)
k = 0
t0 = time.time()
while True:
    log.record("/count", {"k": k}, time.time())
    log.pose("/state/pose", np.array([k * 1e-3, 0, 1.0]), np.eye(3), time.time())
    if k % 100 == 0:
        print(k, time.time() - t0, flush=True)
    k += 1
    time.sleep(0.002)
"""


def test_round_trip_counts(tmp_path):
    path = tmp_path / "a.mcap"
    with FlightLog(path, {"config": "{}"}) as log:
        for k in range(500):
            log.record("/count", {"k": k}, 1000.0 + k * 0.01)
        log.event("info", "hello", 1000.0)
    with open(path, "rb") as fh:
        msgs = [json.loads(m.data)["k"] for _, _, m in make_reader(fh).iter_messages(topics=["/count"])]
    assert msgs == list(range(500))


def test_the_writer_holds_its_log_for_its_life(tmp_path):
    """``being_written`` while the writer process has the file, not after it finished (nor of a file never
    written by one)."""
    path = tmp_path / "live.mcap"
    with FlightLog(path, {"config": "{}"}) as log:
        log.event("info", "hello", 1000.0)
        deadline = time.monotonic() + 10.0  # the writer process starting (its header is 76 bytes until the end)
        while not being_written(path) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert being_written(path)
    assert not being_written(path) and not being_written(tmp_path / "none.mcap")


def _run_and_kill(path: Path, kill) -> tuple[dict[float, int], float]:
    """Run WRITER logging to ``path`` for 4 s, then ``kill(proc)`` (``proc.writer_pid``: its writer process);
    returns {elapsed s: k logged} and the last elapsed s."""
    # Its own process group, as in a terminal, and Ctrl-C's default action (an ignored SIGINT is inherited: a test
    # runner in the background, or a test that left it ignored, would make the script deaf to it).
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True,
                            cwd=ROOT, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    proc.writer_pid = int(proc.stdout.readline().split()[1])
    written_by = {}
    t_kill = time.monotonic() + 4.0
    while time.monotonic() < t_kill:
        line = proc.stdout.readline()
        k, t = line.split()
        written_by[float(t)] = int(k)
    kill(proc)
    proc.wait(timeout=60)  # a generous bound: on a loaded machine its exit waits for the writer to take the queue
    return written_by, max(written_by)


def _counts(path: Path) -> list[int]:
    with open(path, "rb") as fh:
        return [json.loads(m.data)["k"] for _, _, m in make_reader(fh).iter_messages(topics=["/count"])]


@pytest.mark.parametrize("kill", [lambda proc: os.kill(proc.pid, signal.SIGKILL),
                                  lambda proc: os.killpg(proc.pid, signal.SIGINT)],  # Ctrl-C in the terminal
                         ids=["sigkill", "sigint-to-the-group"])
def test_the_writer_outlives_the_flight_process_and_finalizes_the_file(tmp_path, kill):
    path = tmp_path / "killed.mcap"
    written_by, last_t = _run_and_kill(path, kill)
    deadline = time.monotonic() + 60.0  # the writer process sees the pipe close and finishes the file
    while being_written(path) and time.monotonic() < deadline:
        time.sleep(0.05)
    with open(path, "rb") as fh:
        assert make_reader(fh).get_summary() is not None  # summary and footer written: a seeking reader opens it
    # everything fed to the writer is there: all but the last few tens of milliseconds before the kill
    must_have = max(k for t, k in written_by.items() if t <= last_t - 0.1)
    ks = _counts(path)
    assert ks[: must_have + 1] == list(range(must_have + 1))


def test_sigkill_of_both_processes_leaves_a_recoverable_file(tmp_path):
    path = tmp_path / "killed.mcap"
    def kill_both(proc):
        os.kill(proc.writer_pid, signal.SIGKILL)
        os.kill(proc.pid, signal.SIGKILL)

    written_by, last_t = _run_and_kill(path, kill_both)
    # everything logged up to about one second before the kill must come back
    must_have = max(k for t, k in written_by.items() if t <= last_t - 1.5)
    out = tmp_path / "recovered.mcap"
    with _argv_exit() as result:
        main(["log", "recover", str(path), str(out)])
    assert result["code"] == 0
    ks = _counts(out)
    assert ks[: must_have + 1] == list(range(must_have + 1))
    counts = recover(path, tmp_path / "again.mcap")
    assert not counts["source_was_complete"] and counts["channels"] >= 2


class _argv_exit:
    def __enter__(self):
        self.result = {}
        return self.result

    def __exit__(self, et, ev, tb):
        if et is SystemExit:
            self.result["code"] = ev.code
            return True
        return False


def test_writer_is_a_process_of_its_own(tmp_path):
    """The flight process only queues: encoding and I/O happen in the writer process (its cost per record is the
    loop benchmark's business)."""
    path = tmp_path / "b.mcap"
    log = FlightLog(path)
    assert log.writer_pid != os.getpid()
    for k in range(5000):
        log.pose("/p", np.zeros(3), np.eye(3), 1000.0 + k)
    log.close()
    with open(path, "rb") as fh:
        counts = {c.topic: n for c, n in ((c, make_reader(fh).get_summary().statistics.channel_message_counts[c.id])
                                          for c in make_reader(fh).get_summary().channels.values())}
    assert counts == {"/p": 5000, "/tf": 5000} and log.error is None


def test_writer_failure_is_reported(tmp_path):
    log = FlightLog(tmp_path / "missing-dir" / "x.mcap")
    log.record("/count", {"k": 0}, 1000.0)
    log.close()
    assert log.error is not None and log.error.startswith("FileNotFoundError")
    log.record("/count", {"k": 1}, 1001.0)
    assert log.dropped == 1  # after close: counted, not lost silently
