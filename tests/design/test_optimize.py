from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog

from groundstation.assembly import kinematics as kin
from groundstation.assembly.assembly_file import load_assembly, save_assembly
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.design.optimize import SolverOptions, least_bound, optimize, with_input_bound
from groundstation.design.task import load_task
from tests.recheck import wrenches_from_rotors

ROOT = Path(__file__).resolve().parents[2]
P = ModuleParams()


def toy_wrenches():
    return load_task(ROOT / "configs/tasks/toy_push_y.toml").wrenches_for(2, P)


def scan_symmetric_v(wrenches):
    """Independent of the solver: minimum-norm cost of the symmetric V family over its tilt, 0.1 deg steps over
    0-60 deg, then 0.01 deg steps within 0.1 deg of the best (the cost is smooth in the tilt; 6000 fine steps took
    22 s of the suite)."""
    coarse = _scan_tilts(wrenches, np.arange(0.0, 60.0, 0.1))
    return _scan_tilts(wrenches, np.arange(coarse[1] - 0.1, coarse[1] + 0.1 + 1e-9, 0.01))


def _scan_tilts(wrenches, tilts_deg):
    best = (np.inf, None)
    for tilt in np.radians(tilts_deg):
        pos, rot = kin.module_frames(Topology.from_code("oS"), np.array([tilt, 0.0, -2 * tilt]), P.l_c)
        a = kin.allocation_matrix(pos, rot, P)
        u = wrenches @ np.linalg.pinv(a).T
        if u.min() < 0 or u.max() > P.u_max or not np.allclose(u @ a.T, wrenches, atol=1e-6):
            continue
        cost = float(np.sum(u * u))
        if cost < best[0]:
            best = (cost, np.degrees(tilt))
    return best


def test_toy_case_finds_the_symmetric_v():
    b, w = toy_wrenches()
    assert np.allclose(b[:, 2], 2 * 0.24 * 9.81) and b[0, 1] == 0.36 and b[1, 1] == -0.36 and b[2, 1] == 0
    scan_cost, scan_tilt = scan_symmetric_v(b)
    assert scan_tilt == pytest.approx(22.5, abs=0.1)
    for code in ("oS", "oE"):  # the same assembly in both headings: the body yaw takes care of it
        d = optimize(Topology.from_code(code), P, b, w)
        assert d.feasible and d.status == "Solve_Succeeded"
        root_tilt = np.degrees(np.max(np.abs(d.alpha[:2])))
        assert root_tilt == pytest.approx(scan_tilt, abs=0.1)
        assert abs(np.degrees(d.alpha[2])) == pytest.approx(2 * scan_tilt, abs=0.2)
        assert d.cost == pytest.approx(scan_cost, rel=1e-4)


def test_saved_design_rechecked_from_poses(tmp_path):
    b, w = toy_wrenches()
    d = optimize(Topology.from_code("oS"), P, b, w)
    path = save_assembly(tmp_path / "toy.json", d.record("toy"))
    _, rec = load_assembly(path)
    # Recompute wrenches and clearance from the saved rotor list and poses, without package geometry.
    u = np.array(rec["u"])
    wrench = wrenches_from_rotors(rec, P.c_f, P.c_m)
    np.testing.assert_allclose(wrench, rec["wrenches"], atol=1e-6)
    assert u.min() >= 0 and u.max() <= P.u_max
    mods = rec["modules"]
    mu = np.linspace(P.capsule_a, P.capsule_b, 600)
    axis = [np.array(m["position"]) - mu[:, None] * np.array(m["rotation"])[:, 2] for m in mods]
    clearance = np.min(np.linalg.norm(axis[0][:, None] - axis[1][None], axis=2))
    assert clearance >= 2 * P.r - 1e-6
    assert rec["verification"]["feasible"] and rec["feasible"]


def test_infeasible_task_is_a_result():
    # One module cannot push both ways sideways while hovering.
    b = np.array([[1.0, 0, 2.4, 0, 0, 0], [-1.0, 0, 2.4, 0, 0, 0]])
    d = optimize(Topology.single(), P, b, opts=SolverOptions(rim_tilts_deg=(0.0,)))
    assert not d.feasible
    assert d.verification.max_wrench_residual > 0.1


def test_designs_keep_the_clearance_margin():
    b, w = toy_wrenches()
    d = optimize(Topology.from_code("oS"), P, b, w)
    assert d.verification.min_capsule_distance >= 2 * P.r
    assert d.verification.residual_tolerance == pytest.approx(1e-6 * np.max(np.abs(b)))


