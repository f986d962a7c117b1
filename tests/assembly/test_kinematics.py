from decimal import Decimal

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from groundstation.assembly import kinematics as kin
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from tests.recheck import exact_segment_distance
from tests.strategies import lattice_trees

P = ModuleParams()


def test_flat_pair_hand_derived():
    pos, rot = kin.module_frames(Topology.from_code("oE"), np.zeros(3), P.l_c)
    np.testing.assert_allclose(pos, [[-P.l_c, 0, 0], [P.l_c, 0, 0]], atol=1e-15)
    np.testing.assert_allclose(rot, [np.eye(3)] * 2)
    a = kin.allocation_matrix(pos, rot, P)
    d = P.l_arm / np.sqrt(2)
    # module 0, rotor 1 at (-l_c + d, -d, 0), thrust +z, yaw sign -1
    px, py = -P.l_c + d, -d
    np.testing.assert_allclose(a[:, 0], [0, 0, P.c_f, P.c_f * py, -P.c_f * px, -P.c_m])
    assert np.linalg.matrix_rank(a) == 4  # flat: fz, roll, pitch, yaw only


@pytest.mark.parametrize("theta", [0.3, -0.7, np.pi / 2])
def test_two_module_hinge_about_y(theta):
    # oE: the root's connector 4 (+x) hinges about y; relative angle theta.
    pos, rot = kin.module_frames(Topology.from_code("oE"), np.array([0.0, 0.0, theta]), P.l_c)
    p1 = np.array([P.l_c * (1 + np.cos(theta)), 0.0, -P.l_c * np.sin(theta)])
    np.testing.assert_allclose(pos[1] - pos[0], p1, atol=1e-15)
    np.testing.assert_allclose(pos[0] + pos[1], 0, atol=1e-15)
    c, s = np.cos(theta), np.sin(theta)
    np.testing.assert_allclose(rot[1], [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-15)


def test_two_module_hinge_about_x_with_root_angles():
    a0, a1, th = 0.2, -0.1, 0.5
    pos, rot = kin.module_frames(Topology.from_code("oS"), np.array([a0, a1, th]), P.l_c)
    r0 = kin.rot_x(a0) @ kin.rot_y(a1)
    np.testing.assert_allclose(rot[0], r0)
    np.testing.assert_allclose(rot[1], r0 @ kin.rot_x(th))
    t = np.array([0.0, -1.0, 0.0])  # root is the upper module; its connector 3 faces south
    np.testing.assert_allclose(pos[1] - pos[0], P.l_c * r0 @ t + P.l_c * rot[1] @ t, atol=1e-15)


@settings(max_examples=40, deadline=None)
@given(lattice_trees(min_n=1, max_n=10), st.data())
def test_geometry_consistent_and_numpy_equals_casadi(tree, data):
    topo = Topology.from_cells_edges(*tree)
    alpha = np.array(data.draw(st.lists(st.floats(-1.5, 1.5), min_size=topo.n + 1, max_size=topo.n + 1)))
    yaw = data.draw(st.floats(-3, 3))
    pos, rot = kin.module_frames(topo, alpha, P.l_c, yaw)
    for r in rot:
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    for child, parent, c in topo.bfs_tree():  # connectors meet: same point seen from both modules
        t = kin.connector_vector(c)
        np.testing.assert_allclose(pos[parent] + P.l_c * rot[parent] @ t, pos[child] - P.l_c * rot[child] @ t,
                                   atol=1e-12)
    np.testing.assert_allclose(np.mean(pos, axis=0), 0, atol=1e-12)
    a_sym, y_sym = ca.SX.sym("a", topo.n + 1), ca.SX.sym("y")
    ps, rs = kin.module_frames(topo, a_sym, P.l_c, y_sym, kin.CASADI)
    f = ca.Function("A", [a_sym, y_sym], [kin.allocation_matrix(ps, rs, P, kin.CASADI)])
    np.testing.assert_allclose(np.array(f(alpha, yaw)), kin.allocation_matrix(pos, rot, P), atol=1e-15)


@settings(max_examples=30, deadline=None)
@given(lattice_trees(min_n=1, max_n=8), st.data())
def test_allocation_reproduces_rotor_by_rotor_wrench(tree, data):
    topo = Topology.from_cells_edges(*tree)
    alpha = np.array(data.draw(st.lists(st.floats(-1.5, 1.5), min_size=topo.n + 1, max_size=topo.n + 1)))
    pos, rot = kin.module_frames(topo, alpha, P.l_c)
    u = np.random.default_rng(0).uniform(0, P.u_max, 4 * topo.n)
    force, torque = np.zeros(3), np.zeros(3)
    for i in range(topo.n):
        z = rot[i][:, 2]
        for q, (sx, sy) in enumerate([(1, -1), (-1, -1), (-1, 1), (1, 1)]):
            p = pos[i] + rot[i] @ np.array([sx, sy, 0.0]) * P.l_arm / np.sqrt(2)
            f = P.c_f * u[4 * i + q] * z
            force += f
            torque += np.cross(p, f) + (-1) ** (q + 1) * P.c_m * u[4 * i + q] * z
    w = kin.allocation_matrix(pos, rot, P) @ u
    np.testing.assert_allclose(w, np.concatenate([force, torque]), rtol=1e-12, atol=1e-12)
    # the per-module moment matrix used by the optimizer gives the same wrench
    mm = kin.module_moment_matrix(P)
    tau2 = sum(P.c_f * u[4 * i:4 * i + 4].sum() * np.cross(pos[i], rot[i][:, 2]) + rot[i] @ mm @ u[4 * i:4 * i + 4]
               for i in range(topo.n))
    np.testing.assert_allclose(tau2, torque, rtol=1e-12, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=12, max_size=12))
