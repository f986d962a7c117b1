import numpy as np

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.control.allocation import allocate, allocate_bounded
from groundstation.control.model import ControlModel

P = ModuleParams()
FULL = Assembly(Topology.from_code("oES"), P, np.radians([0, 10, -30, 40]))


def test_feasible_wrench_is_reproduced():
    model = ControlModel.from_assembly(FULL)
    u0 = P.u_max * np.random.default_rng(2).uniform(0.35, 0.45, 12)  # interior inputs: w is producible
    w = FULL.allocation @ u0
    u = allocate(w, model)
    assert u.min() > 0 and u.max() < P.u_max
    np.testing.assert_allclose(FULL.allocation @ u, w, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(allocate_bounded(w, model), u)


def test_bounded_allocation_beats_clipping_when_saturated():
    model = ControlModel.from_assembly(FULL)
    # Heavy lift plus a strong roll torque: the pseudo-inverse asks for negative and above-limit inputs.
    w = np.array([0.0, 0.0, 0.9 * 3 * 4 * P.c_f * P.u_max, 0.25, 0.0, 0.0])
    raw = model.pinv @ w
    assert raw.min() < 0 or raw.max() > P.u_max
    scale = model.wrench_scale
    err_clip = np.linalg.norm((FULL.allocation @ allocate(w, model) - w) / scale)
    u_b = allocate_bounded(w, model)
    err_bounded = np.linalg.norm((FULL.allocation @ u_b - w) / scale)
    assert u_b.min() >= 0 and u_b.max() <= P.u_max
    assert err_bounded < 0.75 * err_clip  # measured: 3.27 vs 6.25 (normalized units)
    # and the produced torque points the requested way much more closely
    def torque_angle(u):
        t = FULL.allocation[3:] @ u
        return np.degrees(np.arccos(t @ w[3:] / (np.linalg.norm(t) * np.linalg.norm(w[3:]))))
    assert torque_angle(u_b) < torque_angle(allocate(w, model))
