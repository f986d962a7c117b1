"""Hypothesis strategies shared by the tests: random lattice trees grown module by module."""

from hypothesis import strategies as st

STEPS = ((0, 1), (-1, 0), (0, -1), (1, 0))


@st.composite
def lattice_trees(draw, min_n: int = 1, max_n: int = 14):
    """Cells and edges of a random tree of adjacent lattice modules, in random order and translation."""
    n = draw(st.integers(min_n, max_n))
    cells = [(draw(st.integers(-5, 5)), draw(st.integers(-5, 5)))]
    edges = []
    while len(cells) < n:
        options = [(i, (cells[i][0] + dx, cells[i][1] + dy)) for i in range(len(cells)) for dx, dy in STEPS
                   if (cells[i][0] + dx, cells[i][1] + dy) not in cells]
        i, q = draw(st.sampled_from(options))
        cells.append(q)
        edges.append((i, len(cells) - 1))
    perm = draw(st.permutations(range(n)))
    inv = {old: new for new, old in enumerate(perm)}
    return [cells[p] for p in perm], [(inv[a], inv[b]) for a, b in edges]
