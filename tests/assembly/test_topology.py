import numpy as np
import pytest
from hypothesis import given, settings

from benchmarks.enumeration_baseline import _group, canonical
from groundstation.assembly.lattice import GROUPS
from groundstation.assembly.topology import Topology
from groundstation.errors import TopologyError
from tests.strategies import lattice_trees


def test_two_module_matrix_is_the_papers_coding():
    topo = Topology.from_cells_edges([(0, 0), (1, 0)], [(0, 1)])
    expected = np.array([[0, 1, 0, 1, 0],
                         [1, 6, 2, 6, 1],
                         [0, 1, 0, 1, 0]])
    np.testing.assert_array_equal(topo.to_matrix(), expected)
    assert topo.connector(0, 1) == 4 and topo.connector(1, 0) == 2  # east side of 0 meets west side of 1


def test_blocked_connector_between_adjacent_unconnected_modules():
    # A U of four modules: (0,1)-(0,0)-(1,0)-(1,1); (0,1) and (1,1) touch but are not connected.
    topo = Topology.from_cells_edges([(0, 1), (0, 0), (1, 0), (1, 1)], [(0, 1), (1, 2), (2, 3)])
    mat = topo.to_matrix()
    assert mat[1, 2] == 3  # shared border of the two upper modules: blocked
    assert mat[3, 2] == 2 and mat[2, 1] == 2 and mat[2, 3] == 2
    assert (mat == 6).sum() == 4 and (mat == 2).sum() == 3 and (mat == 3).sum() == 1
    assert (mat == 1).sum() == topo.free_connectors() == 8


def test_root_is_upper_left_module():
    topo = Topology.from_cells_edges([(3, 0), (2, 0), (2, 1)], [(0, 1), (1, 2)])
    assert topo.cells[0] == (0, 1)  # after translation the top row holds only (2,1) -> (0,1)


@settings(max_examples=200, deadline=None)
@given(lattice_trees())
def test_matrix_and_code_round_trip(tree):
    topo = Topology.from_cells_edges(*tree)
    assert Topology.from_matrix(topo.to_matrix()) == topo
    assert Topology.from_code(topo.code) == topo


@settings(max_examples=100, deadline=None)
@given(lattice_trees(min_n=2), )
def test_canonical_form_invariant_under_group(tree):
    topo = Topology.from_cells_edges(*tree)
    for name, mats in GROUPS.items():
        key = topo.canonical_key(name)
        for m in mats:
            moved = topo.transformed(m)
            assert moved.canonical_key(name) == key
            assert moved.canonical(name) == topo.canonical(name)
        assert topo.canonical(name).canonical(name) == topo.canonical(name)


@settings(max_examples=100, deadline=None)
@given(lattice_trees(min_n=2, max_n=9), lattice_trees(min_n=2, max_n=9))
def test_isomorphism_agrees_with_independent_baseline(a, b):
    ta, tb = Topology.from_cells_edges(*a), Topology.from_cells_edges(*b)
    for name in GROUPS:
        group = _group(name)

        def bonds(t):
            return tuple((t.cells[i], t.cells[j]) for i, j in t.edges)

        same = ta.n == tb.n and canonical(bonds(ta), group) == canonical(bonds(tb), group)
        assert ta.is_isomorphic(tb, name) == same


def test_mirror_images_are_distinct_under_c4_only():
    s = Topology.from_code("oEES(E)S")  # chiral
    m = s.transformed([[-1, 0], [0, 1]])
    assert not s.is_isomorphic(m, "C4")
    assert s.is_isomorphic(m, "D4")


@pytest.mark.parametrize("cells, edges, msg", [
    ([(0, 0), (0, 0)], [(0, 1)], "same lattice cell"),
    ([(0, 0), (2, 0)], [(0, 1)], "not lattice neighbours"),
    ([(0, 0), (1, 0), (2, 0)], [(0, 1)], "2 connections"),
    ([(0, 0), (1, 0), (1, 1), (0, 1)], [(0, 1), (1, 2), (2, 3)][:2] + [(0, 1)], "one tree"),
])
def test_invalid_topologies_rejected(cells, edges, msg):
    with pytest.raises(TopologyError, match=msg):
        Topology.from_cells_edges(cells, edges)


@pytest.mark.parametrize("code", ["E", "oE)", "o(E", "oX"])
def test_invalid_codes_rejected(code):
    with pytest.raises(TopologyError):
        Topology.from_code(code)


def test_inconsistent_matrix_rejected():
    mat = Topology.from_code("oEE").to_matrix()
    mat[1, 0] = 3  # a blocked connector with no neighbour
    with pytest.raises(TopologyError, match="inconsistent"):
        Topology.from_matrix(mat)


def test_bfs_tree_and_radius_of_gyration():
    topo = Topology.from_code("oEE")
    assert topo.bfs_tree() == ((1, 0, 4), (2, 1, 4))
    assert topo.radius_of_gyration() == pytest.approx(np.sqrt(2 / 3))
