"""Compiled kernels of the enumeration: canonical codes of lattice bond trees and level expansion.

A configuration with ``n`` modules is stored as lattice cells ``(x, y)`` plus one parent index per cell
(``parent[0] = -1``; edge ``k`` joins cell ``k + 1`` and ``parent[k + 1]``). Candidates are told apart by their
exact canonical code (:mod:`groundstation.assembly.canonical_code`).

Deduplication uses an open-addressing hash table over a 64-bit hash of the code, with an exact comparison of
the stored codes on every hash match, so a hash collision can never merge two distinct configurations.

Why numba: the straightforward pure-Python version (see ``benchmarks/enumeration_baseline.py``) spends its time
in per-candidate interpreter overhead; the loops below are the same algorithm without that overhead.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from groundstation.assembly.canonical_code import canonical_code
from groundstation.assembly.lattice import DIRECTIONS

_DX = np.ascontiguousarray(DIRECTIONS[:, 0])
_DY = np.ascontiguousarray(DIRECTIONS[:, 1])
@njit(cache=True, nogil=True)
def _hash_code(code, m):
    h = np.uint64(0xCBF29CE484222325)
    for k in range(m):
        h ^= np.uint64(code[k] & 0xFFFFFFFF)
        h *= np.uint64(0x100000001B3)
        h ^= h >> np.uint64(29)
    return h


@njit(cache=True, nogil=True)
def expand_level(cells_x, cells_y, parent, mats, capacity_hint):
    """Attach one module at every free connector of every configuration; keep one per isomorphism class.

    ``cells_x, cells_y, parent`` are ``(M, n)`` arrays of the level-``n`` configurations in canonical placement
    (coordinates in ``[0, n - 1]``). Returns ``(available, codes, src)``: the number of candidates generated
    (the paper's "available configurations"), the ``(U, n)`` canonical codes of the ``U`` distinct children and,
    per child, ``src[u] = (m, i, d, g)``: parent configuration, cell the new module attaches to, connector
    index at that cell, and the group element of the canonical placement.
    """
    m_count, n = cells_x.shape
    n1 = n + 1
    ne = n
    cap = max(capacity_hint, 16)
    codes = np.empty((cap, ne), dtype=np.int32)
    hashes = np.empty(cap, dtype=np.uint64)
    src = np.empty((cap, 4), dtype=np.int32)
    tcap = 64
    while tcap < 2 * cap:
        tcap *= 2
    table = np.full(tcap, -1, dtype=np.int64)
    count = 0
    available = 0

    grid_w = n + 2
    grid = np.zeros((grid_w, grid_w), dtype=np.bool_)
    cx = np.empty(n1, dtype=np.int64)
    cy = np.empty(n1, dtype=np.int64)
    ea = np.empty(ne, dtype=np.int64)
    eb = np.empty(ne, dtype=np.int64)
    best = np.empty(ne, dtype=np.int32)
    tmp = np.empty(ne, dtype=np.int32)
    tx = np.empty(n1, dtype=np.int64)
    ty = np.empty(n1, dtype=np.int64)

    for m in range(m_count):
        for i in range(n):
            cx[i] = cells_x[m, i]
            cy[i] = cells_y[m, i]
            grid[cx[i] + 1, cy[i] + 1] = True
        for k in range(n - 1):
            ea[k] = parent[m, k + 1]
            eb[k] = k + 1
        eb[ne - 1] = n
        for i in range(n):
            for d in range(4):
                qx = cx[i] + _DX[d]
                qy = cy[i] + _DY[d]
                if grid[qx + 1, qy + 1]:
                    continue
                available += 1
                cx[n] = qx
                cy[n] = qy
                ea[ne - 1] = i
                g = canonical_code(cx, cy, ea, eb, mats, best, tmp, tx, ty)
                h = _hash_code(best, ne)
                slot = np.int64(h & np.uint64(tcap - 1))
                found = False
                while table[slot] >= 0:
                    u = table[slot]
                    if hashes[u] == h:
                        same = True
                        for k in range(ne):
                            if codes[u, k] != best[k]:
                                same = False
                                break
                        if same:
                            found = True
                            break
                    slot = (slot + 1) & (tcap - 1)
                if found:
                    continue
                if count == cap:
                    cap *= 2
                    codes2 = np.empty((cap, ne), dtype=np.int32)
                    codes2[:count] = codes[:count]
                    codes = codes2
                    hashes2 = np.empty(cap, dtype=np.uint64)
                    hashes2[:count] = hashes[:count]
                    hashes = hashes2
                    src2 = np.empty((cap, 4), dtype=np.int32)
                    src2[:count] = src[:count]
                    src = src2
                codes[count] = best
                hashes[count] = h
                src[count, 0] = m
                src[count, 1] = i
                src[count, 2] = d
                src[count, 3] = g
                table[slot] = count
                count += 1
                if 2 * count > tcap:
                    # Rehash into a table twice as large, from the stored hashes.
                    tcap *= 2
                    table = np.full(tcap, -1, dtype=np.int64)
                    for u in range(count):
                        s = np.int64(hashes[u] & np.uint64(tcap - 1))
                        while table[s] >= 0:
                            s = (s + 1) & (tcap - 1)
                        table[s] = u
        for i in range(n):
            grid[cx[i] + 1, cy[i] + 1] = False
    return available, codes[:count].copy(), src[:count].copy()


@njit(cache=True, nogil=True)
def materialize_children(cells_x, cells_y, parent, src, mats):
    """Build the child configurations named by ``src`` (from ``expand_level``) in canonical placement."""
    u_count = src.shape[0]
    n = cells_x.shape[1]
    n1 = n + 1
    out_x = np.empty((u_count, n1), dtype=np.int16)
    out_y = np.empty((u_count, n1), dtype=np.int16)
    out_p = np.empty((u_count, n1), dtype=np.int16)
    tx = np.empty(n1, dtype=np.int64)
    ty = np.empty(n1, dtype=np.int64)
    for u in range(u_count):
        m = src[u, 0]
        i = src[u, 1]
        d = src[u, 2]
        g = src[u, 3]
        a = mats[g, 0, 0]
        b = mats[g, 0, 1]
        c = mats[g, 1, 0]
        e = mats[g, 1, 1]
        minx = 1 << 30
        miny = 1 << 30
        for k in range(n1):
            if k < n:
                x0 = np.int64(cells_x[m, k])
                y0 = np.int64(cells_y[m, k])
            else:
                x0 = np.int64(cells_x[m, i]) + _DX[d]
                y0 = np.int64(cells_y[m, i]) + _DY[d]
            x = a * x0 + b * y0
            y = c * x0 + e * y0
            tx[k] = x
            ty[k] = y
            minx = min(minx, x)
            miny = min(miny, y)
        for k in range(n1):
            out_x[u, k] = tx[k] - minx
            out_y[u, k] = ty[k] - miny
            out_p[u, k] = parent[m, k] if k < n else i
    return out_x, out_y, out_p

