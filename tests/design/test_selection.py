import copy
import json
from pathlib import Path

import numpy as np
import pytest

from groundstation.assembly.module import ModuleParams
from groundstation.design import selection
from groundstation.design.selection import CandidateResult, bound_grid, cost_against_bound, read_results, select
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


@pytest.fixture(scope="module")
def toy_results(tmp_path_factory) -> list[dict]:
    """The results file of the toy task up to two modules: line 1 the single module (infeasible), line 2 oE."""
    path = tmp_path_factory.mktemp("toy") / "r.jsonl"
    select(TOY, P, 2, results_path=path, least=True)
    return [json.loads(line) for line in path.read_text().splitlines()]


def _write(path: Path, entries: list[dict]) -> Path:
    path.write_text("".join(json.dumps(e) + "\n" for e in entries))
    return path


def test_results_file_rows_are_json_with_their_records(toy_results):
    assert [(e["row"]["n"], e["row"]["feasible"]) for e in toy_results] == [(1, False), (2, True)]
    for entry in toy_results:
        assert entry["record"]["feasible"] == entry["row"]["feasible"]
        assert entry["record"]["topology"]["code"] == entry["row"]["code"]


def test_a_hand_edited_record_in_the_results_file_is_named(tmp_path, toy_results):
    entries = copy.deepcopy(toy_results)
    for e in entries:
        e["record"]["angles_deg"] = e["record"]["angles_deg"][:1]  # one angle where there are two or three
    path = _write(tmp_path / "r.jsonl", entries)
    with pytest.raises(ConfigError) as err:
        select(TOY, P, 2, results_path=path, least=True)
    assert err.value.path == f"{path}:1" and err.value.key == "angles_deg"


def _claim_best(entries):
    """The single module's row claims to be feasible at a cost below any design's."""
    entries[0]["row"].update(feasible=True, cost=1.0, status="Solve_Succeeded", certificate="")


def _claim_best_with_its_record(entries):
    _claim_best(entries)
    entries[0]["record"].update(feasible=True, cost=1.0)
    entries[0]["record"]["verification"]["feasible"] = True


def _claim_best_with_another_design(entries):
    """What issue 23 did to oS(W)E: an infeasible topology's line carries a feasible design's record."""
    _claim_best(entries)
    entries[0]["record"] = copy.deepcopy(entries[1]["record"])


def _cheaper(entries):
    entries[1]["row"]["cost"] /= 2


def _hidden(entries):
    entries[1]["row"].update(feasible=False, cost=float("inf"))


@pytest.mark.parametrize("edit, line, key, fragment", [
    (_claim_best, 1, "row.feasible", "says True, but its record, re-verified, gives False"),
    (_claim_best_with_its_record, 1, "feasible", "says True, but the design recomputed from the angles and inputs is "
                                                 "infeasible: wrench residual"),
    (_claim_best_with_another_design, 1, "row.code", "says o, but the record is a design of oE"),
    (_cheaper, 2, "row.cost", "but its record, re-verified, gives"),
    (_hidden, 2, "row.feasible", "says False, but its record, re-verified, gives True"),
])
def test_an_edited_results_line_is_refused_never_reported_best(tmp_path, toy_results, edit, line, key, fragment):
    entries = copy.deepcopy(toy_results)
    edit(entries)
    path = _write(tmp_path / "r.jsonl", entries)
    reported = []
    with pytest.raises(ConfigError) as err:
        select(TOY, P, 2, results_path=path, on_result=reported.append, least=True)
    assert err.value.path == f"{path}:{line}" and err.value.key == key and fragment in str(err.value)
    assert all(r.feasible is False for r in reported)  # the edited row never reached the caller as feasible


def test_rows_of_another_solver_version_are_solved_again(tmp_path, toy_results, monkeypatch):
    path = _write(tmp_path / "r.jsonl", toy_results)
    again = select(TOY, P, 2, results_path=path, least=True)
    assert len(path.read_text().splitlines()) == 2  # same code: reused (and re-verified)
    monkeypatch.setattr(selection, "solver_version", lambda: "a newer solver")
    newer = select(TOY, P, 2, results_path=path, least=True)
    rows = read_results(path)
    assert len(path.read_text().splitlines()) == 4 and len(rows) == 4  # both candidates solved again, appended
    assert newer.best.row.key != again.best.row.key
    assert newer.best.row.cost == pytest.approx(again.best.row.cost, rel=1e-6)


