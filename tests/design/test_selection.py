import json
from pathlib import Path

import numpy as np
import pytest

from groundstation.assembly.module import ModuleParams
from groundstation.design.selection import read_results, select
from groundstation.design.task import load_task
from groundstation.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
P = ModuleParams()
TOY = load_task(ROOT / "configs/tasks/toy_push_y.toml")


def test_toy_selection_stops_at_two_modules(tmp_path):
    sel = select(TOY, P, 4, results_path=tmp_path / "r.jsonl")
    assert sel.n == 2
    assert [(r.n, r.feasible) for r in sel.results] == [(1, False), (2, True)]
    alpha = np.degrees(sel.best.assembly.alpha)
    assert abs(alpha[0]) + abs(alpha[1]) == pytest.approx(22.5, abs=0.1)
    assert sel.best.row.feasible and sel.best.verification.feasible and sel.best.record["feasible"]


def test_resume_does_not_redo_finished_candidates(tmp_path):
    path = tmp_path / "r.jsonl"
    first = select(TOY, P, 3, min_modules=3, results_path=path)
    lines = path.read_text().splitlines()
    assert len(lines) == 2  # both n = 3 topologies
    solved = []
    again = select(TOY, P, 3, min_modules=3, results_path=path, on_result=solved.append)
    assert path.read_text().splitlines() == lines  # nothing re-solved, nothing appended
    assert [r.code for r in again.results] == [r.code for r in first.results]
    assert again.best.row.cost == first.best.row.cost  # read back from the results file
    assert np.array_equal(again.best.assembly.alpha, first.best.assembly.alpha)
    # A sweep killed mid-write leaves a torn last line: it is ignored and that candidate is solved again.
    path.write_text(lines[0] + "\n" + lines[1][: len(lines[1]) // 2])
    assert len(read_results(path)) == 1
    select(TOY, P, 3, min_modules=3, results_path=path)
    assert len(read_results(path)) == 2


def test_process_pool_gives_the_same_answer():
    serial = select(TOY, P, 3, min_modules=3)
    pooled = select(TOY, P, 3, min_modules=3, workers=2)
    assert sorted((r.code, round(r.cost, -6)) for r in pooled.results) == \
        sorted((r.code, round(r.cost, -6)) for r in serial.results)


def test_dask_scheduler_on_loopback():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        sel = select(TOY, P, 3, min_modules=3, scheduler=cluster.scheduler_address)
    assert sel.n == 3 and len(sel.results) == 2
    assert all(np.isfinite(r.cost) for r in sel.results)


def test_infeasible_up_to_max_is_a_result():
    sel = select(TOY, P, 1)
    assert sel.best is None and sel.n is None and len(sel.results) == 1


def test_results_file_rows_are_json(tmp_path):
    path = tmp_path / "r.jsonl"
    select(TOY, P, 2, results_path=path)
    for line in path.read_text().splitlines():
        entry = json.loads(line)
        assert entry["row"]["feasible"] == (entry["record"] is not None)


def test_a_hand_edited_record_in_the_results_file_is_named(tmp_path):
    path = tmp_path / "r.jsonl"
    select(TOY, P, 2, results_path=path)
    entries = [json.loads(line) for line in path.read_text().splitlines()]
    for e in entries:
        if e["record"] is not None:
            e["record"]["angles_deg"] = e["record"]["angles_deg"][:1]  # one angle where oE has three
    path.write_text("".join(json.dumps(e) + "\n" for e in entries))
    with pytest.raises(ConfigError) as err:
        select(TOY, P, 2, results_path=path)
    assert err.value.path == str(path) and err.value.key == "angles_deg"
