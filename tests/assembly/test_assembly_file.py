import json
from pathlib import Path

import numpy as np
import pytest

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.assembly_file import assembly_record, load_assembly, save_assembly
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]


def test_every_shipped_assembly_loads_and_is_feasible():
    files = sorted((ROOT / "configs/assemblies").glob("*.json"))
    assert files
    for f in files:
        assembly, rec = load_assembly(f)
        assert rec["feasible"] and rec["verification"]["feasible"]
        assert assembly.n == rec["n"]


def _axis_distance(p0, p1, q0, q1, samples=400):
    """Brute-force distance between two segments (independent of the package's closed form), m."""
    s = np.linspace(0.0, 1.0, samples)[:, None]
    a, b = p0 + s * (p1 - p0), q0 + s * (q1 - q0)
    return float(np.min(np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)))


@pytest.mark.parametrize("path", sorted((ROOT / "configs/assemblies").glob("*.json")), ids=lambda p: p.stem)
def test_shipped_assembly_meets_its_task_recomputed_from_the_saved_poses(path):
    """Wrenches and clearances recomputed rotor by rotor and pair by pair from the file's explicit poses."""
    rec = json.loads(path.read_text())
    p = rec["module_params"]
    u = np.array(rec["u"])
    assert u.min() >= 0 and u.max() <= p["u_max"] * (1 + 1e-9)
    for u_k, b_k in zip(u, rec["wrenches"], strict=True):
        force, torque = np.zeros(3), np.zeros(3)
        for rotor, u_i in zip(rec["rotors"], u_k, strict=True):
            f = p["c_f"] * u_i * np.array(rotor["axis"])
            force += f
            torque += np.cross(rotor["position"], f) + rotor["spin"] * p["c_m"] * u_i * np.array(rotor["axis"])
        np.testing.assert_allclose(np.concatenate([force, torque]), b_k, atol=1e-6 * np.abs(b_k).max())
    axes = [(np.array(m["position"]) - p["capsule_a"] * np.array(m["rotation"])[:, 2],
             np.array(m["position"]) - p["capsule_b"] * np.array(m["rotation"])[:, 2]) for m in rec["modules"]]
    length = p["capsule_b"] - p["capsule_a"]
    mids = [(a + b) / 2 for a, b in axes]
    # Segments whose midpoints are farther apart than a length plus the clearance cannot come closer than 2 r.
    near = [(i, j) for i in range(len(axes)) for j in range(i + 1, len(axes))
            if np.linalg.norm(mids[i] - mids[j]) < length + 2 * p["r"] + 0.1]
    # Coarse sampling overestimates a distance by at most one sample spacing; refine only the pairs it finds close.
    coarse = {(i, j): _axis_distance(*axes[i], *axes[j], samples=50) for i, j in near}
    worst = min(_axis_distance(*axes[i], *axes[j]) if d < 2 * p["r"] + 0.1 else d for (i, j), d in coarse.items())
    assert worst >= 2 * p["r"] - 2e-3  # sampling resolution 0.6 m / 400 along each axis
    assert worst == pytest.approx(rec["verification"]["min_capsule_distance"], abs=2e-3)


def test_round_trip(tmp_path):
    a = Assembly(Topology.from_code("oES"), ModuleParams(), np.radians([5, -3, 20, -15]), 0.4)
    path = save_assembly(tmp_path / "a.json", assembly_record(a))
    b, _ = load_assembly(path)
    np.testing.assert_allclose(b.allocation, a.allocation, atol=1e-12)
    assert b.topology == a.topology and b.params == a.params


@pytest.mark.parametrize("edit, key", [
    (lambda r: r["modules"][1].update(position=[9, 9, 9]), "modules[1].position"),
    (lambda r: r.update(angles_deg=[0, 0]), "angles_deg"),
    (lambda r: r.update(angles_deg=[0, 0, 120, 0]), "angles_deg"),
    (lambda r: r["module_params"].update(mass=-1), "module_params.mass"),
    (lambda r: r["topology"].update(code="oX"), "topology.code"),
    (lambda r: r.pop("modules"), "modules"),
    (lambda r: r.update(format="other"), "format"),
])
def test_tampered_files_name_the_key(tmp_path, edit, key):
    a = Assembly(Topology.from_code("oES"), ModuleParams(), np.radians([5, -3, 20, -15]))
    rec = assembly_record(a)
    edit(rec)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(rec))
    with pytest.raises(ConfigError) as err:
        load_assembly(path)
    assert err.value.key == key and str(path) in str(err.value)
