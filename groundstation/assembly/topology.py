"""Topology of an assembly: an edge-labelled tree of modules on the square lattice (paper §II-B, §III).

A :class:`Topology` is what enumeration produces and what the optimizer turns into a 3D design: ``n`` lattice
cells (one module each) and ``n - 1`` lattice bonds (one rigid connection each). It is always stored
*normalized*: translated so the minimum x and y are 0, cells in reading order of the paper's matrix
(top row first, left to right), so cell 0 is the paper's root, "the first upper-left module". Edge labels
``(c_v, c_h)`` are the connectors used on each side (see :mod:`groundstation.assembly.lattice`).

Three views of the same object:

* the paper's matrix (:meth:`Topology.to_matrix` / :meth:`Topology.from_matrix`): each module a 3x3 block
  with centre ``6``; neighbouring blocks share their border entry, which is ``2`` for a connection (the two
  connectors' ``1`` summed), ``3`` for a connector blocked by an adjacent module it is not connected to, and
  ``1`` for a free connector; corners are ``0``.
* a compact code (:attr:`Topology.code`), SMILES-like: ``o`` is the root, a letter ``N W S E`` steps to a child
  through that side, branches other than the last are in parentheses. ``oE(N)S`` is root - east - then from
  that module one branch north and one south.
* the canonical form under a symmetry group (:meth:`Topology.canonical`), equal for isomorphic topologies.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from groundstation.assembly.lattice import DIRECTION_LETTERS, DIRECTIONS, connector_between, group_matrices
from groundstation.errors import TopologyError

FREE, CONNECTED, BLOCKED, CENTRE = 1, 2, 3, 6


Cell = tuple[int, int]


@dataclass(frozen=True)
class Topology:
    """A tree of ``n`` modules on the square lattice, normalized (see module docstring).

    Build one with :meth:`from_cells_edges`, :meth:`from_matrix`, :meth:`from_code` or :meth:`from_arrays`.
    """

    cells: tuple[Cell, ...]
    """Lattice cell ``(x, y)`` of each module, lattice units (one unit = one module pitch, ``2 l_c``)."""
    edges: tuple[tuple[int, int], ...]
    """Connections as module index pairs ``(i, j)``, ``i < j``, sorted."""

    def __post_init__(self) -> None:
        n = len(self.cells)
        if n < 1:
            raise TopologyError("a topology needs at least one module")
        if len(set(self.cells)) != n:
            raise TopologyError("two modules occupy the same lattice cell")
        if len(self.edges) != n - 1:
            raise TopologyError(f"a tree of {n} modules has {n - 1} connections, got {len(self.edges)}")
        for i, j in self.edges:
            if not (0 <= i < j < n):
                raise TopologyError(f"connection {(i, j)} does not name two modules of {n}")
            (xi, yi), (xj, yj) = self.cells[i], self.cells[j]
            if abs(xi - xj) + abs(yi - yj) != 1:
                raise TopologyError(f"modules {i} and {j} are connected but not lattice neighbours")
        if len(self._bfs_order()) != n:
            raise TopologyError("the connections do not join all modules into one tree")
        if (self.cells, self.edges) != _normalize(self.cells, self.edges):
            raise TopologyError("topology is not normalized; build it with Topology.from_cells_edges")

    # ----------------------------------------------------------------------------------------------------------
    # construction
    @classmethod
    def from_cells_edges(cls, cells, edges) -> Topology:
        """Normalize and validate any translation and ordering of cells and ``(i, j)`` connections."""
        cells = [tuple(int(v) for v in c) for c in cells]
        edges = [(int(i), int(j)) for i, j in edges]
        n = len(cells)
        for i, j in edges:
            if not (0 <= i < n and 0 <= j < n) or i == j:
                raise TopologyError(f"connection {(i, j)} does not name two modules of {n}")
        return cls(*_normalize(cells, edges))

    @classmethod
    def from_arrays(cls, cells_x, cells_y, parent) -> Topology:
        """From enumeration arrays: cell coordinates and one parent index per module (``parent[0] = -1``)."""
        cells = list(zip(np.asarray(cells_x).tolist(), np.asarray(cells_y).tolist(), strict=True))
        edges = [(int(p), k) for k, p in enumerate(np.asarray(parent).tolist()) if k > 0]
        return cls.from_cells_edges(cells, edges)

    @classmethod
    def single(cls) -> Topology:
        """One module alone."""
        return cls(cells=((0, 0),), edges=())

    # ----------------------------------------------------------------------------------------------------------
    # basic properties
    @property
    def n(self) -> int:
        """Number of modules."""
        return len(self.cells)

    @cached_property
    def _adjacency(self) -> tuple[tuple[int, ...], ...]:
        adj: list[list[int]] = [[] for _ in self.cells]
        for i, j in self.edges:
            adj[i].append(j)
            adj[j].append(i)
        return tuple(tuple(sorted(a, key=lambda k, i=i: connector_between(self.cells[i], self.cells[k])))
                     for i, a in enumerate(adj))

    def _bfs_order(self) -> list[int]:
        adj: dict[int, list[int]] = {i: [] for i in range(len(self.cells))}
        for i, j in self.edges:
            adj[i].append(j)
            adj[j].append(i)
        seen, order, queue = {0}, [], deque([0])
        while queue:
            v = queue.popleft()
            order.append(v)
            for w in adj[v]:
                if w not in seen:
                    seen.add(w)
                    queue.append(w)
        return order

    def connector(self, i: int, j: int) -> int:
        """Connector number (1..4) on module ``i`` used by its connection to module ``j``."""
        return connector_between(self.cells[i], self.cells[j]) + 1

    def bfs_tree(self) -> tuple[tuple[int, int, int], ...]:
        """Breadth-first traversal from the root: ``(child, parent, connector on parent 1..4)`` per non-root module.

        Children of a module are visited in connector order, so the traversal is a function of the topology.
        """
        out, seen, queue = [], {0}, deque([0])
        while queue:
            v = queue.popleft()
            for w in self._adjacency[v]:
                if w not in seen:
                    seen.add(w)
                    out.append((w, v, self.connector(v, w)))
                    queue.append(w)
        return tuple(out)

    def radius_of_gyration(self) -> float:
        """Radius of gyration of the module centres, lattice units (paper §III-B, ``g_m``)."""
        c = np.asarray(self.cells, dtype=float)
        return float(np.sqrt(np.mean(np.sum((c - c.mean(axis=0)) ** 2, axis=1))))

    def free_connectors(self) -> int:
        """Number of connectors facing an empty cell (entries ``1`` of the matrix view)."""
        occupied = set(self.cells)
        return sum((x + dx, y + dy) not in occupied for x, y in self.cells for dx, dy in DIRECTIONS.tolist())

    # ----------------------------------------------------------------------------------------------------------
    # matrix view
    def to_matrix(self) -> np.ndarray:
        """The paper's matrix representation, shape ``(2h + 1, 2w + 1)`` for a ``w x h`` bounding box."""
        w = 1 + max(x for x, _ in self.cells)
        h = 1 + max(y for _, y in self.cells)
        mat = np.zeros((2 * h + 1, 2 * w + 1), dtype=np.int8)
        occupied = {c: i for i, c in enumerate(self.cells)}
        connected = {frozenset(e) for e in self.edges}
        for i, (x, y) in enumerate(self.cells):
            r, c = 2 * (h - 1 - y) + 1, 2 * x + 1
            mat[r, c] = CENTRE
            for dx, dy in DIRECTIONS.tolist():
                rr, cc = r - dy, c + dx  # matrix rows grow southward
                j = occupied.get((x + dx, y + dy))
                if j is None:
                    mat[rr, cc] = FREE
                else:
                    mat[rr, cc] = CONNECTED if frozenset((i, j)) in connected else BLOCKED
        return mat

    @classmethod
    def from_matrix(cls, matrix) -> Topology:
        """Inverse of :meth:`to_matrix`; checks every entry is consistent with the modules around it."""
        mat = np.asarray(matrix)
        if mat.ndim != 2 or mat.shape[0] % 2 == 0 or mat.shape[1] % 2 == 0:
            raise TopologyError(f"matrix must be 2D with odd sides, got shape {mat.shape}")
        rows, cols = np.nonzero(mat == CENTRE)
        if np.any((rows % 2 == 0) | (cols % 2 == 0)):
            raise TopologyError("a centre entry 6 is not at an odd row and column")
        h = mat.shape[0] // 2
        cells = [(int(c) // 2, h - 1 - int(r) // 2) for r, c in zip(rows, cols, strict=True)]
        index = {c: i for i, c in enumerate(cells)}
        edges = []
        for (x, y), i in index.items():
            for dx, dy in ((1, 0), (0, -1)):  # each shared border once: east and south
                j = index.get((x + dx, y + dy))
                r, c = 2 * (h - 1 - y) + 1, 2 * x + 1
                if j is not None and mat[r - dy, c + dx] == CONNECTED:
                    edges.append((i, j))
        topo = cls.from_cells_edges(cells, edges)
        if not np.array_equal(topo.to_matrix(), mat):
            raise TopologyError("matrix entries are inconsistent with the modules and connections it encodes")
        return topo

    # ----------------------------------------------------------------------------------------------------------
    # compact code
    @cached_property
    def code(self) -> str:
        """Compact, human-readable serialisation (see module docstring); :meth:`from_code` inverts it."""
        children: dict[int, list[int]] = {i: [] for i in range(self.n)}
        for child, parent, _ in self.bfs_tree():
            children[parent].append(child)

        def write(v: int) -> str:
            parts = []
            kids = children[v]
            for idx, w in enumerate(kids):
                step = DIRECTION_LETTERS[self.connector(v, w) - 1] + write(w)
                parts.append(step if idx == len(kids) - 1 else f"({step})")
            return "".join(parts)

        return "o" + write(0)

    @classmethod
    def from_code(cls, code: str) -> Topology:
        """Parse a compact code such as ``oE(N)S``."""
        if not code.startswith("o"):
            raise TopologyError(f"topology code must start with 'o', got {code!r}")
        cells: list[Cell] = [(0, 0)]
        edges: list[tuple[int, int]] = []
        stack: list[int] = []
        current = 0
        for ch in code[1:]:
            if ch == "(":
                stack.append(current)
            elif ch == ")":
                if not stack:
                    raise TopologyError(f"unbalanced ')' in topology code {code!r}")
                current = stack.pop()
            elif ch in DIRECTION_LETTERS:
                dx, dy = DIRECTIONS[DIRECTION_LETTERS.index(ch)].tolist()
                x, y = cells[current]
                cells.append((x + dx, y + dy))
                edges.append((current, len(cells) - 1))
                current = len(cells) - 1
            else:
                raise TopologyError(f"unexpected character {ch!r} in topology code {code!r}")
        if stack:
            raise TopologyError(f"unbalanced '(' in topology code {code!r}")
        return cls.from_cells_edges(cells, edges)

    # ----------------------------------------------------------------------------------------------------------
    # symmetry
    def canonical_key(self, symmetry: str = "C4") -> tuple[int, ...]:
        """Exact canonical code under ``symmetry``: equal keys <=> isomorphic topologies."""
        return canonical_placement(self, symmetry)[1]

    def canonical(self, symmetry: str = "C4") -> Topology:
        """The representative of this topology's isomorphism class under ``symmetry``."""
        return canonical_placement(self, symmetry)[0]

    def is_isomorphic(self, other: Topology, symmetry: str = "C4") -> bool:
        return self.n == other.n and self.canonical_key(symmetry) == other.canonical_key(symmetry)

    def transformed(self, matrix) -> Topology:
        """The topology with every cell mapped by a 2x2 integer lattice matrix (a rotation or mirror)."""
        m = np.asarray(matrix, dtype=np.int64)
        cells = (np.asarray(self.cells, dtype=np.int64) @ m.T).tolist()
        return Topology.from_cells_edges(cells, self.edges)


def canonical_placement(topo: Topology, symmetry: str) -> tuple[Topology, tuple[int, ...]]:
    """Canonical representative and exact key of ``topo`` under ``symmetry``, using the enumeration kernel."""
    # numba (~0.1 s to import) is paid only by code that canonicalizes.
    from groundstation.assembly.canonical_code import canonical_code

    mats = group_matrices(symmetry)
    if topo.n == 1:
        return topo, ()
    cx = np.array([c[0] for c in topo.cells], dtype=np.int64)
    cy = np.array([c[1] for c in topo.cells], dtype=np.int64)
    ea = np.array([e[0] for e in topo.edges], dtype=np.int64)
    eb = np.array([e[1] for e in topo.edges], dtype=np.int64)
    out = np.empty(topo.n - 1, dtype=np.int32)
    g = canonical_code(cx, cy, ea, eb, mats, out, np.empty_like(out), np.empty_like(cx), np.empty_like(cx))
    return topo.transformed(mats[g]), tuple(int(v) for v in out)


def _normalize(cells, edges) -> tuple[tuple[Cell, ...], tuple[tuple[int, int], ...]]:
    """Translate to minimum x = y = 0, order cells in matrix reading order, sort edges."""
    minx = min(x for x, _ in cells)
    miny = min(y for _, y in cells)
    shifted = [(x - minx, y - miny) for x, y in cells]
    order = sorted(range(len(shifted)), key=lambda i: (-shifted[i][1], shifted[i][0]))
    rank = {old: new for new, old in enumerate(order)}
    new_edges = sorted(tuple(sorted((rank[i], rank[j]))) for i, j in edges)
    return tuple(shifted[i] for i in order), tuple(new_edges)
