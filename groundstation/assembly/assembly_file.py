"""Assembly files (``configs/assemblies/*.json``): what design writes and every later stage loads.

One JSON object holding the module parameters, the topology, the angles, the explicit module poses and rotor
geometry (for readers that do not recompute kinematics), and, for designed assemblies, the design record: the
wrench set solved, inputs, cost, solver statistics and the verification figures.

Loading trusts nothing but the topology, the module parameters and the angles: everything else is derived from
them and the file is refused, naming the key, when a stored value disagrees: the poses, the rotors, ``n``, the
mass, the inertia, the controllable degrees of freedom and, for a designed assembly, the full verification of its
inputs against its wrenches (:mod:`groundstation.assembly.verification`), its ``feasible`` flag, its cost and its
verification figures. A file that says ``n = 3`` or ``mass_kg = 4.8`` over a two-module geometry, or
``feasible`` over inputs that miss their wrenches, does not fly as something else without a word. A flight log's
record is history: replay rebuilds what flew from its geometry alone (:func:`flown_assembly`), whatever today's
rules say of its design.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from groundstation import config
from groundstation.assembly.assembly import Assembly
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.assembly.verification import ANGLE_TOLERANCE, Verification, input_cost, verify
from groundstation.errors import ConfigError, TopologyError
from groundstation.output import writing

FORMAT = "groundstation.assembly/1"
POSE_TOLERANCE = 1e-6
"""Largest disagreement between stored and recomputed poses, rotor positions and axes, and capsule clearance
accepted on load, m (or unitless for rotations and axes)."""
DERIVED_RTOL = 1e-6
"""Largest relative disagreement between the stored and the derived mass and inertia."""
COST_RTOL = 1e-9
"""Largest relative disagreement between a stored cost and the one recomputed from the stored inputs (the same
sum of the same numbers: only rounding)."""
GEOMETRY_KEYS = ("module_params", "topology", "angles_deg", "yaw_deg", "modules", "n", "rotors", "mass_kg",
                 "inertia_kg_m2", "controllable_dof")
"""Keys every assembly record has (:func:`assembly_record` writes them all)."""
DESIGN_KEYS = ("wrenches", "weights", "u", "feasible", "cost", "verification")
"""Keys of a designed assembly (``Design.record``): all of them or none."""
LEGACY_FIGURES = frozenset(("max_wrench_residual", "max_bound_violation", "max_angle_violation",
                            "min_capsule_distance", "required_distance", "feasible"))
"""The verification figures of records written before the verification kept its tolerances (``toy_v2``). They are
checked by today's exact rules like every other record: the code that wrote them accepted a clearance of
``2 r - 1e-6 m``, and designs it shipped 2.0-2.1e-9 m inside ``2 r`` were solved again and re-shipped
(``paper_fig1_n12``, ``random10_seed0_n30``/``n60``; a user's file of that kind is refused naming ``feasible``:
solve it again)."""


@dataclass(frozen=True, eq=False)
class CheckedDesign:
    """The design part of a record, re-verified from its angles and inputs."""

    wrenches: np.ndarray
    """(K, 6) wrenches the design was solved for: force (N) then torque (N m), body frame."""
    weights: np.ndarray
    """(K,) lambda_k."""
    u: np.ndarray
    """(K, 4n) rotor inputs, rad^2/s^2, rotor order of :attr:`Assembly.rotor_positions`."""
    verification: Verification
    """Recomputed from the angles and inputs (the stored figures agree with it)."""
    cost: float
    """sum_k lambda_k |u_k|^2 recomputed, (rad^2/s^2)^2 (``inf`` when infeasible)."""


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
    return checked_record(record, src)[0]


def flown_assembly(record, src: str) -> Assembly:
    """The assembly of a record without the verdict on its design: a flight log's, which is history (what flew,
    accepted by the rules of its day: the Fig. 1 design shipped before 2026-12-02 sat 2e-9 m inside ``2 r``, and
    its logs replay). The geometry is validated as on load (a malformed record is refused naming ``src`` and the
    key); the design part, if any, is not read."""
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise ConfigError(f"expected format {FORMAT!r}", path=src, key="format")
    for key in GEOMETRY_KEYS:
        if key not in record:
            raise ConfigError("missing", path=src, key=key)
    assembly = _geometry(record, src)
    _check_derived(record, assembly, src)
    return assembly


def checked_record(record, src: str) -> tuple[Assembly, CheckedDesign | None]:
    """Validate an assembly record and re-verify its design part; returns the assembly and, for a designed
    assembly, its design as recomputed. A stored value that disagrees with the derived one is a ConfigError
    naming ``src`` and the key."""
    assembly = flown_assembly(record, src)
    if not any(key in record for key in DESIGN_KEYS):
        return assembly, None
    for key in DESIGN_KEYS:
        if key not in record:
            raise ConfigError(f"missing (a design record has {', '.join(DESIGN_KEYS)})", path=src, key=key)
    return assembly, _check_design(record, assembly, src)


def _numbers(value, src: str, key: str, shape: tuple[int | None, ...], finite: bool = True) -> np.ndarray:
    """``value`` as a float array of ``shape`` (``None``: any length there), finite unless told; else a ConfigError
    naming ``key``."""
    if (written := _not_a_number(value)) is not None:  # numpy takes "0.24" and true as numbers
        raise ConfigError(f"not a number: {json.dumps(written)}", path=src, key=key)
    try:
        arr = np.asarray(value, dtype=float)
    except OverflowError:  # an integer past any float (10**400)
        raise ConfigError("a number too large for any float", path=src, key=key) from None
    except (TypeError, ValueError):
        raise ConfigError("not numeric (or rows of unequal length)", path=src, key=key) from None
    fits = arr.ndim == len(shape) and all(want is None or got == want for got, want in zip(arr.shape, shape,
                                                                                           strict=True))
    if not fits:
        want = "x".join("k" if d is None else str(d) for d in shape)
        raise ConfigError(f"expected {f'{want} numbers' if want else 'one number'}, got "
                          f"{'x'.join(map(str, arr.shape)) or 'one'}", path=src, key=key)
    if finite and not np.all(np.isfinite(arr)):  # "NaN" and "inf" as strings convert too
        bad = arr[~np.isfinite(arr)].flat[0] if arr.ndim else arr
        raise ConfigError(f"not a finite number: {float(bad)}", path=src, key=key)
    return arr


def _geometry(record: dict, src: str) -> Assembly:
    """The assembly the record's topology, module parameters and angles define."""
    params = config.validate(ModuleParams, record["module_params"], path=src, prefix="module_params")
    try:
        topo = Topology.from_code(record["topology"]["code"])
    except (KeyError, TypeError, TopologyError) as exc:
        raise ConfigError(f"invalid topology: {exc}", path=src, key="topology.code") from None
    for name, derived in (("cells", topo.cells), ("edges", topo.edges)):
        if name in record["topology"] and not _same_whole_numbers(record["topology"][name], derived):
            raise ConfigError(f"{name} disagree with the topology code", path=src, key=f"topology.{name}")
    if record["n"] != topo.n or isinstance(record["n"], bool):
        raise ConfigError(f"says {record['n']!r}, but {topo.code} has {topo.n} modules", path=src, key="n")
    alpha = np.radians(_numbers(record["angles_deg"], src, "angles_deg", (topo.n + 1,)))
    if np.any(np.abs(alpha) > np.pi / 2 + ANGLE_TOLERANCE):
        raise ConfigError("angles must lie in [-90, 90] degrees", path=src, key="angles_deg")
    yaw = float(np.radians(_numbers(record["yaw_deg"], src, "yaw_deg", ())))
    return Assembly(topo, params, alpha, yaw)


