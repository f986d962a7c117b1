"""Rotation helpers shared by control, simulation, mocap and logging (one home, no copies).

Quaternions are ``(x, y, z, w)``, the order of PyBullet and of ``foxglove.Quaternion``.
"""

from __future__ import annotations

import math

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis times angle, rad), Rodrigues' formula ``I + s K + c K^2``.

    In scalar arithmetic: the estimator calls it a few times every control period, and numpy's per-call overhead
    on 3-vectors made it ~10 us; this is ~2 us."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    th2 = x * x + y * y + z * z
    if th2 < 1e-24:
        return np.array([[1.0, -z, y], [z, 1.0, -x], [-y, x, 1.0]])
    th = math.sqrt(th2)
    s = math.sin(th) / th
    c = (1.0 - math.cos(th)) / th2
    xy, xz, yz = c * x * y, c * x * z, c * y * z
    return np.array([[1.0 - c * (y * y + z * z), xy - s * z, xz + s * y],
                     [xy + s * z, 1.0 - c * (x * x + z * z), yz - s * x],
                     [xz - s * y, yz + s * x, 1.0 - c * (x * x + y * y)]])


def matrix_to_rotvec(r: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (inverse of :func:`rotvec_to_matrix` for angles below pi); scalar
    arithmetic, like it."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = r.tolist()
    angle = math.acos(min(1.0, max(-1.0, (r00 + r11 + r22 - 1.0) / 2.0)))
    k = 0.5 if angle < 1e-9 else angle / (2.0 * math.sin(angle))
    return np.array([k * (r21 - r12), k * (r02 - r20), k * (r10 - r01)])


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
