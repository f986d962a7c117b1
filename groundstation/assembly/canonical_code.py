"""The canonical code of a lattice bond tree (compiled): the exact isomorphism key of a topology.

A configuration with ``n`` modules is lattice cells ``(x, y)`` plus its edges. Its *canonical code* is exact, not a
hash: for every element of the symmetry group the cells are transformed and translated so the minimum x and y
are 0, every edge becomes ``((py * S + px) << 1) | vertical`` with ``(px, py)`` its lower-left end and
``S = n`` the stride, the ``n - 1`` edge codes are sorted, and the lexicographically smallest sorted vector over
the group is the code. Two configurations are isomorphic exactly when their codes are equal, because a tree's
cells are the end points of its edges (``n >= 2``).

It lives with the assembly model (``Topology.canonical`` uses it); the enumeration's kernels
(:mod:`groundstation.design.kernels`) call it for every candidate.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_INSERTION_SORT_MAX = 24


@njit(cache=True, nogil=True)
def _sort_small(a, m):
    if m > _INSERTION_SORT_MAX:
        a[:m] = np.sort(a[:m])
        return
    for i in range(1, m):
        v = a[i]
        j = i - 1
        while j >= 0 and a[j] > v:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = v


@njit(cache=True, nogil=True)
def canonical_code(cx, cy, ea, eb, mats, out, tmp, tx, ty):
    """Write the canonical code of the tree (cells ``cx, cy``; edges ``ea[k]-eb[k]``) into ``out``.

    Returns the index of the group element that produces it. ``tmp``, ``tx`` and ``ty`` are scratch arrays of
    at least ``n - 1``, ``n`` and ``n`` entries.
    """
    n = cx.shape[0]
    ne = ea.shape[0]
    stride = n
    best_g = -1
    for g in range(mats.shape[0]):
        a = mats[g, 0, 0]
        b = mats[g, 0, 1]
        c = mats[g, 1, 0]
        d = mats[g, 1, 1]
        minx = 1 << 30
        miny = 1 << 30
        for i in range(n):
            x = a * cx[i] + b * cy[i]
            y = c * cx[i] + d * cy[i]
            tx[i] = x
            ty[i] = y
            if x < minx:
                minx = x
            if y < miny:
                miny = y
        for k in range(ne):
            i = ea[k]
            j = eb[k]
            px = min(tx[i], tx[j]) - minx
            py = min(ty[i], ty[j]) - miny
            vertical = 0 if ty[i] == ty[j] else 1
            tmp[k] = ((py * stride + px) << 1) | vertical
        _sort_small(tmp, ne)
        better = best_g < 0
        if not better:
            for k in range(ne):
                if tmp[k] != out[k]:
                    better = tmp[k] < out[k]
                    break
        if better:
            for k in range(ne):
                out[k] = tmp[k]
            best_g = g
    return best_g
