import csv
import json
import math
import re
from pathlib import Path

import pytest
from matplotlib.image import imread

from groundstation.assembly.assembly_file import load_assembly
from groundstation.cli.design_cmd import _print_ranking
from groundstation.design.selection import CandidateResult, SelectedDesign, Selection, results_table

ROOT = Path(__file__).resolve().parents[2]
TOY = str(ROOT / "configs/tasks/toy_push_y.toml")
TOY_V2 = ROOT / "configs/assemblies/toy_v2.json"  # a saved toy design record


def _printed_angles(out: str, code: str) -> list[float]:
    """The best's angles as printed, deg, in the assembly file's order: yaw_deg, then angles_deg."""
    line = next(line for line in out.splitlines() if line.startswith(f"angles of {code} (deg): "))
    return [float(v) for v in re.findall(r"(-?\d+\.\d+)(?:,|$)", line)]


def test_toy_design_outputs(cli, tmp_path):
    out, table, figs = tmp_path / "a.json", tmp_path / "t.csv", tmp_path / "figs"
    code, stdout, err = cli("design", TOY, "--max-modules", "3", "--json", "--out", str(out),
                            "--table", str(table), "--figures", str(figs))
    assert code == 0
    best = json.loads(stdout)
    assert best["n"] == 2 and best["feasible"]
    assembly, _ = load_assembly(out)
    assert assembly.n == 2
    rows = list(csv.DictReader(table.open()))
    assert [(r["n"], r["feasible"]) for r in rows] == [("1", "False"), ("2", "True")]
    assert all(r["least_searched"] == "False" for r in rows)  # the least-bound search only when asked for
    for name in ("fig1_assembly.png", "fig5_costs.png", "fig6_polytope.png"):
        assert imread(figs / name).shape[0] > 300
    assert not (figs / "fig5_cost_vs_u_max.png").exists()


def test_toy_design_prints_the_least_bound(cli, tmp_path):
    table, figs, best = tmp_path / "t.json", tmp_path / "figs", tmp_path / "best.json"
    code, out, _ = cli("design", TOY, "--max-modules", "2", "--table", str(table), "--least-u-max", "--figures",
                       str(figs), "--out", str(best))
    assert code == 0
    assert "n = 1: 0 of 1 candidates feasible (1 certified infeasible, 0 not found feasible)" in out
    assert "n = 2, 1 of 1 candidates feasible; the table shows 1 of 1 candidates" in out
    assert "best oE (7.37" in out and "no runner-up: the only feasible candidate with n = 2" in out
    saved = json.loads(best.read_text())
    assert _printed_angles(out, "oE") == pytest.approx([saved["yaw_deg"], *saved["angles_deg"]], abs=0.005)
    rows = json.loads(table.read_text())
    v = rows[1]["least_u_max"]
    # Never for the single module (one thrust axis: the proof, and JSON's null for inf), below u_max for the V.
    assert rows[0]["least_u_max"] is None and rows[0]["never_feasible"].startswith("every force")
    assert 0 < v < 4e6 and not rows[1]["never_feasible"]
    assert imread(figs / "fig5_cost_vs_u_max.png").shape[0] > 300
    header = next(line for line in out.splitlines() if "code" in line)
    assert "least u_max" in header  # the whole header: not cut to a pipe's 80 columns
    assert f"{v:.5g} ({100 * (v / 4e6 - 1):+.2f}%)" in out


def _result(n: int, code: str, cost: float = math.inf, certificate: str = "") -> CandidateResult:
    return CandidateResult(n, code, "ok", math.isfinite(cost), cost, 0, 1.0, 0.1, 0.05, code, starts=16,
                           feasible_starts=4 if math.isfinite(cost) else 0, optima=1, certificate=certificate)


def test_the_ranking_says_what_it_shows_and_prints_every_cell_whole(capsys):
    """12 feasible candidates with codes long enough that the table is wider than any fixed console, a certified
    and two uncertified infeasible ones, and a smaller n; stdout is not a terminal (a pipe)."""
    record = json.loads(TOY_V2.read_text())
    best = _result(2, "oS", record["cost"])
    feasible = [best] + [_result(2, "o" + "S(W)" * 20 + "E" * k, record["cost"] * (1 + k / 100)) for k in range(1, 12)]
    proof = "every force of every design lies along one line"
    others = [_result(2, "oEEE", certificate=proof), _result(2, "oSEN"), _result(2, "oS(W)E"),
              _result(1, "o", certificate=proof)]
    sel = Selection(SelectedDesign.of(best, record, str(TOY_V2)), 2, tuple(feasible + others))
    _print_ranking(sel, "t", results_table(sel.results), 4e6, least=False)
    out = capsys.readouterr().out
    assert "n = 1: 0 of 1 candidates feasible (1 certified infeasible, 0 not found feasible)" in out
    assert "t: n = 2, 12 of 15 candidates feasible; the table shows 10 of 15 candidates (the 10 best of the 12 " \
           "feasible; --table FILE has every row)" in out
    table = [line for line in out.splitlines() if line.startswith(("┃", "│"))]
    assert len(table) == 1 + 10
    assert [line.split("│")[1].strip() for line in table[1:]] == [r.code for r in feasible[:10]]  # whole codes
    assert "…" not in out and len({len(line) for line in table}) == 1 and len(table[0]) > 140
    assert f"  oEEE: infeasible: {proof}\n" in out  # certified: infeasible, with the proof
    for code in ("oSEN", "oS(W)E"):  # no certificate: nothing is proven
        assert f"  {code}: not found feasible: no start met the wrenches (least residual 0.05, 16 starts)\n" in out
    assert f"best oS ({record['cost']:.5g}); runner-up {feasible[1].code} ({feasible[1].cost:.5g}, +1.00 %)" in out
    assert _printed_angles(out, "oS") == pytest.approx([record["yaw_deg"], *record["angles_deg"]], abs=0.005)