def test_multi_start_stops_on_evidence_and_within_budget():
    b, w = toy_wrenches()
    d = optimize(Topology.from_code("oS"), P, b, w, SolverOptions(min_starts=2, max_starts=6))
    # The toy case has one optimum: two starts agree and the search stops there.
    assert d.stop_reason == "confirmed" and len(d.starts) == 2 and d.best_hits == 2 and len(d.optima) == 1
    capped = optimize(Topology.from_code("oS"), P, b, w, SolverOptions(min_starts=3, max_starts=3))
    assert len(capped.starts) == 3 and capped.best_hits == 3
    assert capped.cost == pytest.approx(d.cost, rel=1e-6)
    assert [s.start for s in capped.starts] == ["fold 20 deg, yaw +0 deg", "fold 20 deg, yaw +180 deg",
                                                "fold 20 deg, yaw +90 deg"]


def test_start_statistics_in_the_record():
    b, w = toy_wrenches()
    d = optimize(Topology.from_code("oS"), P, b, w, SolverOptions(min_starts=6, max_starts=6))
    rec = d.record()["solver"]
    assert rec["stop_reason"] == "confirmed" and len(rec["starts"]) == 6 and rec["best_hits"] == 6
    # Boender-Rinnooy Kan: one optimum from six successful starts, w (N - 1) / (N - w - 2) - w = 5/3 - 1.
    assert rec["expected_unseen_optima"] == pytest.approx(5 / 3 - 1)
    assert rec["spread"] is None and rec["optima"] == [pytest.approx(d.cost)]


def least_max_input_of_symmetric_v(wrenches):
    """Independent of the solver: the least largest input that meets every wrench over the symmetric V family,
    an LP per tilt (minimise t subject to A u_k = b_k, 0 <= u_k <= t), 0.05 deg steps around the optimum."""
    k = len(wrenches)
    best = np.inf
    for tilt in np.radians(np.arange(25.0, 40.0, 0.05)):
        pos, rot = kin.module_frames(Topology.from_code("oS"), np.array([tilt, 0.0, -2 * tilt]), P.l_c)
        a = kin.allocation_matrix(pos, rot, P)
        m = a.shape[1]
        # Variables: u_1 .. u_k (m each), then t; inputs in units of u_max keep HiGHS's tolerances meaningful.
        a_eq = np.hstack([np.kron(np.eye(k), a * P.u_max), np.zeros((6 * k, 1))])
        a_ub = np.hstack([np.eye(k * m), -np.ones((k * m, 1))])
        res = linprog(np.r_[np.zeros(k * m), 1.0], A_ub=a_ub, b_ub=np.zeros(k * m), A_eq=a_eq,
                      b_eq=wrenches.ravel(), bounds=(0, None), method="highs")
        if res.status == 0:
            best = min(best, res.x[-1] * P.u_max)
    return best


def test_least_bound_of_the_toy_v_matches_an_lp_scan():
    b, w = toy_wrenches()
    d = least_bound(Topology.from_code("oS"), P, b, w)
    assert d.feasible and d.objective == "bound" and d.certificate is None
    assert d.params.u_max == pytest.approx(least_max_input_of_symmetric_v(b), rel=1e-5)
    # Verified at its own bound, which is its largest input; everything but the bound is the module's.
    assert d.params.u_max == d.u.max() and d.params == with_input_bound(P, d.u.max())
    assert d.verification.feasible and d.verification.max_bound_violation == 0.0
    assert d.verification.min_capsule_distance >= 2 * P.r
    assert d.record()["module_params"]["u_max"] == d.params.u_max


def test_least_bound_never_for_a_force_outside_the_thrust_axes_span():
    """One module pushes along its axis only: a sideways push while hovering needs two directions, at any bound.
    A thrust-capacity shortfall at the nominal bound is no such proof: the least bound is then above it."""
    b = np.array([[1.0, 0, 2.4, 0, 0, 0], [0.0, 0, 2.4, 0, 0, 0]])
    never = least_bound(Topology.single(), P, b)
    assert not never.feasible and never.certificate.kind == "force-span" and never.starts == ()
    heavy = np.array([[0.0, 0.0, 1.5 * 4 * P.c_f * P.u_max, 0, 0, 0]])  # 1.5 times one module's full thrust
    assert optimize(Topology.single(), P, heavy).certificate.kind == "thrust-capacity"
    d = least_bound(Topology.single(), P, heavy)
    assert d.feasible and d.params.u_max == pytest.approx(1.5 * P.u_max, rel=1e-6)
