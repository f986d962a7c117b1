"""The independent check of a design against the original constraints of eq. (opti), in numpy.

The optimizer solves a reformulated NLP (lifted kinematics, separating planes, scaled inputs); what it returns is
accepted only if this check passes on the geometry recomputed from the angles. Loading an assembly file and
resuming a design sweep run the same check on the saved angles and inputs (:mod:`assembly_file`), so a design is
verified wherever it enters, not only where it was solved.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from groundstation.assembly import kinematics as kin
from groundstation.assembly.assembly import Assembly

RESIDUAL_TOLERANCE = 1e-6
"""A design meets a wrench when ``|A u - b|_inf <= RESIDUAL_TOLERANCE max(1, |b|_inf)`` (N, N m): floating
point, not modelling slack."""
BOUND_TOLERANCE = 1e-6
"""Inputs may leave [0, u_max] by this fraction of ``u_max`` (Ipopt's interior point touches its bounds)."""
ANGLE_TOLERANCE = 1e-8
"""Angles may leave [-pi/2, pi/2] by this much, rad. The one tolerance of the angle bound: the solver derives its
bound relaxation from it (:data:`SOLVER_BOUND_RELAXATION`), so a design the solver leaves at +-90 deg (the paper's
oSWS sits 9.98e-10 rad past) passes with a tenfold margin, not by the coincidence of two equal numbers."""
SOLVER_BOUND_RELAXATION = ANGLE_TOLERANCE / 10
"""How far the solver may place a variable past its bounds, absolute (rad for the angles). Ipopt relaxes every
bound by ``min(bound_relax_factor max(1, |bound|), constr_viol_tol)``; the NLP sets ``constr_viol_tol`` to this,
which is the smaller term at +-pi/2 with the default ``bound_relax_factor`` 1e-8."""


@dataclass(frozen=True)
class Verification:
    """Checks made after the solve, in numpy, independently of the solver, over ALL module pairs."""

    max_wrench_residual: float
    """max_k |A u_k - b_k|_inf, N or N m."""
    max_bound_violation: float
    """Largest violation of 0 <= u <= u_max, rad^2/s^2."""
    max_angle_violation: float
    """Largest violation of |alpha| <= pi/2, rad."""
    min_capsule_distance: float
    """Smallest distance between any two capsule axes, m (``inf`` for one module)."""
    required_distance: float
    """2 r, m: required without tolerance."""
    residual_tolerance: float
    """Largest wrench residual accepted, N or N m (``RESIDUAL_TOLERANCE`` max(1, |b|_inf))."""
    bound_tolerance: float
    """Largest input bound violation accepted, rad^2/s^2."""
    feasible: bool
    """All checks pass."""

    def failures(self) -> list[str]:
        """The checks these figures fail, one phrase each with the numbers; empty when they pass. A non-finite
        figure fails."""
        out = []
        if not self.max_wrench_residual <= self.residual_tolerance:
            out.append(f"wrench residual {self.max_wrench_residual:.3g} above {self.residual_tolerance:.3g}")
        if not self.max_bound_violation <= self.bound_tolerance:
            out.append(f"inputs {self.max_bound_violation:.3g} rad^2/s^2 outside [0, u_max]")
        if not self.max_angle_violation <= ANGLE_TOLERANCE:
            out.append(f"an angle {self.max_angle_violation:.3g} rad past +-90 deg")
        if not self.min_capsule_distance >= self.required_distance:
            out.append(f"capsule axes {self.min_capsule_distance:.10g} m apart, under 2 r = "
                       f"{self.required_distance:g} m")
        return out


def verify(assembly: Assembly, u: np.ndarray, wrenches: np.ndarray) -> Verification:
    """Check a candidate design, the angles of ``assembly`` with inputs ``u`` (K, 4n) rad^2/s^2, against the
    original constraints of eq. (opti) for ``wrenches`` (K, 6), N and N m. Non-finite inputs make the residual
    non-finite, and fail."""
    params = assembly.params
    residual = float(np.max(np.abs(u @ assembly.allocation.T - wrenches))) if len(wrenches) else 0.0
    bound = float(max(0.0, -u.min(), u.max() - params.u_max))
    angle = float(max(0.0, np.max(np.abs(assembly.alpha)) - np.pi / 2))
    dist = kin.pairwise_capsule_distances(assembly.module_positions, assembly.module_rotations, params)
    dmin = float(dist.min()) if assembly.n > 1 else float("inf")
    res_tol = RESIDUAL_TOLERANCE * (max(1.0, float(np.max(np.abs(wrenches)))) if len(wrenches) else 1.0)
    figures = Verification(residual, bound, angle, dmin, 2 * params.r, res_tol, BOUND_TOLERANCE * params.u_max,
                           feasible=False)
    return replace(figures, feasible=not figures.failures())


def input_cost(u: np.ndarray, weights: np.ndarray) -> float:
    """The paper's cost ``sum_k lambda_k |u_k|^2``, (rad^2/s^2)^2, of inputs ``u`` (K, 4n) with weights (K,)."""
    return float(np.sum(weights * np.sum(u * u, axis=1)))
