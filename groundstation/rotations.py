"""Rotation helpers shared by control, simulation, mocap and logging (one home, no copies).

Quaternions are ``(x, y, z, w)``, the order of PyBullet and of ``foxglove.Quaternion``.
"""

from __future__ import annotations

import math

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis times angle, rad), Rodrigues' formula."""
    th = float(np.linalg.norm(v))
    if th < 1e-12:
        return np.eye(3) + skew(v)
    k = skew(np.asarray(v) / th)
    return np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * k @ k


def matrix_to_rotvec(r: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (inverse of :func:`rotvec_to_matrix` for angles below pi)."""
    angle = math.acos(min(1.0, max(-1.0, (float(np.trace(r)) - 1.0) / 2.0)))
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if angle < 1e-9:
        return 0.5 * v
    return angle / (2.0 * np.sin(angle)) * v


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