def test_the_solver_version_hashes_the_design_and_assembly_sources():
    version = selection.solver_version()
    assert len(version) == 16 and int(version, 16) >= 0
    assert version == selection.solver_version()


@pytest.mark.parametrize("edited, solves_again", [("nlp.py", True), ("figures.py", False), ("drawing.py", False)])
def test_an_edited_solver_file_makes_rows_new_work_a_figure_does_not(monkeypatch, edited, solves_again):
    from pathlib import Path

    hashed = selection.solver_version.__wrapped__  # uncached: the sources as they are now
    before = hashed()
    read = Path.read_bytes
    monkeypatch.setattr(Path, "read_bytes", lambda self: read(self) + (b"# edited" if self.name == edited else b""))
    assert (hashed() != before) is solves_again


def test_results_lines_carry_the_least_bound_design(toy_results):
    single, v = toy_results
    assert single["row"]["never_feasible"] and single["row"]["least_u_max"] == float("inf")
    assert single["least_u_max_record"]["certificate"]["kind"] == "force-span"
    least = v["least_u_max_record"]
    assert v["row"]["least_u_max"] == least["module_params"]["u_max"] == np.max(least["u"]) < P.u_max
    assert least["feasible"] and least["solver"]["objective"] == "bound"


def _lower_bound(entries):
    entries[1]["row"]["least_u_max"] *= 0.99


def _lower_bound_with_its_record(entries):
    _lower_bound(entries)
    entries[1]["least_u_max_record"]["module_params"]["u_max"] *= 0.99


def _bound_for_the_single_module(entries):
    entries[0]["row"].update(least_u_max=1e6, never_feasible="")


def _hidden_proof(entries):
    entries[0]["row"]["never_feasible"] = ""


def _cheaper_at_the_bound(entries):
    entries[1]["row"]["least_u_max_cost"] /= 2


@pytest.mark.parametrize("edit, src, key, fragment", [
    (_lower_bound, "2", "row.least_u_max", "but its record, re-verified, gives"),
    (_lower_bound_with_its_record, "2: least_u_max_record", "feasible",
     "says True, but the design recomputed from the angles and inputs is infeasible: inputs"),
    (_bound_for_the_single_module, "1", "row.least_u_max", "says 1000000.0, but its record, re-verified, gives inf"),
    (_hidden_proof, "1", "row.never_feasible", 'says \'\', but its record, re-verified, gives "every force'),
    (_cheaper_at_the_bound, "2", "row.least_u_max_cost", "but its record, re-verified, gives"),
])
def test_an_edited_least_bound_is_refused(tmp_path, toy_results, edit, src, key, fragment):
    entries = copy.deepcopy(toy_results)
    edit(entries)
    path = _write(tmp_path / "r.jsonl", entries)
    with pytest.raises(ConfigError) as err:
        select(TOY, P, 2, results_path=path, least=True)
    assert err.value.path == f"{path}:{src}" and err.value.key == key and fragment in str(err.value)


def test_cost_against_bound_from_each_least_bound(toy_results):
    rows = [CandidateResult(**e["row"]) for e in toy_results]
    single, v = rows
    np.testing.assert_allclose(bound_grid(rows, P.u_max, 3), [v.least_u_max, (v.least_u_max + 4.8e6) / 2, 4.8e6])
    progress = []
    never, curve = cost_against_bound(TOY, P, rows, np.array([2.5e6, 5e6]),
                                      on_solve=lambda done, total: progress.append((done, total)))
    assert progress == [(1, 2), (2, 2)]  # the single module is never feasible: nothing to solve
    assert never.u_max == () and never.never_feasible == single.never_feasible
    # The least-bound design and the sweep's own design at u_max are points without a solve.
    assert curve.u_max == (v.least_u_max, 2.5e6, P.u_max, 5e6)
    assert curve.cost[0] == v.least_u_max_cost and curve.cost[2] <= v.cost
    assert list(curve.cost) == sorted(curve.cost, reverse=True)  # the least found at each bound or below
