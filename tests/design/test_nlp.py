import casadi as ca
import numpy as np

from groundstation.assembly.verification import ANGLE_TOLERANCE, SOLVER_BOUND_RELAXATION
from groundstation.design.nlp import ipopt_options


def test_the_solver_leaves_a_bound_by_at_most_its_relaxation():
    """An angle pushed against +90 deg with the NLP's Ipopt options ends past the bound, as oSWS did (Ipopt
    relaxes bounds), but by no more than SOLVER_BOUND_RELAXATION: a tenth of what the verification accepts."""
    x = ca.SX.sym("x", 2)
    for pull in (1.0, 1e3, 1e6):
        solver = ca.nlpsol("bound", "ipopt", {"x": x, "f": -pull * x[0] + (x[1] - 0.3) ** 2},
                           ipopt_options(1e-8, 200))
        past = float(solver(x0=[0, 0], lbx=-np.pi / 2, ubx=np.pi / 2)["x"][0]) - np.pi / 2
        assert solver.stats()["return_status"] == "Solve_Succeeded"
        assert 0.5 * SOLVER_BOUND_RELAXATION < past <= SOLVER_BOUND_RELAXATION <= ANGLE_TOLERANCE / 10