def test_segment_distance_matches_dense_sampling(v):
    p0, p1, q0, q1 = (np.array(v[3 * k:3 * k + 3]) for k in range(4))
    (d,), (s,), (t,) = kin.segment_distances(p0, p1, q0, q1)
    grid = np.linspace(0, 1, 401)
    a = p0 + grid[:, None] * (p1 - p0)
    b = q0 + grid[:, None] * (q1 - q0)
    brute = np.min(np.linalg.norm(a[:, None] - b[None], axis=2))
    assert d <= brute + 1e-12
    assert d >= brute - 0.01 * (np.linalg.norm(p1 - p0) + np.linalg.norm(q1 - q0)) - 1e-12
    assert 0 <= s <= 1 and 0 <= t <= 1
    assert np.linalg.norm(p0 + s * (p1 - p0) - q0 - t * (q1 - q0)) == pytest.approx(d)


EXACT = 1e-15
"""Largest error accepted against rational arithmetic, m: a few ulps of coordinates of order 1 (measured: at most
2.7e-16 over 3000 random pairs and 3000 random near-parallel ones)."""


def _capsule_pair(theta: float, lateral: float = 0.0, gap: float = 0.19):
    """Two 0.6 m capsule axes: one vertical, the other tilted by ``theta`` so that they converge toward their far
    ends, where they are ``gap`` apart (plus ``lateral`` out of their plane)."""
    p0, p1 = np.array([0.0, 0.0, -0.0475]), np.array([0.0, 0.0, -0.6475])
    q1 = np.array([gap, lateral, -0.6475])
    q0 = q1 + 0.6 * np.array([np.sin(theta), 0.0, np.cos(theta)])
    return p0, p1, q0, q1


