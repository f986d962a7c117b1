"""Wrench-to-rotor allocation (paper §V): regularized inverse with clipping, and a saturation-aware option.

``allocate`` is the paper's closed form ``u = A^T (A A^T + delta I)^-1 W_d`` (precomputed, in normalized units),
bounded to ``[0, u_max]``. When rotors saturate, clipping changes the produced wrench arbitrarily (its
direction included); ``allocate_bounded`` instead solves the bounded least-squares problem
``min |S^-1 (A u - W_d)|^2 + delta |u / u_max|^2, 0 <= u <= u_max`` and so returns the producible wrench
closest to the request.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

from groundstation.control.model import ControlModel


def allocate(wrench: np.ndarray, model: ControlModel) -> np.ndarray:
    """Rotor inputs (4n,), rad^2/s^2, bounded to [0, u_max]."""
    return np.minimum(np.maximum(model.pinv @ wrench, 0.0), model.u_max)  # np.clip costs 4x more per call


def allocate_bounded(wrench: np.ndarray, model: ControlModel, delta: float = 1e-6) -> np.ndarray:
    """Saturation-aware rotor inputs (4n,): bounded least squares in normalized units."""
    u = np.clip(model.pinv @ wrench, 0.0, model.u_max)
    if np.all((model.pinv @ wrench >= 0) & (model.pinv @ wrench <= model.u_max)):
        return u  # nothing saturates: identical to the closed form
    a_v = model.allocation * model.u_max / model.wrench_scale[:, None]
    k = a_v.shape[1]
    lhs = np.vstack([a_v, np.sqrt(delta) * np.eye(k)])
    rhs = np.concatenate([wrench / model.wrench_scale, np.zeros(k)])
    sol = lsq_linear(lhs, rhs, bounds=(0.0, 1.0), method="bvls")
    return sol.x * model.u_max
