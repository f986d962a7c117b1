"""Configuration kinematics and the allocation matrix (paper §IV-A), one implementation for numpy and CasADi.

Given a topology, connector angles ``alpha`` (``n + 1`` values, radians) and a body yaw ``yaw``:

* root orientation ``R_1 = R_x(alpha_0) R_y(alpha_1)``; for each connection, visited breadth-first from the
  root, the child's orientation is ``R_child = R_parent R_x(alpha_e)`` when the parent's connector is 1 or 3 and
  ``R_parent R_y(alpha_e)`` otherwise;
* positions ``p_child = p_parent + l_c R_parent t + l_c R_child t`` with ``t`` the unit vector from the parent's
  centre to its connector (parent body frame);
* everything is recentred on the module centroid (``o_i = p_i - p_0``, the COM for identical modules) and then
  rotated by ``R_z(yaw)``. The paper has no yaw; it is the free choice of the assembly's body frame about z,
  which lets one representative of a C4 class serve a task in any heading.

Rotors (module body frame, X layout, arm ``l_arm``): ``q = 1..4`` at ``(+,-)``, ``(-,-)``, ``(-,+)``, ``(+,+)``
times ``l_arm / sqrt(2)``, thrust along ``+z``, yaw torque sign ``(-1)^q``. Backends map these to motors.

The functions take an ``ops`` argument (:data:`NUMPY` or :data:`CASADI`); everything else is shared, so the
optimizer's symbolic model and the numeric checks are the same geometry.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from groundstation.assembly.lattice import DIRECTIONS
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology

#: Rotor positions in the module frame, in units of ``l_arm / sqrt(2)``; row q-1 is rotor q.
ROTOR_DIRECTIONS = np.array([[1.0, -1.0, 0.0], [-1.0, -1.0, 0.0], [-1.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
#: Yaw-torque sign ``(-1)^q`` of rotor q = 1..4.
ROTOR_SPIN = np.array([-1.0, 1.0, -1.0, 1.0])
E3 = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class _Ops:
    """The handful of operations the kinematics needs, for one numeric backend."""

    name: str
    sin: object
    cos: object
    mat: object  # rows -> 3x3 matrix
    col: object  # 3 entries -> column vector / 1-D vector
    cross: object


NUMPY = _Ops("numpy", np.sin, np.cos, lambda rows: np.array(rows, dtype=float), lambda v: np.asarray(v, float),
             np.cross)
CASADI = _Ops("casadi", ca.sin, ca.cos, lambda rows: ca.vertcat(*[ca.horzcat(*r) for r in rows]),
              lambda v: ca.vertcat(*v), ca.cross)


def rot_x(a, ops=NUMPY):
    c, s = ops.cos(a), ops.sin(a)
    return ops.mat([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a, ops=NUMPY):
    c, s = ops.cos(a), ops.sin(a)
    return ops.mat([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a, ops=NUMPY):
    c, s = ops.cos(a), ops.sin(a)
    return ops.mat([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def connector_vector(connector: int) -> np.ndarray:
    """Unit vector from a module's centre to connector 1..4, module frame."""
    dx, dy = DIRECTIONS[connector - 1]
    return np.array([float(dx), float(dy), 0.0])


def hinge_axis(connector: int) -> str:
    """The paper's rule: connectors 1 and 3 hinge about x, 2 and 4 about y."""
    return "x" if connector in (1, 3) else "y"


def root_rotation(alpha0, alpha1, yaw=0.0, ops: _Ops = NUMPY):
    """Orientation of the root module: ``R_z(yaw) R_x(alpha_0) R_y(alpha_1)``."""
    return rot_z(yaw, ops) @ rot_x(alpha0, ops) @ rot_y(alpha1, ops)


def relative_rotation(connector: int, angle, ops: _Ops = NUMPY):
    """Rotation of a child relative to its parent across the parent's connector 1..4 (paper's rule)."""
    return rot_x(angle, ops) if hinge_axis(connector) == "x" else rot_y(angle, ops)


def child_position(p_parent, r_parent, r_child, connector: int, l_c: float, ops: _Ops = NUMPY):
    """``p_child = p_parent + l_c R_parent t + l_c R_child t``, ``t`` the parent's connector direction."""
    t = ops.col(connector_vector(connector).tolist())
    return p_parent + l_c * (r_parent @ t) + l_c * (r_child @ t)


def module_frames(topo: Topology, alpha, l_c: float, yaw=0.0, ops: _Ops = NUMPY):
    """Module centres ``o_i`` (relative to the centroid) and orientations ``R_i`` for angles ``alpha``.

    ``alpha[0], alpha[1]`` are the root angles; ``alpha[2 + k]`` is the relative angle of the k-th connection in
    :meth:`Topology.bfs_tree` order. Returns two lists indexed by module.
    """
    n = topo.n
    rot = [None] * n
    pos = [None] * n
    rot[0] = root_rotation(alpha[0], alpha[1], yaw, ops)
    pos[0] = ops.col([0.0, 0.0, 0.0])
    for k, (child, parent, connector) in enumerate(topo.bfs_tree()):
        rot[child] = rot[parent] @ relative_rotation(connector, alpha[2 + k], ops)
        pos[child] = child_position(pos[parent], rot[parent], rot[child], connector, l_c, ops)
    centroid = sum(pos[1:], pos[0]) / n
    return [p - centroid for p in pos], rot


