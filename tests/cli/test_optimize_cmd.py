import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
TOY = str(ROOT / "configs/tasks/toy_push_y.toml")



def test_json_result_keys(cli, tmp_path):
    out_file = tmp_path / "a.json"
    code, out, err = cli("optimize", TOY, "--topology", "oS", "--json", "--out", str(out_file))
    rec = json.loads(out)
    assert code == 0
    for key in ("status", "feasible", "n", "cost", "angles_deg", "modules", "rotors", "u", "wrenches",
                "module_params"):
        assert key in rec
    assert rec["feasible"] and rec["n"] == 2 and len(rec["rotors"]) == 8 and len(rec["u"]) == 3
    assert abs(rec["angles_deg"][0]) == pytest.approx(22.5, abs=0.1)
    assert json.loads(out_file.read_text())["cost"] == rec["cost"]
    # u follows the order of rotors: module-major
    assert [r["module"] for r in rec["rotors"]] == [0] * 4 + [1] * 4
    assert np.allclose(np.linalg.norm([r["axis"] for r in rec["rotors"]], axis=1), 1)


def test_infeasible_exit_code(cli, tmp_path):
    task = tmp_path / "t.toml"
    task.write_text('[[wrench]]\nforce = [3.0, 0.0, 0.0]\n[[wrench]]\nforce = [-3.0, 0.0, 0.0]\n')
    code, out, err = cli("optimize", str(task), "--topology", "o", "--starts", "0")
    assert code == 1 and "no feasible design" in err and "Traceback" not in err


@pytest.mark.parametrize("args, fragment", [
    (["optimize", TOY, "--topology", "oQ"], "--topology"),
    (["optimize", TOY, "--topology", "oE", "--starts", "a,b"], "--starts"),
    (["optimize", "missing.toml", "--topology", "oE"], "missing.toml: file not found"),
    (["optimize", TOY, "--topology", "oE", "--starts", "nan"], "Invalid value for '--starts': 'nan' is not a finite"),
    (["optimize", TOY, "--topology", "oE", "--starts", "20,1e400"], "'--starts': inf is not in the range"),
    (["optimize", TOY, "--topology", "oE", "--starts", "120"], "--starts': 120.0 is not in the range -90<=x<=90"),
    (["optimize", TOY, "--topology", "oE", "--seed", "-1"], "--seed': -1 is not in the range x>=0"),
    (["optimize", "/dev/zero", "--topology", "oE"], "/dev/zero: not a text file"),
])
def test_bad_input(cli, args, fragment):
    code, out, err = cli(*args)
    assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1
