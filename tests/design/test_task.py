from pathlib import Path

import numpy as np
import pytest

from groundstation.assembly.module import ModuleParams
from groundstation.design.task import load_task, random_task
from groundstation.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
P = ModuleParams()


def test_every_shipped_task_loads():
    files = sorted((ROOT / "configs/tasks").glob("*.toml"))
    assert len(files) >= 6
    for f in files:
        b, w = load_task(f).wrenches_for(4, P)
        assert b.shape[1] == 6 and len(w) == len(b) and np.all(np.isfinite(b))


def test_paper_modifications():
    nmg = 4 * P.mass * 9.81
    b, w = load_task(ROOT / "configs/tasks/paper_iv_c_three_wrenches.toml").wrenches_for(4, P)
    np.testing.assert_allclose(b[:, :3], [[0.5 * nmg, 0, nmg], [0, 0.5 * nmg, nmg], [0, 0, nmg]])
    np.testing.assert_allclose(b[:, 3:], 0)
    np.testing.assert_allclose(w, 1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_sets_match_generator_and_ranges(seed):
    shipped = load_task(ROOT / f"configs/tasks/random10_seed{seed}.toml")
    assert shipped == random_task(seed)
    b, _ = shipped.wrenches_for(10, P)
    nmg = 10 * P.mass * 9.81
    assert len(b) == 10
    assert np.all(np.abs(b[:, :2]) <= 0.2 * nmg) and np.all((b[:, 2] >= 0.9 * nmg) & (b[:, 2] <= 1.1 * nmg))
    assert np.all(np.abs(b[:, 3:]) <= 0.1 * P.l_c * nmg + 1e-12)


@pytest.mark.parametrize("text, key", [
    ('units = "N"\n', "wrench"),
    ('[[wrench]]\nforce = [0, 1]\n', "wrench.0.force"),
    ('[[wrench]]\nforce = [0, 1, 0]\nspeed = 3\n', "wrench.0.speed"),
    ('units = "lbf"\n[[wrench]]\nforce = [0, 1, 0]\n', "units"),
    ('[[wrench]]\nforce = [0, nan, 0]\n', "wrench.0.force"),
])
def test_malformed_task_names_file_and_key(tmp_path, text, key):
    f = tmp_path / "t.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_task(f)
    assert err.value.key.startswith(key) and str(f) in str(err.value)
