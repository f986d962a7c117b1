import json
import subprocess
import sys

import pytest

from groundstation.design.candidates import read_candidates


def test_json_lines(cli):
    code, out, err = cli("enumerate", "7", "--json")
    rows = [json.loads(line) for line in out.splitlines()]
    assert code == 0
    assert [r["n"] for r in rows] == list(range(1, 8))
    assert [r["available"] for r in rows] == [1, 4, 6, 16, 68, 272, 1242]
    assert [r["non_isomorphic"] for r in rows] == [1, 1, 2, 7, 24, 97, 401]
    assert all(r["cpu_s"] >= 0 for r in rows)


def test_table_and_out_and_draw(cli, tmp_path):
    out_file, png = tmp_path / "c.json", tmp_path / "n5.png"
    code, out, err = cli("enumerate", "5", "--out", str(out_file), "--draw", str(png))
    assert code == 0 and "non-isomorphic" in out and "24" in out
    assert len(read_candidates(out_file).levels[5]) == 24
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_sampled_json(cli):
    code, out, _ = cli("enumerate", "9", "--sample", "100", "--seed", "3", "--json")
    last = json.loads(out.splitlines()[-1])
    assert code == 0 and last["kept"] == 100 and last["non_isomorphic"] > 100


@pytest.mark.parametrize("args, fragment", [
    (["enumerate", "0"], "at least 1"),
    (["enumerate", "4", "--symmetry", "C3"], "unknown symmetry group"),
    (["enumerate", "4", "--sample", "0"], "at least 1"),
    (["enumerate", "4", "--out", "/nonexistent-dir/x.json"], "does not exist"),
    (["enumerate", "4", "--out", "x.csv"], "unsupported file type"),
    (["enumerate", "4", "--scheme", "spread"], "only apply with --sample"),
    (["enumerate", "four"], "not a valid integer"),
])
def test_bad_input_one_line_nonzero(cli, args, fragment):
    code, out, err = cli(*args)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0] and "Traceback" not in err


def test_module_entry_point_runs():
    res = subprocess.run([sys.executable, "-m", "groundstation", "enumerate", "3", "--json"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0
    assert [json.loads(x)["non_isomorphic"] for x in res.stdout.splitlines()] == [1, 1, 2]
