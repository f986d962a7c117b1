import json
from pathlib import Path

import numpy as np
import pytest

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.assembly_file import (
    LEGACY_FIGURES,
    assembly_record,
    checked_record,
    flown_assembly,
    load_assembly,
    save_assembly,
)
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.assembly.verification import input_cost
from groundstation.errors import ConfigError

HERE = Path(__file__).resolve().parent
ROOT = Path(__file__).resolve().parents[2]
P = ModuleParams()


SHIPPED = sorted((ROOT / "configs/assemblies").glob("*.json"))
TOY = ROOT / "configs/assemblies/toy_v2.json"


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_every_shipped_assembly_loads_and_reverifies(path):
    rec = json.loads(path.read_text())
    assembly, design = checked_record(rec, str(path))
    assert rec["feasible"] and rec["verification"]["feasible"] and assembly.n == rec["n"]
    assert input_cost(design.u, design.weights) == pytest.approx(rec["cost"], rel=1e-12)
    ver = design.verification
    assert ver.max_wrench_residual <= ver.residual_tolerance and ver.max_bound_violation == 0
    assert ver.feasible and ver.min_capsule_distance >= 2 * P.r  # exactly: no shipped design relies on a slack


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
    (lambda r: r["topology"]["edges"][0].__setitem__(0, bool(r["topology"]["edges"][0][0])), "topology.edges"),
    (lambda r: r["topology"]["edges"].pop(), "topology.edges"),
    (lambda r: r["topology"]["cells"][1].__setitem__(1, float(r["topology"]["cells"][1][1])), "topology.cells"),
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


def _scaled_u(r, factor):
    r["u"] = (np.array(r["u"]) * factor).tolist()


def _swap_verification_fields(r):
    r["verification"]["min_capsule_distance"] = 0.25


@pytest.mark.parametrize("edit, key, fragment", [
    (lambda r: r.update(n=3), "n", "says 3, but oS has 2 modules"),
    (lambda r: r.update(mass_kg=4.8), "mass_kg", "says 4.8 kg, but 2 modules of 0.24 kg make 0.48 kg"),
    (lambda r: r.update(inertia_kg_m2=(2 * np.array(r["inertia_kg_m2"])).tolist()), "inertia_kg_m2", "disagrees"),
    (lambda r: r.update(controllable_dof=6), "controllable_dof", "says 6, but the allocation matrix has rank 5"),
    (lambda r: r["rotors"][5].update(position=[0.0, 0.0, 0.0]), "rotors[5].position", "disagrees"),
    (lambda r: r["rotors"][3].update(spin=-r["rotors"][3]["spin"]), "rotors[3].spin", "disagrees"),
    (lambda r: r["rotors"][6].update(axis=[0, 0, 1]), "rotors[6].axis", "disagrees"),
    (lambda r: r["rotors"].pop(), "rotors", "expected 8 rotors"),
    (lambda r: r.update(yaw_deg="north"), "yaw_deg", 'not a number: "north"'),
    (lambda r: _scaled_u(r, 1.001), "feasible", "says True, but the design recomputed from the angles and inputs is "
                                                 "infeasible: wrench residual"),
    (lambda r: r["u"][0].__setitem__(0, -10.0), "feasible", "inputs 10 rad^2/s^2 outside [0, u_max]"),
    (lambda r: r["wrenches"][1].__setitem__(0, 0.5), "feasible", "wrench residual 0.5 above"),
    (lambda r: r.update(feasible=False), "feasible", "says False, but the design recomputed from the angles and "
                                                     "inputs is feasible: every check passes"),
    (lambda r: r.update(cost=r["cost"] / 2), "cost", "but the inputs cost 7.37546364e+13"),
    (lambda r: r.update(cost=None), "cost", "says None"),
    (_swap_verification_fields, "verification.min_capsule_distance", "says 0.25, recomputed 0.2396"),
    (lambda r: r["verification"].update(feasible=False), "verification.feasible", "says False where feasible"),
    (lambda r: r.pop("u"), "u", "missing"),
    (lambda r: r.update(weights=[1.0]), "weights", "expected 3 numbers, got 1"),
    (lambda r: r.update(mass_kg="NaN"), "mass_kg", 'not a number: "NaN"'),  # a string: numpy would take it
    (lambda r: r.update(angles_deg=[0.0, "inf", 0.0]), "angles_deg", 'not a number: "inf"'),
])
def test_a_tampered_design_file_is_refused_naming_the_key(tmp_path, edit, key, fragment):
    rec = json.loads(TOY.read_text())
    edit(rec)
    path = tmp_path / "tampered.json"
    path.write_text(json.dumps(rec))
    with pytest.raises(ConfigError) as err:
        load_assembly(path)
    assert err.value.key == key and str(err.value).startswith(f"{path}: {key}: ") and fragment in str(err.value)


def test_a_design_written_under_the_old_clearance_rule_is_refused():
    """The Fig. 1 design as shipped before (``data/legacy_paper_fig1_n12.json``, kept as it was written) was
    verified when 2 r - 1e-6 m passed and is 2.0e-9 m inside 2 r: refused, naming ``feasible`` and the distance;
    the design shipped now (the README's command) loads."""
    rec = json.loads((HERE / "data/legacy_paper_fig1_n12.json").read_text())
    assert set(rec["verification"]) == LEGACY_FIGURES and rec["feasible"] is True
    with pytest.raises(ConfigError) as err:
        load_assembly(HERE / "data/legacy_paper_fig1_n12.json")
    assert err.value.key == "feasible" and "capsule axes 0.189999998 m apart, under 2 r = 0.19 m" in str(err.value)
    fig1, _ = load_assembly(ROOT / "configs/assemblies/paper_fig1_n12.json")
    assert fig1.n == 12


def test_a_flown_assembly_is_its_geometry_without_the_design_verdict():
    """What a flight log's record rebuilds (``replay --rerun``: a log is history): the legacy Fig. 1 design,
    refused as a file, gives its geometry; that geometry is checked as on load (a wrong mass is refused naming the
    key)."""
    rec = json.loads((HERE / "data/legacy_paper_fig1_n12.json").read_text())
    assembly = flown_assembly(rec, "log")
    assert assembly.n == 12 and np.allclose(np.degrees(assembly.alpha), rec["angles_deg"])
    rec["mass_kg"] *= 2
    with pytest.raises(ConfigError) as err:
        flown_assembly(rec, "log")
    assert err.value.key == "mass_kg"
