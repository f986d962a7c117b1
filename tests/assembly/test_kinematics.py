import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from groundstation.assembly import kinematics as kin
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
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
    d, s, t = kin.segment_distance(p0, p1, q0, q1)
    grid = np.linspace(0, 1, 401)
    a = p0 + grid[:, None] * (p1 - p0)
    b = q0 + grid[:, None] * (q1 - q0)
    brute = np.min(np.linalg.norm(a[:, None] - b[None], axis=2))
    assert d <= brute + kin.DEGENERATE_LENGTH + 1e-12  # a segment under that length is taken as its first point
    assert d >= brute - 0.01 * (np.linalg.norm(p1 - p0) + np.linalg.norm(q1 - q0)) - 1e-12
    assert np.linalg.norm(p0 + s * (p1 - p0) - q0 - t * (q1 - q0)) == pytest.approx(d)


def test_parallel_segments():
    d, _, _ = kin.segment_distance(np.zeros(3), np.array([0, 0, -1.0]), np.array([0.3, 0, 0]),
                                   np.array([0.3, 0, -1.0]))
    assert d == pytest.approx(0.3)
