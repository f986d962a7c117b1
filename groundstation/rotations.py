"""Rotation helpers shared by control, simulation, mocap and logging (one home, no copies).

Quaternions are ``(x, y, z, w)``, the order of PyBullet and of ``foxglove.Quaternion``.

The ``mat3_*`` forms work on :data:`Mat3`, a 3x3 matrix as a flat tuple of floats, in plain Python arithmetic: code
that runs every control period on single 3-vectors and rotations (the state estimator) pays ~1-2 us of numpy
overhead per call on arrays that small, several times what the arithmetic costs. The numpy forms are built on
them.
"""

from __future__ import annotations

import math

import numpy as np

Vec3 = tuple[float, float, float]
Mat3 = tuple[float, float, float, float, float, float, float, float, float]
"""A 3x3 matrix, its entries row by row."""


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def mat3_from_rotvec(x: float, y: float, z: float) -> Mat3:
    """Rotation matrix of the rotation vector ``(x, y, z)`` (axis times angle, rad), Rodrigues' formula
    ``I + s K + c K^2``."""
    th2 = x * x + y * y + z * z
    if th2 < 1e-24:
        return (1.0, -z, y, z, 1.0, -x, -y, x, 1.0)
    th = math.sqrt(th2)
    s = math.sin(th) / th
    c = (1.0 - math.cos(th)) / th2
    xy, xz, yz = c * x * y, c * x * z, c * y * z
    return (1.0 - c * (y * y + z * z), xy - s * z, xz + s * y,
            xy + s * z, 1.0 - c * (x * x + z * z), yz - s * x,
            xz - s * y, yz + s * x, 1.0 - c * (x * x + y * y))


HALF_TURN_BRANCH = 3.0
"""Above this angle, rad, the axis comes from the rotation's symmetric part (its antisymmetric part, 2 sin(angle),
is then below 0.29 and vanishes at pi)."""


def mat3_to_rotvec(r: Mat3) -> Vec3:
    """Rotation vector of a rotation matrix (inverse of :func:`mat3_from_rotvec` for angles below pi)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = r
    wx, wy, wz = r21 - r12, r02 - r20, r10 - r01  # 2 sin(angle) axis
    sin2 = math.sqrt(wx * wx + wy * wy + wz * wz)
    cos = (r00 + r11 + r22 - 1.0) / 2.0
    angle = math.atan2(0.5 * sin2, cos)  # accurate at every angle, unlike acos near 0 and pi
    if angle > HALF_TURN_BRANCH:
        # Near a half turn the antisymmetric part vanishes (an exact one gave a zero vector: a pose flipped by 180
        # deg, a mocap rigid body defined upside down, passed every attitude gate): the axis is in the symmetric
        # part, r + r^T = 2 cos I + 2 (1 - cos) a a^T; the antisymmetric part gives only the sense.
        c1 = 1.0 - cos
        diag = ((r00 - cos) / c1, (r11 - cos) / c1, (r22 - cos) / c1)
        i = max(range(3), key=diag.__getitem__)
        sym = ((2.0 * r00, r01 + r10, r02 + r20), (r01 + r10, 2.0 * r11, r12 + r21), (r02 + r20, r12 + r21, 2.0 * r22))
        ai = math.sqrt(max(diag[i], 0.0))
        axis = [sym[i][j] / (2.0 * c1 * ai) if j != i else ai for j in range(3)]
        norm = math.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2)
        k = (-angle if (wx, wy, wz)[i] < 0.0 else angle) / norm
        return (k * axis[0], k * axis[1], k * axis[2])
    k = 0.5 if sin2 < 1e-12 else angle / sin2
    return (k * wx, k * wy, k * wz)


def mat3_mul(a: Mat3, b: Mat3) -> Mat3:
    """``a @ b``."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return (a0 * b0 + a1 * b3 + a2 * b6, a0 * b1 + a1 * b4 + a2 * b7, a0 * b2 + a1 * b5 + a2 * b8,
            a3 * b0 + a4 * b3 + a5 * b6, a3 * b1 + a4 * b4 + a5 * b7, a3 * b2 + a4 * b5 + a5 * b8,
            a6 * b0 + a7 * b3 + a8 * b6, a6 * b1 + a7 * b4 + a8 * b7, a6 * b2 + a7 * b5 + a8 * b8)


def mat3_tmul(a: Mat3, b: Mat3) -> Mat3:
    """``a.T @ b``: for rotations, ``b`` relative to ``a``."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return (a0 * b0 + a3 * b3 + a6 * b6, a0 * b1 + a3 * b4 + a6 * b7, a0 * b2 + a3 * b5 + a6 * b8,
            a1 * b0 + a4 * b3 + a7 * b6, a1 * b1 + a4 * b4 + a7 * b7, a1 * b2 + a4 * b5 + a7 * b8,
            a2 * b0 + a5 * b3 + a8 * b6, a2 * b1 + a5 * b4 + a8 * b7, a2 * b2 + a5 * b5 + a8 * b8)


def mat3_vec(a: Mat3, v: Vec3) -> Vec3:
    """``a @ v``."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    x, y, z = v
    return (a0 * x + a1 * y + a2 * z, a3 * x + a4 * y + a5 * z, a6 * x + a7 * y + a8 * z)


def mat3_orthonormal(r: Mat3) -> Mat3:
    """One Newton step back to a rotation, ``r (3 I - r.T r) / 2`` (rounding drifts products of many small rotations
    off it)."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    # r.T r is symmetric: its six distinct entries
    s00, s01, s02 = r0 * r0 + r3 * r3 + r6 * r6, r0 * r1 + r3 * r4 + r6 * r7, r0 * r2 + r3 * r5 + r6 * r8
    s11, s12, s22 = r1 * r1 + r4 * r4 + r7 * r7, r1 * r2 + r4 * r5 + r7 * r8, r2 * r2 + r5 * r5 + r8 * r8
    return mat3_mul(r, (1.5 - 0.5 * s00, -0.5 * s01, -0.5 * s02,
                        -0.5 * s01, 1.5 - 0.5 * s11, -0.5 * s12,
                        -0.5 * s02, -0.5 * s12, 1.5 - 0.5 * s22))


def rotvec_to_matrix(v) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis times angle, rad): :func:`mat3_from_rotvec` as a (3, 3) array."""
    return np.array(mat3_from_rotvec(float(v[0]), float(v[1]), float(v[2]))).reshape(3, 3)


def matrix_to_rotvec(r: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix: :func:`mat3_to_rotvec` of a (3, 3) array."""
    return np.array(mat3_to_rotvec(np.ravel(r).tolist()))


def matrix_to_quat(r: np.ndarray) -> tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) of a rotation matrix (Shepperd's method, robust for all angles)."""
    t = np.trace(r)
    if t > 0:
        s = 2.0 * np.sqrt(t + 1.0)
        w, x, y, z = 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
        q = np.zeros(4)
        q[i] = 0.25 * s
        q[j] = (r[j, i] + r[i, j]) / s
        q[k] = (r[k, i] + r[i, k]) / s
        q[3] = (r[k, j] - r[j, k]) / s
        x, y, z, w = q
    return (float(x), float(y), float(z), float(w))


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w); the quaternion is normalized first."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rotation_angle(ra: np.ndarray, rb: np.ndarray) -> np.ndarray:
    """Angle between rotations (batched over leading axes), rad."""
    tr = np.einsum("...ij,...ij->...", ra, rb)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))
