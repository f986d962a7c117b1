"""What a motion-capture system makes of the physics pose: one sensor model for ``simulate`` (the samples go straight
to the estimator) and the ``fly`` dry run (:class:`~sim.virtual_mocap.VirtualMocap` publishes them on Zenoh), so
the two fly on the same measurements."""

from __future__ import annotations

from collections import deque

import numpy as np

from groundstation.control.state import RigidState
from groundstation.estimation.measurement import PoseMeasurement
from groundstation.rotations import rotvec_to_matrix


class MocapSensor:
    """Samples the physics pose every ``1 / rate_hz`` s of simulated time, adds Gaussian noise (``position_noise``
    m and ``attitude_noise`` rad std per axis, the attitude's as a body-frame rotation vector) and delivers each
    sample ``latency`` s after its capture. ``rate_hz`` 0: no samples."""

    def __init__(self, rate_hz: float, position_noise: float, attitude_noise: float, latency: float,
                 rng: np.random.Generator) -> None:
        self.period = 1.0 / rate_hz if rate_hz > 0 else float("inf")
        """s"""
        self.latency = latency
        """s"""
        self._pos_noise, self._att_noise = position_noise, attitude_noise
        self._rng = rng
        self._next = 0.0
        self._pending: deque[PoseMeasurement] = deque()

    def observe(self, t: float, state: RigidState) -> list[PoseMeasurement]:
        """After a physics step to ``t`` (s) with the true ``state``: the samples delivered by ``t``, captured
        ``latency`` earlier (their ``t`` is the capture time)."""
        if self.period == float("inf"):
            return []
        if t + 1e-9 >= self._next:
            self._next += self.period * max(1, int((t - self._next) / self.period) + 1)
            pos = state.position + self._rng.normal(0.0, self._pos_noise, 3)
            rot = state.rotation @ rotvec_to_matrix(self._rng.normal(0.0, self._att_noise, 3))
            self._pending.append(PoseMeasurement(t, pos, rot))
        out = []
        while self._pending and self._pending[0].t + self.latency <= t + 1e-9:
            out.append(self._pending.popleft())
        return out
