"""A hardware flight never imports the simulator: ``groundstation fly`` with PyBullet and ``sim`` blocked from
importing, against simulated modules in another process (which do use PyBullet, in their own process)."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys

from tests.peers import attempted, host_freezes, raise_if_stopped_by_host
from tests.runtime.test_fly import sim_peer  # noqa: F401  (the fixture: sim-peer in its own process, per kind)

NO_SIMULATOR = """
import sys

class NoSimulator:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("pybullet", "pybullet_data", "sim"):
            raise ImportError(f"{name} is blocked: a hardware flight must not import the simulator")

sys.meta_path.insert(0, NoSimulator())
"""


def _run(code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", NO_SIMULATOR + code, *args], capture_output=True, text=True,
                          timeout=120)


def test_the_blocker_blocks():
    r = _run("import sim.pybullet_backend")
    assert r.returncode != 0 and "sim is blocked" in r.stderr


def test_a_hardware_flight_runs_without_the_simulator(sim_peer, tmp_path):  # noqa: F811
    cfg, _, kind = sim_peer

    logs = (tmp_path / f"h{n}.mcap" for n in itertools.count())  # an existing log is never written over

    def flown():
        with host_freezes() as seen:
            r = _run("from groundstation.cli import main; main(sys.argv[1:])",
                     "fly", str(cfg), "--duration", "1", "--log", str(next(logs)), "--json")
        summary = json.loads(r.stdout) if r.stdout.startswith("{") else {}
        if r.returncode != 0 and summary:
            raise_if_stopped_by_host(summary["phase"], summary["reason"], seen)
        assert r.returncode == 0, r.stdout + r.stderr
        return summary

    summary = attempted(flown, label=kind)
    assert summary["phase"] == "done" and summary["reason"] == "", kind
