"""Initial guesses of the multi-start (paper §IV-C's NLP is non-convex: where a solve starts decides what it finds).

A start is a *fold* or a *random* shape, turned by a number of quarter turns about the vertical:

* fold: a "bowl-up" shape, each child module raised and tilted toward its parent by the fold angle, the root
  levelled so that the mean thrust axis is vertical. The fold is the rim tilt divided by the lattice radius, so a
  90-module assembly starts as shallow a bowl as a two-module V; a fixed fold compounds with distance and starts
  large assemblies nearly inverted (n = 90: 85 Ipopt iterations at a 3 degree fold, 994 at 20). Rim tilt 0 is
  the paper's flat start.
* random: every connector angle drawn uniformly from +-``RANDOM_FOLD_DEG``, root levelled.
* quarter turns: the body yaw starts at the task-facing yaw (:func:`task_yaw`) plus ``k`` 90 degree turns. The
  yaw is optimized, but its gradient vanishes at the symmetric headings, and the §IV-C example showed that which
  of a topology's four C4 rotations the solver starts from decides whether it finds a design (oSEE feasible from
  two of the four, oSSE from two, oSWS from two; one heading finds nothing for each).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from groundstation.assembly import kinematics as kin
from groundstation.assembly.topology import Topology

RANDOM_FOLD_DEG = 60.0
"""Half-width of the uniform distribution of connector angles in random starts, degrees."""


@dataclass(frozen=True)
class Start:
    """One initial guess."""

    kind: Literal["fold", "random"]
    yaw_turns: int
    """Quarter turns (90 degrees each) added to the task-facing starting yaw."""
    rim_tilt_deg: float = 0.0
    """Fold starts: tilt of the outermost module, degrees."""
    seed: int = 0
    """Random starts: seed of the connector angles."""

    @property
    def label(self) -> str:
        shape = f"fold {self.rim_tilt_deg:g} deg" if self.kind == "fold" else f"random #{self.seed}"
        return f"{shape}, yaw +{90 * self.yaw_turns} deg"


def plan(rim_tilts_deg: tuple[float, ...], yaw_turns: tuple[int, ...], random_starts: int,
         seed: int) -> list[Start]:
    """The starts in the order they are tried: every quarter turn of a fold before the next fold, then random
    shapes cycling through the quarter turns."""
    out = [Start("fold", k, rim_tilt_deg=rim) for rim in rim_tilts_deg for k in yaw_turns]
    out += [Start("random", yaw_turns[i % len(yaw_turns)], seed=seed + i) for i in range(random_starts)]
    return out


def lattice_radius(topo: Topology) -> float:
    """Largest distance of a module from the centroid, lattice units, at least 1/2."""
    cells = np.asarray(topo.cells, dtype=float)
    return max(0.5, float(np.max(np.linalg.norm(cells - cells.mean(axis=0), axis=1))))


def _toward_parent(connector: int) -> float:
    """Sign of the connector angle that tilts the child's thrust axis toward its parent."""
    t = kin.connector_vector(connector)
    probe = kin.rot_x(1.0) if kin.hinge_axis(connector) == "x" else kin.rot_y(1.0)
    return float(-np.sign((probe @ kin.E3) @ t))


def level_root(topo: Topology, alpha: np.ndarray) -> np.ndarray:
    """``alpha`` with the root angles chosen so that the mean thrust axis is vertical."""
    alpha = np.array(alpha, dtype=float)
    alpha[:2] = 0.0
    _, rot = kin.module_frames(topo, alpha, 1.0)
    m = np.mean([r @ kin.E3 for r in rot], axis=0)
    a1 = np.arctan2(-m[0], m[2])
    m2 = kin.rot_y(a1) @ m
    a0 = np.arctan2(m2[1], m2[2])
    alpha[0], alpha[1] = np.clip([a0, a1], -np.pi / 2, np.pi / 2)
    return alpha


def fold_angles(topo: Topology, fold: float) -> np.ndarray:
    """Angles that raise every child module and tilt it toward its parent by ``fold`` rad, root levelled."""
    alpha = np.zeros(topo.n + 1)
    for k, (_child, _parent, connector) in enumerate(topo.bfs_tree()):
        alpha[2 + k] = _toward_parent(connector) * fold
    return level_root(topo, alpha)


def random_angles(topo: Topology, seed: int) -> np.ndarray:
    """Connector angles uniform in +-``RANDOM_FOLD_DEG``, root levelled."""
    rng = np.random.default_rng(seed)
    alpha = np.zeros(topo.n + 1)
    alpha[2:] = np.radians(rng.uniform(-RANDOM_FOLD_DEG, RANDOM_FOLD_DEG, topo.n - 1))
    return level_root(topo, alpha)


def _principal_angle(points: np.ndarray) -> float | None:
    """Direction (rad, mod pi) of the largest spread of 2-D points about the origin; None when isotropic."""
    if len(points) == 0:
        return None
    cov = points.T @ points
    vals, vecs = np.linalg.eigh(cov)
    if vals[1] - vals[0] <= 1e-9 * max(vals[1], 1e-12):
        return None
    return float(np.arctan2(vecs[1, 1], vecs[0, 1]))


def task_yaw(topo: Topology, wrenches: np.ndarray) -> float:
    """Starting yaw that turns the assembly's long lattice axis toward the task's main lateral force direction.

    A fold only creates lateral force along the connections, so a task pushing along y needs the long axis of
    the assembly along y.
    """
    cells = np.asarray(topo.cells, dtype=float)
    structure = _principal_angle(cells - cells.mean(axis=0))
    lateral = _principal_angle(wrenches[:, :2])
    if structure is None or lateral is None:
        return 0.0
    return lateral - structure


def initial_shape(start: Start, topo: Topology, wrenches: np.ndarray, free_yaw: bool) -> tuple[np.ndarray, float]:
    """Angles and yaw of a start (yaw 0 when the yaw is not optimized)."""
    if start.kind == "fold":
        alpha = fold_angles(topo, np.radians(start.rim_tilt_deg / lattice_radius(topo)))
    else:
        alpha = random_angles(topo, start.seed)
    yaw = task_yaw(topo, wrenches) + start.yaw_turns * np.pi / 2 if free_yaw else 0.0
    return alpha, yaw


def least_squares_inputs(a: np.ndarray, wrenches: np.ndarray, u_max: float) -> np.ndarray:
    """Minimum-norm inputs for every wrench, clipped to the bounds: the starting inputs."""
    return np.clip(wrenches @ np.linalg.pinv(a).T, 0.0, u_max)
