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


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Row-wise dot product of two ``(m, 3)`` arrays."""
    return np.einsum("ij,ij->i", x, y)


def _clamped_projection(x: np.ndarray, origin: np.ndarray, direction: np.ndarray, length2: np.ndarray) -> np.ndarray:
    """Parameter in [0, 1] of the point of segment ``origin + t direction`` nearest to ``x`` (row-wise; 0 for a
    zero-length segment)."""
    t = np.divide(_dot(x - origin, direction), length2, out=np.zeros_like(length2), where=length2 > 0)
    return np.clip(t, 0.0, 1.0)


def segment_distances(p0, p1, q0, q1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shortest distances between the segments ``p0[k]-p1[k]`` and ``q0[k]-q1[k]`` (``(m, 3)`` arrays, m) and the
    parameters ``s, t`` in [0, 1] of their closest points, as three ``(m,)`` arrays (numpy).

    The squared distance is a convex quadratic in ``(s, t)`` over the unit square, so its least value is at the
    closest points of the two lines when both lie in the square, or else on an edge of the square: one parameter
    0 or 1 and the other the clamped projection of that end point onto the other segment. All five candidates are
    evaluated and the least taken. Every candidate is a pair of points on the segments, so no case depends on a
    threshold: parallel, near-parallel, collinear and zero-length segments are exact up to rounding (the tests
    check it against rational arithmetic). A parallelism cut-off here (``s = 0`` below ``sin^2 = 1e-12``) once
    overestimated near-parallel capsules by up to 4e-7 m, enough to accept an assembly inside ``2 r``.

    The lines' closest points come from ``n = d1 x d2`` (relative error ``eps / sin(angle)``), not from
    ``|d1|^2 |d2|^2 - (d1.d2)^2`` (relative error ``eps / sin^2``). When the lines are so near parallel that even
    these are inaccurate, the distance along the lines is flat to within ``|d| sin(angle)`` and an edge candidate
    is as good: the error is never above a few ulps of the coordinates.
    """
    p0, p1, q0, q1 = (np.atleast_2d(np.asarray(v, dtype=float)) for v in (p0, p1, q0, q1))
    d1, d2, r = p1 - p0, q1 - q0, q0 - p0
    a, e = _dot(d1, d1), _dot(d2, d2)
    normal = np.cross(d1, d2)
    nn = _dot(normal, normal)
    s_line = np.divide(_dot(np.cross(r, d2), normal), nn, out=np.full_like(nn, np.nan), where=nn > 0)
    t_line = np.divide(_dot(np.cross(r, d1), normal), nn, out=np.full_like(nn, np.nan), where=nn > 0)
    inside = (s_line >= 0.0) & (s_line <= 1.0) & (t_line >= 0.0) & (t_line <= 1.0)  # False for NaN (parallel)
    t_p0 = _clamped_projection(p0, q0, d2, e)
    zero, one = np.zeros_like(a), np.ones_like(a)
    # Candidates: s = 0, s = 1, t = 0, t = 1, the lines' closest points (else a repeat of the first).
    s = np.stack([zero, one, _clamped_projection(q0, p0, d1, a), _clamped_projection(q1, p0, d1, a),
                  np.where(inside, s_line, 0.0)], axis=1)
    t = np.stack([t_p0, _clamped_projection(p1, q0, d2, e), zero, one, np.where(inside, t_line, t_p0)], axis=1)
    gaps = (p0 - q0)[:, None, :] + s[:, :, None] * d1[:, None, :] - t[:, :, None] * d2[:, None, :]
    dist = np.linalg.norm(gaps, axis=2)
    rows, best = np.arange(len(dist)), np.argmin(dist, axis=1)
    return dist[rows, best], s[rows, best], t[rows, best]


def pairwise_capsule_distances(positions, rotations, params: ModuleParams) -> np.ndarray:
    """``(n, n)`` matrix of distances between capsule axes, m (numpy); the diagonal is ``inf``."""
    ends = np.array(capsule_endpoints(positions, rotations, params)).reshape(-1, 2, 3)
    n = len(ends)
    out = np.full((n, n), np.inf)
    i, j = np.triu_indices(n, 1)
    out[i, j] = out[j, i] = segment_distances(ends[i, 0], ends[i, 1], ends[j, 0], ends[j, 1])[0]
    return out
