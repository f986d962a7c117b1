"""The rotation helpers against scipy's rotations and numpy's products (independent implementations)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from groundstation.rotations import (
    mat3_from_rotvec,
    mat3_mul,
    mat3_orthonormal,
    mat3_tmul,
    mat3_to_rotvec,
    mat3_vec,
    matrix_to_rotvec,
    rotvec_to_matrix,
)


def _rotvecs(count: int, seed: int = 0) -> np.ndarray:
    """Random rotation vectors from 1e-14 rad (the small-angle branch) to 3 rad."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(count, 3))
    return axes / np.linalg.norm(axes, axis=1, keepdims=True) * 10 ** rng.uniform(-14, np.log10(3.0), (count, 1))


def _mat(m) -> np.ndarray:
    return np.array(m).reshape(3, 3)


def test_rotation_matrix_and_vector_agree_with_scipy_both_ways():
    for v in _rotvecs(200):
        expected = Rotation.from_rotvec(v).as_matrix()
        np.testing.assert_allclose(_mat(mat3_from_rotvec(*v.tolist())), expected, rtol=0, atol=1e-15)
        np.testing.assert_allclose(rotvec_to_matrix(v), expected, rtol=0, atol=1e-15)
        np.testing.assert_allclose(mat3_to_rotvec(tuple(expected.ravel())), v, rtol=0, atol=1e-12)
        np.testing.assert_allclose(matrix_to_rotvec(expected), v, rtol=0, atol=1e-12)
    assert rotvec_to_matrix([0.2, 0.0, 0.0]).shape == (3, 3) and matrix_to_rotvec(np.eye(3)).shape == (3,)


def test_products_are_numpys():
    rng = np.random.default_rng(1)
    for _ in range(50):
        a, b, v = rng.normal(size=(3, 3)), rng.normal(size=(3, 3)), rng.normal(size=3)
        fa, fb = tuple(a.ravel()), tuple(b.ravel())
        np.testing.assert_allclose(_mat(mat3_mul(fa, fb)), a @ b, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(_mat(mat3_tmul(fa, fb)), a.T @ b, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(mat3_vec(fa, tuple(v)), a @ v, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("drift", [1e-4, 1e-7])
def test_one_newton_step_squares_the_distance_from_a_rotation(drift):
    """A rotation drifted off by ``drift`` (what rounding leaves after many products) comes back to ~drift^2,
    without turning."""
    rng = np.random.default_rng(2)
    r = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    off = r + drift * rng.normal(size=(3, 3))
    fixed = _mat(mat3_orthonormal(tuple(off.ravel())))
    assert np.abs(fixed.T @ fixed - np.eye(3)).max() < max(20 * drift ** 2, 1e-15)
    assert np.abs(fixed - r).max() < 5 * drift


@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (1.0, 2.0, -2.0), (-0.3, 0.1, 0.9)])
@pytest.mark.parametrize("angle", [np.pi, np.pi - 1e-6, np.pi - 1e-4, np.pi - 2e-4, 3.0 + 1e-9, 3.0 - 1e-9, 2.5])
def test_a_half_turn_keeps_its_angle_and_axis(axis, angle):
    """A pose flipped by 180 deg must show as a 180 deg innovation (an exact half turn once gave a zero vector)."""
    rv = np.array(axis) / np.linalg.norm(axis) * angle
    r = Rotation.from_rotvec(rv).as_matrix()
    got = np.array(mat3_to_rotvec(tuple(r.ravel())))
    assert np.linalg.norm(got) == pytest.approx(angle, abs=1e-12)
    np.testing.assert_allclose(Rotation.from_rotvec(got).as_matrix(), r, atol=1e-12)  # the same rotation
