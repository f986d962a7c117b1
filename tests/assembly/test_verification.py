from decimal import Decimal

import numpy as np
import pytest
from scipy.optimize import brentq

from groundstation.assembly import kinematics as kin
from groundstation.assembly.assembly import Assembly
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.assembly.verification import ANGLE_TOLERANCE, SOLVER_BOUND_RELAXATION, input_cost, verify
from tests.recheck import exact_segment_distance

P = ModuleParams()
NO_WRENCH = (np.zeros((1, 24)), np.zeros((1, 6)))
"""Inputs and wrenches that meet each other exactly for six modules: only the geometry is checked."""


def _v_pair(alpha):
    """Two modules (oS) with a hover wrench met by the least-norm inputs."""
    asm = Assembly(Topology.from_code("oS"), P, np.asarray(alpha, float))
    b = np.array([[0, 0, 4.7, 0, 0, 0]])
    return asm, b @ np.linalg.pinv(asm.allocation).T, b


def test_verify_detects_each_violation():
    asm, u, b = _v_pair(np.radians([22.5, 0, -45]))
    ok = verify(asm, u, b)
    assert ok.feasible and ok.failures() == []
    assert ok.max_wrench_residual < 1e-12 and ok.residual_tolerance == pytest.approx(4.7e-6)
    residual = verify(asm, u * 1.01, b)
    assert not residual.feasible and residual.max_wrench_residual == pytest.approx(0.047, rel=1e-9)
    assert residual.failures() == ["wrench residual 0.047 above 4.7e-06"]
    negative = verify(asm, u - u.max(), b)
    assert not negative.feasible and negative.max_bound_violation == pytest.approx(u.max() - u.min())
    nan = verify(asm, np.full_like(u, np.nan), b)
    assert not nan.feasible and "wrench residual nan" in nan.failures()[0]
    crossed, _, _ = _v_pair(np.radians([-30, 0, 60]))  # bowl down: the axes converge below and the capsules cross
    bad = verify(crossed, u, b)
    assert bad.min_capsule_distance < 2 * P.r and not bad.feasible and "capsule axes" in bad.failures()[-1]


def test_clearance_is_verified_without_tolerance():
    # Two modules leaning toward each other (a bowl-down V): find the lean at which the capsule axes are exactly
    # 2r apart, then step 1e-7 rad either side.
    def asm(t):
        return Assembly(Topology.from_code("oS"), P, np.array([-t, 0.0, 2 * t]))

    def gap(t):
        a = asm(t)
        return kin.pairwise_capsule_distances(a.module_positions, a.module_rotations, P)[0, 1] - 2 * P.r

    touch = brentq(gap, 0.0, 0.3, xtol=1e-14)
    for t, feasible in ((touch - 1e-7, True), (touch + 1e-7, False)):
        ver = verify(asm(t), np.zeros((1, 8)), np.zeros((1, 6)))
        assert abs(ver.min_capsule_distance - 2 * P.r) < 1e-6
        assert ver.feasible is feasible is (ver.min_capsule_distance >= 2 * P.r)


NEAR_PARALLEL = Assembly(Topology.from_code("o(SEEN)E"), P, np.array([
    1.2326523845862185, -1.3531212941068607, -0.34234500107211985, -0.9763131989764735, -0.7851066940135184,
    -0.21862349767949854, 0.1891431049107104]))
"""Six modules built for the purpose (issue 23): modules 1 and 2 hang 7.86e-7 rad from parallel, converging
toward their far ends 1.16e-7 m inside 2 r; every other pair is at least 0.1996 m apart. The segment distance
before issue 23 took them as parallel from the near end and found 2 r + 3.1e-7 m: the assembly passed."""


def test_the_near_parallel_six_module_assembly_is_refused():
    ends = kin.capsule_endpoints(NEAR_PARALLEL.module_positions, NEAR_PARALLEL.module_rotations, P)
    z1, z2 = NEAR_PARALLEL.module_rotations[1][:, 2], NEAR_PARALLEL.module_rotations[2][:, 2]
    assert np.linalg.norm(np.cross(z1, z2)) == pytest.approx(7.86e-7, rel=1e-3)
    exact = exact_segment_distance(*ends[1], *ends[2])
    assert Decimal(2 * P.r) - exact == pytest.approx(Decimal("1.16e-7"), rel=Decimal("1e-3"))
    ver = verify(NEAR_PARALLEL, *NO_WRENCH)
    assert abs(Decimal(ver.min_capsule_distance) - exact) <= Decimal("1e-15")
    assert not ver.feasible and ver.failures() == ["capsule axes 0.189999884 m apart, under 2 r = 0.19 m"]
    others = kin.pairwise_capsule_distances(NEAR_PARALLEL.module_positions, NEAR_PARALLEL.module_rotations, P)
    others[1, 2] = others[2, 1] = np.inf
    assert others.min() > 0.199


def test_one_angle_tolerance_with_a_tenfold_margin_over_the_solver():
    assert SOLVER_BOUND_RELAXATION == ANGLE_TOLERANCE / 10
    u, b = np.zeros((1, 8)), np.zeros((1, 6))

    def at(alpha0):
        return verify(Assembly(Topology.from_code("oE"), P, np.array([alpha0, 0.0, 0.0])), u, b)

    # Where the solver may leave a design (oSWS sat 9.98e-10 rad past +90 deg), it passes by ten times that.
    assert at(np.pi / 2 + SOLVER_BOUND_RELAXATION).feasible
    past = at(np.pi / 2 + 2 * ANGLE_TOLERANCE)
    assert not past.feasible and past.max_angle_violation == pytest.approx(2 * ANGLE_TOLERANCE, rel=1e-7)
    assert past.failures() == [f"an angle {past.max_angle_violation:.3g} rad past +-90 deg"]


def test_input_cost_by_hand():
    u = np.array([[1.0, 2.0], [3.0, 4.0]])
    assert input_cost(u, np.array([0.5, 2.0])) == 0.5 * 5 + 2.0 * 25
