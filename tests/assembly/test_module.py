import dataclasses
from pathlib import Path

import pytest

from groundstation.assembly.module import ModuleParams, load_module_params
from groundstation.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]


def test_shipped_module_files_load_and_match_table_ii():
    files = sorted((ROOT / "configs" / "modules").glob("*.toml"))
    assert files
    for f in files:
        load_module_params(f)
    p = load_module_params(ROOT / "configs/modules/paper_table2.toml")
    assert dataclasses.replace(p, motor_command=None) == ModuleParams()  # defaults are Table II
    assert p.motor_command.platform == "bolt"
    assert (p.mass, p.c_f, p.c_m, p.l_arm, p.l_c, p.r) == (0.24, 3.87e-7, 1.06e-8, 0.06, 0.11, 0.095)
    assert p.capsule_a == pytest.approx(p.r / 2) and p.capsule_b == pytest.approx(p.r / 2 + 10 * p.l_arm)
    assert p.max_thrust_per_module / (p.mass * 9.81) == pytest.approx(2.63, abs=0.01)


@pytest.mark.parametrize("text, key", [
    ("mass = 0.24\nthrust = 3\n", "thrust"),
    ("c_f = -1.0\n", "c_f"),
    ("r = 'wide'\n", "r"),
    # beyond a module's physics (module.py's bounds): optimize overflowed, or took them (inertia 1e-300, exit 0)
    ("mass = 1e300\n", "mass"), ("mass = 0.001\n", "mass"), ("l_arm = 1e300\n", "l_arm"), ("l_c = 1e-9\n", "l_c"),
    ("c_m = 1e300\n", "c_m"), ("c_m = 1e-12\n", "c_m"),
    ("inertia = [1e-300, 1e-300, 1e-300]\n", "inertia"),
    ("inertia = [1.0, 1.0, 1.0]\n", "inertia"),  # a radius of gyration of 2 m for a module 0.22 m across
    ("inertia = [1e-4, 1e-4, 1e-3]\n", "inertia"),  # one principal moment above the sum of the other two
    ("frame_half_extents = [0.085, 0.085, 1e-9]\n", "frame_half_extents.2"),
])
def test_bad_module_file_names_file_and_key(tmp_path, text, key):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_module_params(f)
    assert err.value.key == key and str(f) in str(err.value)


def test_capsule_bounds_must_be_ordered(tmp_path):
    f = tmp_path / "m.toml"
    f.write_text("capsule_a = 0.5\ncapsule_b = 0.1\n")
    with pytest.raises(ConfigError, match="capsule_b must be greater"):
        load_module_params(f)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_module_params(tmp_path / "nope.toml")
    f = tmp_path / "broken.toml"
    f.write_text("mass = = 1")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_module_params(f)
