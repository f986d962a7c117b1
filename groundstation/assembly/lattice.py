"""Square-lattice geometry of module connectors: the single home of directions and symmetry groups.

Modules sit on the integer lattice, ``x`` east and ``y`` north, one module per cell. Each module has four
connectors numbered counter-clockwise starting north (viewed from above, thrust axis ``z`` up)::

            1 (+y)
     2 (-x)  [ ]  4 (+x)
            3 (-y)

so a 90 degree rotation about ``z`` maps connector ``c`` to ``c % 4 + 1``. The paper's kinematic rule rotates
about ``x`` for connectors {1, 3} (hinges along x, on the ±y sides) and about ``y`` for {2, 4}; this numbering
keeps that rule. Internally connectors are indexed 0..3 (connector number minus one).
"""

from __future__ import annotations

import numpy as np

from groundstation.choices import SYMMETRY_GROUPS

#: Unit step to the neighbouring cell through connector index 0..3 (connectors 1..4), lattice units.
DIRECTIONS: np.ndarray = np.array([[0, 1], [-1, 0], [0, -1], [1, 0]], dtype=np.int64)

#: One letter per connector index, used by the compact topology code.
DIRECTION_LETTERS = "NWSE"


def connector_between(a: tuple[int, int], b: tuple[int, int]) -> int:
    """Connector index (0..3) on the module at cell ``a`` that faces the adjacent cell ``b``."""
    step = (b[0] - a[0], b[1] - a[1])
    for k, (dx, dy) in enumerate(DIRECTIONS.tolist()):
        if (dx, dy) == step:
            return k
    raise ValueError(f"cells {a} and {b} are not lattice neighbours")


def _rotations(mirror: bool) -> np.ndarray:
    rot = np.array([[0, -1], [1, 0]], dtype=np.int64)  # 90 degrees counter-clockwise about z
    flip = np.array([[-1, 0], [0, 1]], dtype=np.int64) if mirror else np.eye(2, dtype=np.int64)
    mats = [np.linalg.matrix_power(rot, k) @ flip for k in range(4)]
    return np.stack(mats)


#: Symmetry groups acting on lattice coordinates, as stacks of 2x2 integer matrices (identity first).
#: ``C4`` is the paper's default: thrust is directional, so mirror images are distinct assemblies.
#: ``D4`` adds mirror images, for module families with flip symmetry. ``none`` keeps translation only.
GROUPS: dict[str, np.ndarray] = {
    "none": np.eye(2, dtype=np.int64)[None, :, :],
    "C4": _rotations(mirror=False),
    "D4": np.concatenate([_rotations(mirror=False), _rotations(mirror=True)]),
}
assert set(GROUPS) == set(SYMMETRY_GROUPS), "groundstation.choices names the groups the CLI offers"


def group_matrices(name: str) -> np.ndarray:
    """The 2x2 integer matrices of symmetry group ``name`` (``C4``, ``D4`` or ``none``)."""
    from groundstation.errors import UsageError

    try:
        return GROUPS[name]
    except KeyError:
        raise UsageError(f"unknown symmetry group {name!r}; choose one of {', '.join(GROUPS)}") from None