def module_moment_matrix(params: ModuleParams) -> np.ndarray:
    """3 x 4 map from a module's four rotor inputs to its moment about its own centre, module frame.

    Column q is ``c_f (delta_q x e3) + (-1)^q c_m e3`` with ``delta_q`` the rotor offset.
    """
    offsets = params.l_arm / np.sqrt(2.0) * ROTOR_DIRECTIONS
    return np.array([params.c_f * np.cross(d, E3) + s * params.c_m * E3 for d, s in zip(offsets, ROTOR_SPIN,
                                                                                           strict=True)]).T


def rotor_geometry(positions, rotations, params: ModuleParams, ops: _Ops = NUMPY):
    """Per rotor (module-major, q = 1..4): position, thrust axis and yaw sign, as three lists."""
    offsets = [ops.col((params.l_arm / np.sqrt(2.0) * d).tolist()) for d in ROTOR_DIRECTIONS]
    pos, axis, spin = [], [], []
    for o, r in zip(positions, rotations, strict=True):
        z = r @ ops.col(E3.tolist())
        for q in range(4):
            pos.append(o + r @ offsets[q])
            axis.append(z)
            spin.append(float(ROTOR_SPIN[q]))
    return pos, axis, spin


def module_wrench(position, rotation, u, params: ModuleParams, ops: _Ops = NUMPY):
    """Force (N) and torque (N m) about the origin that one module at ``position`` with ``rotation`` produces from
    its four rotor inputs ``u`` (rad^2/s^2): the total thrust along its z axis, acting at its centre, plus the
    rotors' moments about its centre (:func:`module_moment_matrix`).

    The one definition of the wrench: :func:`allocation_matrix` takes its columns from it, and the design NLP
    calls it with symbolic inputs (one bilinear term per module instead of one per rotor keeps its graph small).
    """
    z = rotation[:, 2]
    thrust = params.c_f * (u[0] + u[1] + u[2] + u[3])
    return thrust * z, thrust * ops.cross(position, z) + rotation @ (ops.mat(module_moment_matrix(params).tolist()) @ u)


def allocation_matrix(positions, rotations, params: ModuleParams, ops: _Ops = NUMPY):
    """The 6 x 4n matrix ``A`` with ``[F; tau] = A u`` about the origin of ``positions`` (the centroid, paper §IV-A):
    column ``4 i + q`` is :func:`module_wrench` of module i for a unit input on rotor q."""
    cols = [module_wrench(p, r, ops.col(np.eye(4)[q].tolist()), params, ops)
            for p, r in zip(positions, rotations, strict=True) for q in range(4)]
    if ops is NUMPY:
        return np.array([np.concatenate([f, t]) for f, t in cols]).T
    return ca.horzcat(*[ca.vertcat(f, t) for f, t in cols])


def capsule_endpoints(positions, rotations, params: ModuleParams, ops: _Ops = NUMPY):
    """End points ``o_i - a R_i e3`` and ``o_i - b R_i e3`` of every module's downwash capsule axis."""
    ends = []
    for o, r in zip(positions, rotations, strict=True):
        z = r @ ops.col(E3.tolist())
        ends.append((o - params.capsule_a * z, o - params.capsule_b * z))
    return ends


DEGENERATE_LENGTH = 1e-9
"""Segments shorter than this are points in :func:`segment_distance`, m."""


def segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> tuple[float, float, float]:
    """Shortest distance between segments ``p0-p1`` and ``q0-q1`` and the parameters ``s, t`` in [0, 1] of the
    closest points (numpy; exact, including parallel segments). A segment shorter than ``DEGENERATE_LENGTH`` is
    taken as its point ``p0`` (``q0``), which moves the answer by at most that length."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    eps = DEGENERATE_LENGTH ** 2
    if a <= eps and e <= eps:  # both segments are points
        return float(np.linalg.norm(r)), 0.0, 0.0
    if a <= eps:
        s, t = 0.0, float(np.clip(f / e, 0.0, 1.0))
    else:
        c = d1 @ r
        if e <= eps:
            s, t = float(np.clip(-c / a, 0.0, 1.0)), 0.0
        else:
            b = d1 @ d2
            denom = a * e - b * b
            # For (near-)parallel segments any s minimizes the unclamped problem; start from s = 0.
            s = float(np.clip((b * f - c * e) / denom, 0.0, 1.0)) if denom > 1e-12 * a * e else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t, s = 0.0, float(np.clip(-c / a, 0.0, 1.0))
            elif t > 1.0:
                t, s = 1.0, float(np.clip((b - c) / a, 0.0, 1.0))
    return float(np.linalg.norm(p0 + s * d1 - q0 - t * d2)), s, float(t)


def pairwise_capsule_distances(positions, rotations, params: ModuleParams) -> np.ndarray:
    """``(n, n)`` matrix of distances between capsule axes (numpy); the diagonal is ``inf``."""
    ends = capsule_endpoints(positions, rotations, params)
    n = len(ends)
    out = np.full((n, n), np.inf)
    for i in range(n):
        for j in range(i + 1, n):
            out[i, j] = out[j, i] = segment_distance(*ends[i], *ends[j])[0]
    return out