def test_least_bound_cell():
    from groundstation.cli.design_cmd import _least_bound

    assert _least_bound({"least_u_max": float("inf"), "never_feasible": "one plane"}, 4e6) == "never"
    assert _least_bound({"least_u_max": float("inf"), "never_feasible": ""}, 4e6) == "none found"
    assert _least_bound({"least_u_max": 4.0568e6, "never_feasible": ""}, 4e6) == "4.0568e+06 (+1.42%)"


def test_infeasible_within_max(cli):
    code, out, err = cli("design", TOY, "--max-modules", "1")
    assert code == 1 and "no feasible design with up to 1 modules" in err


@pytest.mark.parametrize("args, fragment", [
    (["design", TOY, "--max-modules", "0"], "--min-modules <= --max-modules"),
    (["design", TOY, "--workers", "0"], "--workers must be 1 to 256, got 0"),
    (["design", TOY, "--workers", "1000000"], "--workers must be 1 to 256, got 1000000"),
    (["design", TOY, "--results", "r.txt"], "unsupported file type"),
    (["design", "missing.toml"], "missing.toml: file not found"),
    (["design", TOY, "--sample", "2", "--sigma", "nan"], "Invalid value for '--sigma': 'nan' is not a finite"),
    (["design", TOY, "--sample", "2", "--seed", "-5"], "--seed': -5 is not in the range x>=0"),
    (["design", "/dev/zero"], "/dev/zero: not a text file"),
])
def test_bad_input(cli, args, fragment):
    code, out, err = cli(*args)
    assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1, err


def test_a_scheduler_that_is_not_there_is_one_line(cli, tmp_path):
    """Not an address, or nobody listening (a 20 s wait): before, distributed's traceback."""
    code, _, err = cli("design", TOY, "--scheduler", "junk", "--results", str(tmp_path / "r.jsonl"))
    assert code == 2 and err == ("groundstation: error: cannot reach the Dask scheduler junk: missing port number in "
                                 "address 'junk'\n"), err


def test_an_edited_results_file_is_refused(cli, tmp_path):
    results = tmp_path / "r.jsonl"
    code, _, _ = cli("design", TOY, "--max-modules", "2", "--results", str(results))
    assert code == 0
    lines = results.read_text().splitlines()
    entry = json.loads(lines[0])  # the single module: infeasible
    entry["row"].update(feasible=True, cost=1.0)
    results.write_text(json.dumps(entry) + "\n" + lines[1] + "\n")
    out_file = tmp_path / "best.json"
    code, out, err = cli("design", TOY, "--max-modules", "2", "--results", str(results), "--out", str(out_file))
    assert code == 2 and not out_file.exists() and "best" not in out
    assert err == f"groundstation: error: {results}:1: row.feasible: says True, but its record, re-verified, " \
                  "gives False\n"


IV_C = str(ROOT / "configs/tasks/paper_iv_c_three_wrenches.toml")


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines() if path.exists() else []


@pytest.mark.parametrize("workers", ["1", "2"])
def test_ctrl_c_stops_a_sweep_and_the_rerun_resumes(cli, tmp_path, workers):
    """Ctrl-C (SIGINT to the terminal's process group) stops the sweep: exit 130, finished candidates kept."""
    import os
    import signal
    import subprocess
    import sys
    import time

    results = tmp_path / "r.jsonl"
    args = ["design", IV_C, "--min-modules", "4", "--max-modules", "4", "--results", str(results),
            "--workers", workers]
    proc = subprocess.Popen([sys.executable, "-m", "groundstation", *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 300
    while not _lines(results) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "run the same command to resume" in err and "Traceback" not in err
    kept = _lines(results)
    assert 1 <= len(kept) < 7  # stopped before the end of the 7 candidates
    assert all(json.loads(line)["row"]["code"] for line in kept)  # whole rows only, even from a terminated pool
    if workers == "2":
        return  # the rerun is the same code for either (and solves the rest of the sweep: 12 s of CI)
    code, out, err = cli(*args)
    assert code == 0 and "best oSEE" in out
    after = _lines(results)
    assert len(after) == 7 and after[:len(kept)] == kept  # resumed: nothing solved twice, nothing lost