def _rotation(axis, angle):
    k = np.cross(np.eye(3), axis / np.linalg.norm(axis))
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _adversarial_pairs():
    """Near-parallel, parallel, collinear, degenerate and touching segments, by name."""
    z, x = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    cases = {f"near-parallel {th:g} rad{' skew' if lat else ''}": _capsule_pair(th, lat)
             for th in (1e-3, 1e-5, 1e-6, 9e-7, 7.86e-7, 5e-7, 2e-7, 1e-9, 1e-12, 1e-15) for lat in (0.0, 1e-3)}
    cases.update({
        "parallel overlapping": (np.zeros(3), -z, 0.3 * x, 0.3 * x - z),
        "parallel, one past the other's end": (np.zeros(3), -z, 0.3 * x - 1.2 * z, 0.3 * x - 2 * z),
        "antiparallel overlapping": (np.zeros(3), -z, 0.19 * x - z, 0.19 * x + 0.5 * z),
        "parallel through rounding": (np.array([0.1, 0.2, 0.3]), np.array([0.4, 0.8, 1.2]), np.array([0.2, 0.1, 0.3]),
                                      np.array([0.2, 0.1, 0.3]) + 3 * np.array([0.3, 0.6, 0.9])),
        "collinear overlapping": (np.zeros(3), -z, -0.5 * z, -1.5 * z),
        "collinear apart": (np.zeros(3), -z, -1.1 * z, -2 * z),
        "one segment a point": (np.zeros(3), -z, np.array([0.3, 0.1, -0.4]), np.array([0.3, 0.1, -0.4])),
        "both points": (np.array([0.1, 0.2, 0.3]),) * 2 + (np.array([-0.2, 0.5, 0.1]),) * 2,
        "a point on the other": (np.zeros(3), -z, -0.25 * z, -0.25 * z),
        "crossing": (-x, x, np.array([0.0, -1.0, 0.0]), np.array([0.0, 1.0, 0.0])),
        "skew crossing near-parallel": (-x, x, np.array([-1.0, -1e-7, 0.19]), np.array([1.0, 1e-7, 0.19])),
        "sharing an end": (np.zeros(3), x, x, x + z),
    })
    rng = np.random.default_rng(23)
    for k in range(40):
        cases[f"random {k}"] = tuple(rng.uniform(-1, 1, (4, 3)))
        direction = rng.normal(size=3)
        p0 = rng.uniform(-1, 1, 3)
        q0 = p0 + rng.uniform(-0.3, 0.3, 3)
        tilted = _rotation(rng.normal(size=3), 10 ** rng.uniform(-16, -2)) @ direction
        cases[f"random near-parallel {k}"] = (p0, p0 + direction, q0, q0 + rng.uniform(0.1, 1.5) * tilted)
    return cases


ADVERSARIAL = _adversarial_pairs()


@pytest.mark.parametrize("name", list(ADVERSARIAL))
def test_segment_distance_is_exact_against_rational_arithmetic(name):
    """Against the least value of the squared distance computed in fractions on the same floats. Before issue 23
    the parallelism cut-off (``s = 0`` below ``sin^2 = 1e-12``) was 5.4e-7 m over at 9e-7 rad."""
    p0, p1, q0, q1 = ADVERSARIAL[name]
    (d,), (s,), (t,) = kin.segment_distances(p0, p1, q0, q1)
    assert abs(Decimal(float(d)) - exact_segment_distance(p0, p1, q0, q1)) <= Decimal(EXACT)
    assert 0 <= s <= 1 and 0 <= t <= 1
    assert np.linalg.norm(p0 + s * (p1 - p0) - q0 - t * (q1 - q0)) == pytest.approx(d, abs=EXACT)


def test_segment_distances_vectorized_equal_one_at_a_time():
    pairs = list(ADVERSARIAL.values())
    d, s, t = kin.segment_distances(*(np.array([p[k] for p in pairs]) for k in range(4)))
    for k, p in enumerate(pairs):
        assert (d[k], s[k], t[k]) == tuple(a[0] for a in kin.segment_distances(*p))


def test_parallel_capsules_hand_computed():
    # 0.3 m apart side by side, and the second one entirely below the first: end to end, 0.3 across and 0.2 down.
    (d,), _, _ = kin.segment_distances(np.zeros(3), [0, 0, -1.0], [0.3, 0, 0], [0.3, 0, -1.0])
    assert d == 0.3
    (d,), _, _ = kin.segment_distances(np.zeros(3), [0, 0, -1.0], [0.3, 0, -1.2], [0.3, 0, -2.0])
    assert d == pytest.approx(np.hypot(0.3, 0.2), abs=1e-16)
