"""What the controller needs to know about an assembly, precomputed once: :class:`ControlModel`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from groundstation.assembly.assembly import Assembly

Actuation = Literal["full", "force-deficient-1", "force-deficient-2", "mixed"]


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ControlModel:
    """Mass properties, allocation and actuation structure of one assembly. Built by :meth:`from_assembly`."""

    mass: float
    """kg"""
    inertia: np.ndarray
    """(3, 3) about the COM, body frame, kg m^2."""
    allocation: np.ndarray
    """(6, 4n) A: body wrench = A u."""
    wrench_scale: np.ndarray
    """(6,) row scales S used to normalize A (N for forces, N m for torques)."""
    pinv: np.ndarray
    """(4n, 6) regularized inverse ``u_max A_v^T (A_v A_v^T + delta I)^-1 S^-1``, A_v = S^-1 A u_max."""
    u_max: float
    """rad^2/s^2"""
    actuation: Actuation
    """``full`` (rank 6); ``force-deficient-1``: one body force direction cannot be produced (the paper's
    two-module V); ``force-deficient-2``: thrust along one body axis only (flat assemblies); ``mixed``: the
    missing wrench direction involves torque (no attitude adaptation is attempted)."""
    null_force: np.ndarray
    """(k, 3) body force directions that cannot be produced (empty when fully actuated)."""

    @classmethod
    def from_assembly(cls, assembly: Assembly, delta: float = 1e-6) -> ControlModel:
        """``delta`` regularizes the inverse in normalized units (inputs / u_max, wrench / S)."""
        p = assembly.params
        s = np.array([p.c_f * p.u_max] * 3 + [p.c_f * p.u_max * p.l_arm] * 3)
        return cls._build(assembly.mass, assembly.inertia, assembly.allocation, s, p.u_max, delta)

    def without_modules(self, failed, delta: float = 1e-6) -> ControlModel:
        """The same assembly with the rotors of modules ``failed`` (indices) producing nothing: their columns of A
        are zero, so the allocation gives them zero and the rest produce the wrench alone."""
        a = np.array(self.allocation)
        for i in failed:
            a[:, 4 * i:4 * i + 4] = 0.0
        return self._build(self.mass, self.inertia, a, self.wrench_scale, self.u_max, delta)

    def can_hold(self, wrench: np.ndarray, tolerance: float = 0.01) -> bool:
        """The rotors, each within [0, u_max], produce ``wrench`` (body frame) to ``tolerance`` of the scales."""
        from scipy.optimize import lsq_linear

        a_v = self.allocation * self.u_max / self.wrench_scale[:, None]
        sol = lsq_linear(a_v, np.asarray(wrench, float) / self.wrench_scale, bounds=(0.0, 1.0), method="bvls")
        return bool(np.max(np.abs(a_v @ sol.x - wrench / self.wrench_scale)) <= tolerance)

    @classmethod
    def _build(cls, mass: float, inertia: np.ndarray, a: np.ndarray, s: np.ndarray, u_max: float,
               delta: float) -> ControlModel:
        a_v = a * u_max / s[:, None]
        pinv = u_max * a_v.T @ np.linalg.inv(a_v @ a_v.T + delta * np.eye(6)) / s[None, :]
        u_svd, sv, _ = np.linalg.svd(a_v)
        null = u_svd[:, sv < 1e-9 * sv[0]]
        force_part, torque_part = null[:3], null[3:]
        if null.shape[1] == 0:
            actuation: Actuation = "full"
            null_force = np.zeros((0, 3))
        elif np.linalg.norm(torque_part) < 1e-6:
            actuation = "force-deficient-1" if null.shape[1] == 1 else "force-deficient-2"
            null_force = force_part.T
        else:
            actuation, null_force = "mixed", np.zeros((0, 3))
        return cls(mass=mass, inertia=_frozen(inertia), allocation=_frozen(a), wrench_scale=_frozen(s),
                   pinv=_frozen(pinv), u_max=u_max, actuation=actuation, null_force=_frozen(null_force))

