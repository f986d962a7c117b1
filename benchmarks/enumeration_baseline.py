"""The straightforward enumeration the issue measures against: a Python set of canonical tuples.

A configuration is a sorted tuple of lattice bonds ``((x1, y1), (x2, y2))``, translated so the minimum
coordinates are 0; its canonical form is the smallest such tuple over the symmetry group. Each level is grown
from the previous one by attaching a module at every free connector. Nothing here is shared with the package,
so the tests also use it as an independent oracle for the counts of every symmetry group.
"""

from __future__ import annotations

import time

ROT90 = lambda x, y: (-y, x)  # noqa: E731
MIRROR = lambda x, y: (-x, y)  # noqa: E731


def _group(symmetry: str):
    def rot(k):
        def f(x, y):
            for _ in range(k):
                x, y = ROT90(x, y)
            return x, y
        return f

    rots = [rot(k) for k in range(4)]
    if symmetry == "none":
        return [rots[0]]
    if symmetry == "C4":
        return rots
    if symmetry == "D4":
        return rots + [lambda x, y, r=r: r(*MIRROR(x, y)) for r in rots]
    raise ValueError(symmetry)


def _normalize(bonds):
    xs = [c[0] for b in bonds for c in b]
    ys = [c[1] for b in bonds for c in b]
    mx, my = min(xs), min(ys)
    return tuple(sorted(tuple(sorted(((a[0] - mx, a[1] - my), (b[0] - mx, b[1] - my)))) for a, b in bonds))


def canonical(bonds, group) -> tuple:
    return min(_normalize([(g(*a), g(*b)) for a, b in bonds]) for g in group)


def enumerate_baseline(n_max: int, symmetry: str = "C4"):
    """Yield ``(n, available, non_isomorphic, cpu_s)`` for ``n = 1 .. n_max``."""
    group = _group(symmetry)
    yield 1, 1, 1, 0.0
    level = {()}  # n = 1: no bonds
    for n in range(2, n_max + 1):
        t0 = time.process_time()
        new, available = set(), 0
        for bonds in level:
            cells = {c for b in bonds for c in b} or {(0, 0)}
            for x, y in cells:
                for dx, dy in ((0, 1), (-1, 0), (0, -1), (1, 0)):
                    q = (x + dx, y + dy)
                    if q in cells:
                        continue
                    available += 1
                    new.add(canonical(bonds + (((x, y), q),), group))
        level = new
        yield n, available, len(level), time.process_time() - t0
