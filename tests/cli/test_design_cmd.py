import csv
import json
from pathlib import Path

import pytest
from matplotlib.image import imread

from groundstation.assembly.assembly_file import load_assembly

ROOT = Path(__file__).resolve().parents[2]
TOY = str(ROOT / "configs/tasks/toy_push_y.toml")



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
    for name in ("fig1_assembly.png", "fig5_costs.png", "fig6_polytope.png"):
        assert imread(figs / name).shape[0] > 300


def test_infeasible_within_max(cli):
    code, out, err = cli("design", TOY, "--max-modules", "1")
    assert code == 1 and "no feasible design with up to 1 modules" in err


@pytest.mark.parametrize("args, fragment", [
    (["design", TOY, "--max-modules", "0"], "--min-modules <= --max-modules"),
    (["design", TOY, "--workers", "0"], "--workers must be at least 1"),
    (["design", TOY, "--results", "r.txt"], "unsupported file type"),
    (["design", "missing.toml"], "missing.toml: file not found"),
])
def test_bad_input(cli, args, fragment):
    code, out, err = cli(*args)
    assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1, err