def _same_whole_numbers(stored, derived) -> bool:
    """``stored`` (from JSON) is ``derived``'s pairs element for element, each a JSON integer: Python's ``True == 1``
    would take a boolean for a cell's coordinate."""
    def exact(value):
        if isinstance(value, list):
            return [exact(v) for v in value]
        return value if type(value) is int else None  # bool and float are not the code's cells

    return exact(stored) == [list(pair) for pair in derived]


def _disagrees(src: str, key: str, what: str = "the value computed from the angles") -> ConfigError:
    return ConfigError(f"disagrees with {what}", path=src, key=key)


def _check_derived(record: dict, assembly: Assembly, src: str) -> None:
    """The stored poses, rotors, mass, inertia and controllable degrees of freedom against the derived ones."""
    n = assembly.n
    modules = record["modules"]
    if not isinstance(modules, list) or len(modules) != n:
        raise ConfigError(f"expected {n} modules", path=src, key="modules")
    for i, m in enumerate(modules):
        for name, derived in (("position", assembly.module_positions[i]), ("rotation", assembly.module_rotations[i])):
            key = f"modules[{i}].{name}"
            if not isinstance(m, dict) or name not in m:
                raise ConfigError("missing", path=src, key=key)
            if np.max(np.abs(_numbers(m[name], src, key, derived.shape) - derived)) > POSE_TOLERANCE:
                raise _disagrees(src, key, "the pose computed from the angles")
    rotors = record["rotors"]
    if not isinstance(rotors, list) or len(rotors) != 4 * n:
        raise ConfigError(f"expected {4 * n} rotors", path=src, key="rotors")
    for k, rotor in enumerate(rotors):
        derived = {"module": k // 4, "position": assembly.rotor_positions[k], "axis": assembly.rotor_axes[k],
                   "spin": assembly.rotor_spin[k]}
        for name, value in derived.items():
            key = f"rotors[{k}].{name}"
            if not isinstance(rotor, dict) or name not in rotor:
                raise ConfigError("missing", path=src, key=key)
            stored = _numbers(rotor[name], src, key, np.shape(value))
            if np.max(np.abs(stored - value)) > POSE_TOLERANCE:
                raise _disagrees(src, key, "the rotor computed from the angles")
    mass = _numbers(record["mass_kg"], src, "mass_kg", ())
    if abs(mass - assembly.mass) > DERIVED_RTOL * assembly.mass:
        raise ConfigError(f"says {float(mass):g} kg, but {n} modules of {assembly.params.mass:g} kg make "
                          f"{assembly.mass:g} kg", path=src, key="mass_kg")
    inertia = _numbers(record["inertia_kg_m2"], src, "inertia_kg_m2", (3, 3))
    if np.max(np.abs(inertia - assembly.inertia)) > DERIVED_RTOL * np.max(np.abs(assembly.inertia)):
        raise _disagrees(src, "inertia_kg_m2")
    if record["controllable_dof"] != assembly.controllable_dof:
        raise ConfigError(f"says {record['controllable_dof']!r}, but the allocation matrix has rank "
                          f"{assembly.controllable_dof}", path=src, key="controllable_dof")


