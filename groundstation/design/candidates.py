"""The file of candidate topologies that ``groundstation enumerate --out`` writes and the design stage reads.

Two encodings of the same content, chosen by the file suffix:

* ``.json``: human-readable, one compact code per topology (see :class:`~groundstation.assembly.topology.Topology`)::

    {"format": "groundstation.candidates/1", "symmetry": "C4", "sampling": null,
     "levels": [{"n": 1, "available": 1, "non_isomorphic": 1, "topologies": ["o"]}, ...]}

* ``.npz``: the enumeration arrays per level (``n{N}_cells_x``, ``n{N}_cells_y``, ``n{N}_parent``) plus a
  ``meta`` JSON string with the same keys as above; about 50x faster to write and read for large levels.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from groundstation.assembly.topology import Topology
from groundstation.design.enumeration import Level, SamplingPolicy
from groundstation.errors import ConfigError, TopologyError
from groundstation.output import writing

FORMAT = "groundstation.candidates/1"
SUFFIXES = (".json", ".npz")


@dataclass(frozen=True)
class CandidateSet:
    """Candidate topologies per number of modules, as read from a candidates file."""

    symmetry: str
    """Symmetry group the candidates are non-isomorphic under."""
    sampled: bool
    """Whether the levels were thinned by sampling (then they are not exhaustive)."""
    levels: dict[int, tuple[Topology, ...]]
    """Topologies per number of modules ``n``."""


def write_candidates(path: str | Path, levels: list[Level], symmetry: str,
                     sampling: SamplingPolicy | None, progress=None) -> None:
    """Write ``levels`` to ``path`` (``.json`` or ``.npz``). ``progress(k)`` is called per topology for JSON. A write
    that fails (a full disk) is a :class:`~groundstation.errors.UsageError` naming the file."""
    p = Path(path)
    meta = {
        "format": FORMAT,
        "symmetry": symmetry,
        "sampling": asdict(sampling) if sampling is not None else None,
        "levels": [{"n": lv.n, "available": lv.available, "non_isomorphic": lv.non_isomorphic} for lv in levels],
    }
    if p.suffix == ".npz":
        arrays = {}
        for lv in levels:
            arrays[f"n{lv.n}_cells_x"] = lv.cells_x
            arrays[f"n{lv.n}_cells_y"] = lv.cells_y
            arrays[f"n{lv.n}_parent"] = lv.parent
        with writing(p), p.open("wb") as fh:
            np.savez_compressed(fh, meta=np.array(json.dumps(meta)), **arrays)
        return
    for entry, lv in zip(meta["levels"], levels, strict=True):
        codes = []
        for i in range(lv.kept):
            codes.append(lv.topology(i).code)
            if progress is not None:
                progress(1)
        entry["topologies"] = codes
    with writing(p):
        p.write_text(json.dumps(meta, indent=1) + "\n")


def read_candidates(path: str | Path) -> CandidateSet:
    """Read a candidates file; malformed content is a :class:`ConfigError` naming the file and key."""
    p = Path(path)
    if p.suffix not in SUFFIXES:
        raise ConfigError(f"unknown candidates file type {p.suffix!r}, expected .json or .npz", path=str(p))
    if not p.is_file():
        raise ConfigError("file not found", path=str(p))
    try:
        if p.suffix == ".npz":
            with np.load(p) as data:
                meta = json.loads(str(data["meta"]))
                arrays = {k: data[k] for k in data.files if k != "meta"}
        else:
            meta = json.loads(p.read_text())
            arrays = None
    except (ValueError, OSError, KeyError) as exc:
        raise ConfigError(f"cannot read candidates: {exc}", path=str(p)) from None
    if meta.get("format") != FORMAT:
        raise ConfigError(f"expected {FORMAT!r}", path=str(p), key="format")
    levels: dict[int, tuple[Topology, ...]] = {}
    for k, entry in enumerate(meta.get("levels", [])):
        key = f"levels[{k}]"
        try:
            n = int(entry["n"])
            if arrays is None:
                tops = tuple(Topology.from_code(c) for c in entry["topologies"])
            else:
                cx, cy, par = (arrays[f"n{n}_{name}"] for name in ("cells_x", "cells_y", "parent"))
                tops = tuple(Topology.from_arrays(cx[i], cy[i], par[i]) for i in range(cx.shape[0]))
        except (KeyError, TypeError, ValueError, TopologyError) as exc:
            raise ConfigError(f"malformed level: {exc}", path=str(p), key=key) from None
        if any(t.n != n for t in tops):
            raise ConfigError(f"a topology does not have n = {n} modules", path=str(p), key=key)
        levels[n] = tops
    return CandidateSet(symmetry=str(meta.get("symmetry")), sampled=meta.get("sampling") is not None,
                        levels=levels)
