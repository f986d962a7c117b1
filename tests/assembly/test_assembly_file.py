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
