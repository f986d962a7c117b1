"""Assembly files (``configs/assemblies/*.json``): what design writes and every later stage loads.

One JSON object holding the module parameters, the topology, the angles, the explicit module poses and rotor
geometry (for readers that do not recompute kinematics), and, for designed assemblies, the design record: the
wrench set solved, inputs, cost, solver statistics and the verification figures. Loading recomputes the poses
from the angles and rejects a file whose stored poses disagree, naming the key.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from groundstation import config
from groundstation.assembly.assembly import Assembly
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.errors import ConfigError, TopologyError
from groundstation.output import writing

FORMAT = "groundstation.assembly/1"
POSE_TOLERANCE = 1e-6
"""Largest disagreement between stored and recomputed poses accepted on load, m (or unitless for rotations)."""


def assembly_record(assembly: Assembly) -> dict:
    """The geometric part of an assembly file, as a JSON-ready dict."""
    topo = assembly.topology
    return {
        "format": FORMAT,
        "n": topo.n,
        "topology": {"code": topo.code, "cells": [list(c) for c in topo.cells], "edges": [list(e) for e in topo.edges]},
        "module_params": asdict(assembly.params),
        "angles_deg": np.degrees(assembly.alpha).tolist(),
        "yaw_deg": float(np.degrees(assembly.yaw)),
        "modules": [{"position": p.tolist(), "rotation": r.tolist()}
                    for p, r in zip(assembly.module_positions, assembly.module_rotations, strict=True)],
        "rotors": [{"module": k // 4, "position": p.tolist(), "axis": a.tolist(), "spin": int(s)}
                   for k, (p, a, s) in enumerate(zip(assembly.rotor_positions, assembly.rotor_axes,
                                                     assembly.rotor_spin, strict=True))],
        "mass_kg": assembly.mass,
        "inertia_kg_m2": assembly.inertia.tolist(),
        "controllable_dof": assembly.controllable_dof,
    }


def save_assembly(path: str | Path, record: dict) -> Path:
    """Write an assembly record (from :func:`assembly_record`, optionally with design fields) as JSON."""
    p = Path(path)
    with writing(p):
        p.write_text(json.dumps(record, indent=1) + "\n")
    return p


def load_assembly(path: str | Path) -> tuple[Assembly, dict]:
    """Load and validate an assembly file; returns the assembly and the whole record."""
    p = Path(path)
    record = config.read_json(p)  # capped: a log or /dev/zero given as an assembly is one line, not a hang
    return assembly_from_record(record, str(p)), record


def assembly_from_record(record, src: str) -> Assembly:
    """Validate an assembly record (an assembly file's content, or a flight log's ``assembly`` metadata); errors
    name ``src`` and the key."""
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise ConfigError(f"expected format {FORMAT!r}", path=src, key="format")
    for key in ("module_params", "topology", "angles_deg", "modules"):
        if key not in record:
            raise ConfigError("missing", path=src, key=key)
    params = config.validate(ModuleParams, record["module_params"], path=src, prefix="module_params")
    try:
        topo = Topology.from_code(record["topology"]["code"])
    except (KeyError, TypeError, TopologyError) as exc:
        raise ConfigError(f"invalid topology: {exc}", path=src, key="topology.code") from None
    if [list(c) for c in topo.cells] != record["topology"].get("cells", [list(c) for c in topo.cells]):
        raise ConfigError("cells disagree with the topology code", path=src, key="topology.cells")
    alpha = np.radians(np.asarray(record["angles_deg"], dtype=float))
    if alpha.shape != (topo.n + 1,) or not np.all(np.isfinite(alpha)):
        raise ConfigError(f"expected {topo.n + 1} finite angles", path=src, key="angles_deg")
    if np.any(np.abs(alpha) > np.pi / 2 + 1e-9):
        raise ConfigError("angles must lie in [-90, 90] degrees", path=src, key="angles_deg")
    assembly = Assembly(topo, params, alpha, float(np.radians(record.get("yaw_deg", 0.0))))
    modules = record["modules"]
    if len(modules) != topo.n:
        raise ConfigError(f"expected {topo.n} modules", path=src, key="modules")
    for i, m in enumerate(modules):
        for name, derived in (("position", assembly.module_positions[i]), ("rotation", assembly.module_rotations[i])):
            try:
                stored = np.asarray(m[name], dtype=float)
            except (KeyError, TypeError, ValueError):
                raise ConfigError("missing or not numeric", path=src, key=f"modules[{i}].{name}") from None
            if stored.shape != derived.shape or np.max(np.abs(stored - derived)) > POSE_TOLERANCE:
                raise ConfigError("disagrees with the pose computed from the angles", path=src,
                                  key=f"modules[{i}].{name}")
    if "u" in record:
        u = np.asarray(record["u"], dtype=float)
        if u.ndim != 2 or u.shape[1] != 4 * topo.n:
            raise ConfigError(f"expected one list of {4 * topo.n} inputs per wrench", path=src, key="u")
    return assembly