def _figure_tolerances(ver: Verification) -> dict[str, float]:
    """How far a stored verification figure may lie from the recomputed one: the tolerance its check uses, so no
    disagreement accepted could change a verdict (the others, constants of the checks, agree to rounding)."""
    return {"max_wrench_residual": ver.residual_tolerance, "max_bound_violation": ver.bound_tolerance,
            "max_angle_violation": ANGLE_TOLERANCE, "min_capsule_distance": POSE_TOLERANCE}


def _is_number(x) -> bool:
    """A float (inf too: an infeasible design's figures hold it) or an integer that converts to one (a stored cost
    of 10**400 failed in ``math.isclose``)."""
    if not isinstance(x, int | float) or isinstance(x, bool):
        return False
    try:
        float(x)
    except OverflowError:
        return False
    return True


def _not_a_number(value) -> object | None:
    """The first boolean or string in ``value`` (nested lists), as written; None if there is none."""
    if isinstance(value, bool | str):
        return value
    if isinstance(value, list | tuple):
        return next((found for v in value if (found := _not_a_number(v)) is not None), None)
    return None


def _check_design(record: dict, assembly: Assembly, src: str) -> CheckedDesign:
    """Re-run the verification on the stored angles and inputs; the stored flag, cost and figures must agree
    (a legacy record's fewer figures included, see :data:`LEGACY_FIGURES`)."""
    wrenches = _numbers(record["wrenches"], src, "wrenches", (None, 6))
    k = len(wrenches)
    weights = _numbers(record["weights"], src, "weights", (k,))
    u = _numbers(record["u"], src, "u", (k, 4 * assembly.n), finite=False)  # a failed solve may leave NaN
    ver = verify(assembly, u, wrenches)
    figures = record["verification"]
    names = {f.name for f in fields(Verification)}
    if not isinstance(figures, dict) or set(figures) not in (names, LEGACY_FIGURES):
        raise ConfigError(f"expected the fields {', '.join(sorted(names))}", path=src, key="verification")
    failures = ver.failures()
    if not isinstance(record["feasible"], bool) or record["feasible"] == bool(failures):
        why = "; ".join(failures) or "every check passes"
        raise ConfigError(f"says {record['feasible']!r}, but the design recomputed from the angles and inputs is "
                          f"{'infeasible' if failures else 'feasible'}: {why}", path=src, key="feasible")
    cost = input_cost(u, weights)
    stored = record["cost"]
    if isinstance(stored, int) and not isinstance(stored, bool) and not _is_number(stored):
        raise ConfigError("a number too large for any float", path=src, key="cost")
    if record["feasible"] != _is_number(stored) or (
            record["feasible"] and not math.isclose(stored, cost, rel_tol=COST_RTOL)):
        raise ConfigError(f"says {stored!r}, but the inputs cost {cost:.10g}" if record["feasible"] else
                          f"says {stored!r} for an infeasible design (expected null)", path=src, key="cost")
    if figures["feasible"] is not record["feasible"]:
        raise ConfigError(f"says {figures['feasible']!r} where feasible says {record['feasible']!r}", path=src,
                          key="verification.feasible")
    tolerances = _figure_tolerances(ver)
    for name in sorted(set(figures) - {"feasible"}):
        got, value = figures[name], getattr(ver, name)
        if not (_is_number(got) and math.isclose(got, value, rel_tol=1e-9, abs_tol=tolerances.get(name, 0.0))):
            raise ConfigError(f"says {got!r}, recomputed {value!r}", path=src, key=f"verification.{name}")
    return CheckedDesign(wrenches, weights, u, ver, cost if ver.feasible else math.inf)
