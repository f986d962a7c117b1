"""Proofs that no design of a topology can meet a wrench set, checked before any solve.

A solver that fails proves nothing. These certificates do, from the model alone (paper §IV-A):

* Thrust capacity. Every force an assembly makes is ``F = sum_i T_i z_i`` with ``0 <= T_i <= 4 c_f u_max`` and
  unit thrust axes ``z_i`` (rotor drag makes torque, not force), so ``|F| <= 4 n c_f u_max``.
* Thrust-axis span. Module ``i`` has ``z_i = R_root R_rel,i e3`` where ``R_rel,i`` chains the hinge rotations
  from the root. When every connection hinges about the same body axis ``a`` (a straight chain: all
  connectors north-south, or all east-west), every ``R_rel,i`` is a rotation about ``a``, so every ``z_i`` lies
  in the plane ``R_root a-perp`` and so does every force of every design, whatever the angles. One module
  makes forces along a single line. A wrench set whose forces span more dimensions than that cannot be met.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from groundstation.assembly import kinematics as kin
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology

RANK_TOLERANCE = 1e-6
"""Singular values of the task forces below this fraction of the largest count as zero."""


@dataclass(frozen=True)
class Certificate:
    """Why a topology cannot meet a wrench set, with the numbers that prove it."""

    kind: str
    """``thrust-capacity`` or ``force-span``."""
    reason: str
    """One sentence a user can check by hand."""


def thrust_axis_dimension(topo: Topology) -> int:
    """Dimension of the linear span that the thrust axes of every design of ``topo`` lie in (1, 2 or 3)."""
    if topo.n == 1:
        return 1
    hinges = {kin.hinge_axis(connector) for _child, _parent, connector in topo.bfs_tree()}
    return 2 if len(hinges) == 1 else 3


def infeasibility_certificate(topo: Topology, params: ModuleParams, wrenches: np.ndarray) -> Certificate | None:
    """A proof that no angles and inputs of ``topo`` produce every wrench of ``wrenches`` (K x 6), or None."""
    forces = np.atleast_2d(np.asarray(wrenches, dtype=float))[:, :3]
    capacity = 4 * topo.n * params.c_f * params.u_max
    need = np.linalg.norm(forces, axis=1)
    k = int(np.argmax(need))
    if need[k] > capacity * (1 + 1e-12):
        return Certificate("thrust-capacity", f"wrench {k + 1} needs a force of {need[k]:.4g} N, more than the "
                                              f"{topo.n} modules' total thrust 4 n c_f u_max = {capacity:.4g} N")
    return force_span_certificate(topo, wrenches)


def force_span_certificate(topo: Topology, wrenches: np.ndarray) -> Certificate | None:
    """The thrust-axis span proof alone, or None. It does not involve ``u_max``: a topology it rules out is
    infeasible whatever the input bound."""
    forces = np.atleast_2d(np.asarray(wrenches, dtype=float))[:, :3]
    dim = thrust_axis_dimension(topo)
    sv = np.linalg.svd(forces, compute_uv=False)
    rank = int(np.sum(sv > RANK_TOLERANCE * sv[0])) if sv[0] > 0 else 0
    if rank > dim:
        where = "along one line" if dim == 1 else \
            f"in one plane (every hinge of {topo.code} turns about the same axis)"
        return Certificate("force-span", f"every force of every design lies {where}, but the task's forces span "
                                         f"{rank} dimensions (singular values "
                                         f"{', '.join(f'{s:.4g}' for s in sv)} N)")
    return None
