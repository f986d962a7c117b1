"""A motion-capture pose as the estimator takes it: when it was measured, on the estimator's clock."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class PoseMeasurement:
    t: float
    """When the pose was measured (captured), on the pose source's clock (the ground station's monotonic clock, or
    a simulator's time), s: the stamp mapped onto that clock minus the mocap's latency."""
    position: np.ndarray
    """(3,) body origin (COM), world frame, m."""
    rotation: np.ndarray
    """(3, 3) body-to-world rotation."""
