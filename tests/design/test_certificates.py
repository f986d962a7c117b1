import numpy as np
import pytest

from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.design.certificates import infeasibility_certificate, thrust_axis_dimension
from groundstation.design.optimize import optimize

P = ModuleParams()
HOVER = 4 * P.mass * 9.81


@pytest.mark.parametrize("code, dim", [("o", 1), ("oE", 2), ("oS", 2), ("oEEE", 2), ("oSS", 2), ("oSE", 3),
                                       ("oS(W)E", 3)])
def test_thrust_axis_dimension(code, dim):
    assert thrust_axis_dimension(Topology.from_code(code)) == dim


def test_planar_chain_cannot_make_forces_in_three_dimensions():
    b = np.array([[0.5, 0, 1, 0, 0, 0], [0, 0.5, 1, 0, 0, 0], [0, 0, 1, 0, 0, 0]]) * HOVER
    cert = infeasibility_certificate(Topology.from_code("oEEE"), P, b)
    assert cert.kind == "force-span" and "3 dimensions" in cert.reason
    # Forces in one vertical plane are within reach of the same chain: no certificate.
    assert infeasibility_certificate(Topology.from_code("oEEE"), P, b[[1, 2]]) is None
    assert infeasibility_certificate(Topology.from_code("oSEE"), P, b) is None


def test_single_module_and_the_thrust_capacity():
    one = Topology.single()
    assert infeasibility_certificate(one, P, [[0, 0, 2.0, 0, 0, 0], [0, 0, 4.0, 0, 0, 0]]) is None
    assert infeasibility_certificate(one, P, [[0.1, 0, 2.0, 0, 0, 0], [0, 0, 4.0, 0, 0, 0]]).kind == "force-span"
    capacity = 4 * P.c_f * P.u_max
    assert infeasibility_certificate(one, P, [[0, 0, capacity * 0.999, 0, 0, 0]]) is None
    cert = infeasibility_certificate(one, P, [[0, 0, capacity * 1.001, 0, 0, 0]])
    assert cert.kind == "thrust-capacity" and f"{capacity:.4g} N" in cert.reason


def test_certified_topology_is_not_solved():
    b = np.array([[0.5, 0, 1, 0, 0, 0], [0, 0.5, 1, 0, 0, 0], [0, 0, 1, 0, 0, 0]]) * HOVER * 3 / 4
    d = optimize(Topology.from_code("oEE"), P, b)
    assert not d.feasible and d.status == "Infeasible_Certified" and d.starts == () and d.iterations == 0
    assert d.record()["certificate"]["kind"] == "force-span" and d.record()["cost"] is None
