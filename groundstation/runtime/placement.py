"""Preflight: link i reaches the module mounted at place i, told by the direction of gravity each module measures.

At rest a module's accelerometer reads the specific force ``R_im^T e_z`` (up, in its own frame), where
``R_im = R_wb R_bm`` is the module's attitude: the body's (from mocap) times its mount in the assembly. Modules
mounted at different tilts (the V's two modules lean opposite ways) read different directions, so a link that
reaches a module at another place, or swapped links, show as a measurement far from what the link's place
predicts and near what another place predicts. Places whose predictions are closer than twice the tolerance
cannot be told apart this way: swapping their links goes unseen (they are mounted alike, so the flight does not
depend on which is which for its attitude, though it does for the rotor positions); distinct unique ids rule
out a duplicated link (see the backend's claim).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PlacementCheck:
    tolerance_deg: float = 10.0
    """A module's measured up direction may differ from its place's prediction by this much, deg: accelerometer
    bias and the level of the ground at rest are a few degrees."""


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))))


def predicted_up(module_rotations: np.ndarray, body_rotation: np.ndarray) -> np.ndarray:
    """(n, 3): up (``e_z`` of the world) in each module's frame for the body at ``body_rotation`` (body to world)."""
    return np.einsum("nji,j->ni", np.einsum("ij,njk->nik", body_rotation, module_rotations), [0.0, 0.0, 1.0])


def placement_issues(measured_up: np.ndarray, module_rotations: np.ndarray, body_rotation: np.ndarray,
                     names: list[str], check: PlacementCheck = PlacementCheck()) -> list[str]:
    """One line per link whose module does not measure what its place predicts, naming the place it matches."""
    predicted = predicted_up(np.asarray(module_rotations, float), np.asarray(body_rotation, float))
    issues = []
    for i, up in enumerate(np.asarray(measured_up, float)):
        if not np.all(np.isfinite(up)) or np.linalg.norm(up) < 0.5:
            issues.append(f"{names[i]} reports no accelerometer reading")
            continue
        off = [_angle_deg(up, p) for p in predicted]
        if off[i] <= check.tolerance_deg:
            continue
        best = int(np.argmin(off))
        where = (f"it matches place {best} ({names[best]}): links swapped or in the wrong order?"
                 if best != i and off[best] <= check.tolerance_deg else "it matches no place: mounted otherwise?")
        issues.append(f"{names[i]} measures gravity {off[i]:.0f} deg from where its mount at place {i} puts it; "
                      f"{where}")
    return issues
