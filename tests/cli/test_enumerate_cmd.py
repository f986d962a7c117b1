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
    (["enumerate", "4", "--symmetry", "C3"], "'C3' is not one of 'C4', 'D4', 'none'"),
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


@pytest.mark.parametrize("args, fragment", [
    (["enumerate", "5", "--sample", "3", "--sigma", "nan"], "Invalid value for '--sigma': 'nan' is not a finite"),
    (["enumerate", "5", "--sample", "3", "--sigma", "inf"], "Invalid value for '--sigma': 'inf' is not a finite"),
    (["enumerate", "5", "--sample", "3", "--seed", "-1"], "Invalid value for '--seed': -1 is not in the range"),
])
def test_absurd_options(cli, args, fragment):
    code, out, err = cli(*args)
    assert code == 2 and out == "" and err.count("\n") == 1 and fragment in err, err


def test_ctrl_c_prints_the_finished_levels(cli, monkeypatch, tmp_path):
    """The table mode prints the levels finished before Ctrl-C (``--json`` printed them as they came); an ``--out``
    asked for is said not written (campaign 26: nothing said)."""
    from groundstation.design import enumeration

    levels = enumeration.enumerate_levels

    def interrupted_after_4(*args, **kwargs):
        for level in levels(*args, **kwargs):
            yield level
            if level.n == 4:
                raise KeyboardInterrupt

    monkeypatch.setattr(enumeration, "enumerate_levels", interrupted_after_4)
    code, out, err = cli("enumerate", "8")
    assert code == 130 and "Traceback" not in err
    assert [line.split()[1] for line in out.splitlines() if line.startswith("│")] == ["1", "2", "3", "4"]
    assert "enumeration stopped in level 5; levels 1 to 4 are complete" in err
    out_file = tmp_path / "levels.json"
    code, out, err = cli("enumerate", "8", "--out", str(out_file))
    assert code == 130 and f"levels 1 to 4 are complete; {out_file} not written\n" in err
    assert not out_file.exists()


@pytest.mark.parametrize("symmetry", ["C4", "D4", "none"])
def test_the_largest_drawable_level_is_the_last_within_the_draw_limit(symmetry):
    from groundstation.cli.enumerate_cmd import LARGEST_DRAWABLE
    from groundstation.design.drawing import MAX_DRAWN
    from groundstation.design.enumeration import enumerate_levels

    counts = [lv.non_isomorphic for lv in enumerate_levels(LARGEST_DRAWABLE[symmetry] + 1, symmetry)]
    assert counts[-2] <= MAX_DRAWN < counts[-1]


def test_a_level_too_large_to_draw_is_refused_before_enumerating(cli, tmp_path):
    """n = 40 would enumerate for longer than anyone waits: the refusal comes first, and nothing is drawn."""
    png = tmp_path / "n40.png"
    code, out, err = cli("enumerate", "40", "--draw", str(png))
    assert code == 2 and out == "" and not png.exists()
    assert err.strip() == ("groundstation: error: --draw: level n=40 (C4) has more than 1000 configurations, too "
                           "many to draw; draw n <= 7, or sample it (--sample 1000 or less)")
    code, _, err = cli("enumerate", "9", "--sample", "30", "--draw", str(tmp_path / "n9.png"))
    assert code == 0 and (tmp_path / "n9.png").read_bytes()[:4] == b"\x89PNG"
