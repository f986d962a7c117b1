"""Independent re-computations for the tests: a saved design's wrenches from its record's rotor list alone (no
package geometry), and segment distances in exact rational arithmetic."""

from __future__ import annotations

from decimal import Decimal, localcontext
from fractions import Fraction

import numpy as np


def wrenches_from_rotors(rec: dict, c_f: float, c_m: float) -> np.ndarray:
    """(K, 6) body wrenches [force N, torque N m] the record's inputs ``u`` produce with its rotor positions,
    axes and spin directions."""
    u = np.array(rec["u"])
    wrench = np.zeros((len(u), 6))
    for k, rotor in enumerate(rec["rotors"]):
        p, z = np.array(rotor["position"]), np.array(rotor["axis"])
        f = c_f * u[:, k, None] * z
        wrench[:, :3] += f
        wrench[:, 3:] += np.cross(p, f) + rotor["spin"] * c_m * u[:, k, None] * z
    return wrench


def exact_segment_distance(p0, p1, q0, q1) -> Decimal:
    """Distance between segments ``p0-p1`` and ``q0-q1`` in rational arithmetic on the exact values of the floats
    given, to 50 digits. The squared distance ``|r + s d1 - t d2|^2`` is a convex quadratic over ``[0, 1]^2``: its
    least value is at the stationary point (Cramer's rule on the normal equations) when that lies in the square,
    else on an edge, where the free parameter is the clamped minimizer of a quadratic in one variable."""
    p0, p1, q0, q1 = ([Fraction(float(x)) for x in v] for v in (p0, p1, q0, q1))
    d1 = [b - a for a, b in zip(p0, p1, strict=True)]
    d2 = [b - a for a, b in zip(q0, q1, strict=True)]
    r = [a - b for a, b in zip(p0, q0, strict=True)]

    def dot(x, y):
        return sum((a * b for a, b in zip(x, y, strict=True)), Fraction(0))

    def clamp(x):
        return min(max(x, Fraction(0)), Fraction(1))

    def squared(s, t):
        g = [a + s * b - t * c for a, b, c in zip(r, d1, d2, strict=True)]
        return dot(g, g)

    a, b, e, c, f = dot(d1, d1), dot(d1, d2), dot(d2, d2), dot(d1, r), dot(d2, r)
    candidates = [(Fraction(s), clamp((f + s * b) / e) if e else Fraction(0)) for s in (0, 1)]
    candidates += [(clamp((t * b - c) / a) if a else Fraction(0), Fraction(t)) for t in (0, 1)]
    det = a * e - b * b
    if det:
        s, t = (b * f - c * e) / det, (a * f - b * c) / det
        if 0 <= s <= 1 and 0 <= t <= 1:
            candidates.append((s, t))
    least = min(squared(s, t) for s, t in candidates)
    with localcontext() as ctx:
        ctx.prec = 50
        return (Decimal(least.numerator) / Decimal(least.denominator)).sqrt()
