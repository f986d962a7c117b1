"""The assembly: a topology with fixed connector angles, the one geometric model every stage reads.

Design produces it, control takes its mass, inertia and allocation matrix, the simulator builds its rigid body
from it, logging draws it. Everything is derived from ``(topology, params, alpha, yaw)`` by
:mod:`groundstation.assembly.kinematics`; nothing keeps a second copy of the geometry.

Frames: the assembly body frame has its origin at the centroid of the module centres (the COM, modules being
identical), z up when all angles are zero.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from groundstation.assembly import kinematics as kin
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology


@dataclass(frozen=True, eq=False)
class Assembly:
    """A rigid assembly of modules."""

    topology: Topology
    params: ModuleParams
    alpha: np.ndarray = field(repr=False)
    """(n + 1,) root angles and relative connector angles, rad (see :mod:`kinematics`)."""
    yaw: float = 0.0
    """Body yaw of the root, rad."""

    @property
    def n(self) -> int:
        return self.topology.n

    @cached_property
    def _frames(self) -> tuple[np.ndarray, np.ndarray]:
        pos, rot = kin.module_frames(self.topology, np.asarray(self.alpha, float), self.params.l_c, self.yaw)
        return np.array(pos), np.array(rot)

    @property
    def module_positions(self) -> np.ndarray:
        """(n, 3) module centres, body frame, m."""
        return self._frames[0]

    @property
    def module_rotations(self) -> np.ndarray:
        """(n, 3, 3) module orientations, body frame."""
        return self._frames[1]

    @cached_property
    def _rotors(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pos, axis, spin = kin.rotor_geometry(list(self.module_positions), list(self.module_rotations), self.params)
        return np.array(pos), np.array(axis), np.array(spin)

    @property
    def rotor_positions(self) -> np.ndarray:
        """(4n, 3) rotor centres, body frame, m; rotor ``4 i + q - 1`` is rotor q of module i."""
        return self._rotors[0]

    @property
    def rotor_axes(self) -> np.ndarray:
        """(4n, 3) unit thrust axes, body frame."""
        return self._rotors[1]

    @property
    def rotor_spin(self) -> np.ndarray:
        """(4n,) yaw-torque sign ``(-1)^q`` of each rotor."""
        return self._rotors[2]

    @cached_property
    def allocation(self) -> np.ndarray:
        """(6, 4n) allocation matrix: body wrench [F; tau] about the COM = A u, u in rad^2/s^2."""
        return kin.allocation_matrix(list(self.module_positions), list(self.module_rotations), self.params)

    @property
    def mass(self) -> float:
        """Total mass, kg."""
        return self.n * self.params.mass

    @cached_property
    def inertia(self) -> np.ndarray:
        """(3, 3) inertia about the COM, body frame, kg m^2 (module inertias rotated plus parallel-axis terms)."""
        j_mod = np.diag(self.params.inertia)
        total = np.zeros((3, 3))
        for p, r in zip(self.module_positions, self.module_rotations, strict=True):
            total += r @ j_mod @ r.T + self.params.mass * ((p @ p) * np.eye(3) - np.outer(p, p))
        return total

    @cached_property
    def _corners(self) -> np.ndarray:
        """(8n, 3) the corners of every module's frame box, body frame, m."""
        hx, hy, hz = self.params.frame_half_extents
        box = np.array([[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        frames = zip(self.module_positions, self.module_rotations, strict=True)
        return np.concatenate([p + box @ r.T for p, r in frames])

    @cached_property
    def resting_height(self) -> float:
        """COM height at which the lowest module corner touches the ground (body frame level), m: where a flight
        plan starts when no mocap has seen the assembly yet."""
        return -float(self._corners[:, 2].min())

    def clearance(self, height: float, rotation: np.ndarray) -> float:
        """How far the lowest module corner is above the ground, m, with the COM ``height`` m above where it rests
        level (:attr:`resting_height`) and the body at ``rotation`` (world from body): 0 or less is touching."""
        return height + self.resting_height + float((self._corners @ np.asarray(rotation)[2]).min())

    @cached_property
    def controllable_dof(self) -> int:
        """Rank of the allocation matrix: 6 for a fully actuated assembly, 4 for a flat one."""
        return int(np.linalg.matrix_rank(self.allocation / np.abs(self.allocation).max(), tol=1e-9))
