"""Independent re-computation of a saved design, from its record's rotor list alone (no package geometry)."""

from __future__ import annotations

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
