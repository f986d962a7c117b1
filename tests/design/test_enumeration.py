import numpy as np
import pytest

from benchmarks.enumeration_baseline import _group, canonical, enumerate_baseline
from groundstation.design.enumeration import SamplingPolicy, enumerate_levels, radii_of_gyration, sample_indices
from groundstation.errors import UsageError

# Paper Table I (C4): available and non-isomorphic configurations for n = 1..11.
AVAILABLE = [1, 4, 6, 16, 68, 272, 1242, 5740, 27960, 136628, 678204]
NON_ISOMORPHIC = [1, 1, 2, 7, 24, 97, 401, 1772, 7930, 36335, 168249]


def test_table_i_counts_up_to_10():
    levels = list(enumerate_levels(10))
    assert [lv.available for lv in levels] == AVAILABLE[:10]
    assert [lv.non_isomorphic for lv in levels] == NON_ISOMORPHIC[:10]
    assert all(lv.kept == lv.non_isomorphic for lv in levels)


@pytest.mark.slow
def test_table_i_count_11():
    *_, last = enumerate_levels(11)
    assert (last.available, last.non_isomorphic) == (AVAILABLE[10], NON_ISOMORPHIC[10])


@pytest.mark.parametrize("symmetry", ["none", "C4", "D4"])
def test_counts_match_independent_baseline(symmetry):
    ours = [(lv.n, lv.available, lv.non_isomorphic) for lv in enumerate_levels(8, symmetry)]
    theirs = [(n, a, m) for n, a, m, _ in enumerate_baseline(8, symmetry)]
    assert ours == theirs


@pytest.mark.parametrize("symmetry", ["C4", "D4"])
def test_every_configuration_is_a_tree_without_overlap_and_classes_are_distinct(symmetry):
    group = _group(symmetry)
    for lv in enumerate_levels(8, symmetry):
        seen = set()
        for k in range(lv.kept):
            cells = list(zip(lv.cells_x[k].tolist(), lv.cells_y[k].tolist(), strict=True))
            assert len(set(cells)) == lv.n  # no two modules share a cell
            edges = [(int(lv.parent[k, j]), j) for j in range(1, lv.n)]
            assert len(edges) == lv.n - 1
            assert all(abs(cells[a][0] - cells[b][0]) + abs(cells[a][1] - cells[b][1]) == 1 for a, b in edges)
            assert all(0 <= int(lv.parent[k, j]) < j for j in range(1, lv.n))  # parents first: connected, acyclic
            seen.add(canonical(tuple((cells[a], cells[b]) for a, b in edges), group) if lv.n > 1 else ())
        assert len(seen) == lv.kept  # no two kept configurations are isomorphic (independent check)


def test_levels_convert_to_valid_topologies():
    *_, lv = enumerate_levels(6)
    tops = lv.topologies()
    assert len({t.canonical_key("C4") for t in tops}) == 97
    assert all(t.n == 6 and len(t.edges) == 5 for t in tops)
    np.testing.assert_allclose(lv.radii_of_gyration(), [t.radius_of_gyration() for t in tops])


def test_sampling_is_reproducible_and_keeps_n_n():
    policy = SamplingPolicy(keep=50, sigma=0.5, seed=7)
    a = list(enumerate_levels(12, sampling=policy))
    b = list(enumerate_levels(12, sampling=policy))
    c = list(enumerate_levels(12, sampling=SamplingPolicy(keep=50, sigma=0.5, seed=8)))
    for la, lb in zip(a, b, strict=True):
        np.testing.assert_array_equal(la.cells_x, lb.cells_x)
        np.testing.assert_array_equal(la.parent, lb.parent)
        assert la.kept == min(50, la.non_isomorphic)
    assert not np.array_equal(a[-1].cells_x, c[-1].cells_x)


def test_sampling_keeps_everything_while_level_is_small():
    exhaustive = list(enumerate_levels(5))
    sampled = list(enumerate_levels(5, sampling=SamplingPolicy(keep=24)))
    assert [lv.kept for lv in sampled] == [lv.non_isomorphic for lv in exhaustive]


def test_schemes_order_radius_of_gyration():
    mean_g = {}
    for scheme in ("compact", "uniform", "spread"):
        *_, last = enumerate_levels(14, sampling=SamplingPolicy(keep=200, sigma=0.5, scheme=scheme, seed=1))
        mean_g[scheme] = float(last.radii_of_gyration().mean())
    assert mean_g["compact"] < mean_g["uniform"] < mean_g["spread"]


def test_draw_probabilities_match_gaussian_weights():
    # Drawing one of M without replacement must follow P_m = w_m / sum(w).
    g = np.array([1.0, 1.2, 1.5, 2.0, 3.0])
    sigma = 0.6
    w = np.exp(-((g - g.min()) ** 2) / (2 * sigma**2))
    p = w / w.sum()
    rng = np.random.default_rng(3)
    trials = 40000
    hits = np.bincount([sample_indices(g, SamplingPolicy(keep=1, sigma=sigma), rng)[0] for _ in range(trials)],
                       minlength=5)
    tolerance = 4 * np.sqrt(p * (1 - p) / trials) + 1e-3  # four standard errors per category
    assert np.all(np.abs(hits / trials - p) <= tolerance), (hits / trials, p)
    # reversed scheme: largest radius most likely
    hits = np.bincount([sample_indices(g, SamplingPolicy(keep=1, sigma=sigma, scheme="spread"), rng)[0]
                        for _ in range(4000)], minlength=5)
    assert hits.argmax() == 4


def test_radius_of_gyration_formula():
    x = np.array([[0, 1, 2]])
    y = np.array([[0, 0, 0]])
    assert radii_of_gyration(x, y)[0] == pytest.approx(np.sqrt(2 / 3))


@pytest.mark.parametrize("kwargs", [dict(keep=0), dict(keep=5, sigma=0.0), dict(keep=5, scheme="dense")])
def test_bad_sampling_policy(kwargs):
    with pytest.raises(UsageError):
        SamplingPolicy(**kwargs)


def test_bad_level_count_and_group():
    with pytest.raises(UsageError, match="at least 1"):
        list(enumerate_levels(0))
    with pytest.raises(UsageError, match="unknown symmetry"):
        list(enumerate_levels(3, "C3"))
