"""Failsafes of the flight state machine, injected through the pose source on a simulated backend."""

from pathlib import Path

import numpy as np
import pytest

from groundstation.assembly.assembly_file import load_assembly
from groundstation.control.state import RigidState
from groundstation.control.trajectory import FlightPlan, Hover, euler_zyx
from groundstation.runtime.flight import FailsafePolicy, Flight, PhysicsPoseSource
from groundstation.runtime.loop import SimClock
from sim.pybullet_backend import PyBulletBackend

ROOT = Path(__file__).resolve().parents[2]


class Tampered(PhysicsPoseSource):
    """Physics pose, replaced by ``fault(state)`` from ``t_fault`` on."""

    def __init__(self, backend, t_fault, fault):
        super().__init__(backend)
        self._t_fault, self._fault = t_fault, fault

    def state(self):
        s = super().state()
        return self._fault(s) if self._backend.time >= self._t_fault else s


@pytest.mark.parametrize("fault, reason", [
    (lambda s: RigidState(s.position + [4.0, 0, 0], s.velocity, s.rotation, s.omega), "geofence"),
    (lambda s: RigidState(s.position, s.velocity, euler_zyx(np.radians(80), 0, 0), s.omega), "tilt"),
    (lambda s: RigidState(s.position * np.nan, s.velocity, s.rotation, s.omega), "non-finite"),
])
def test_failsafe_stops_motors_within_one_period(fault, reason):
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    with PyBulletBackend(asm) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 4.0))
        flight = Flight(asm, plan, be, Tampered(be, 3.0, fault), policy=FailsafePolicy())
        flight.run(SimClock(be), 250.0)
        assert flight.phase == "emergency" and reason in flight.reason
        t_stop = [t for t, _, text in flight.events if "emergency" in text][0]
        assert 3.0 <= t_stop <= 3.0 + 1 / 250 + 1e-9  # detected in the first period after the fault
        assert be.telemetry().motors.max() == 0.0  # motors commanded off
        assert flight.metrics.t_last < t_stop  # no command computed after the stop


def test_stale_mocap_with_stop_policy():
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")

    class Stale(PhysicsPoseSource):
        def age(self):
            return 1.0 if self._backend.time >= 2.0 else 0.0

    with PyBulletBackend(asm) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 4.0))
        flight = Flight(asm, plan, be, Stale(be), policy=FailsafePolicy(on_mocap_stale="stop"))
        flight.run(SimClock(be), 250.0)
    assert flight.phase == "emergency" and "mocap stale" in flight.reason


class ModuleStops(PyBulletBackend):
    """Module ``k``'s firmware stops flying it at ``t_fault`` (disarmed by its supervisor): its rotors get nothing
    and the backend names it in ``module_faults``, as the Crazyflie backend does from the module's state."""

    def __init__(self, asm, k, t_fault):
        super().__init__(asm)
        self._k, self._t_fault = k, t_fault

    def _stopped(self):
        return self.time >= self._t_fault

    def send(self, u):
        u = np.array(u, dtype=float)
        if self._stopped():
            u[4 * self._k:4 * self._k + 4] = 0.0
        super().send(u)

    def isolate(self, modules):
        return list(modules) == [self._k]  # its rotors get nothing from the fault on (send)

    def telemetry(self):
        tel = super().telemetry()
        faults = tuple("disarmed by its supervisor" if i == self._k and self._stopped() else ""
                       for i in range(self._asm_n))
        return type(tel)(**{**tel.__dict__, "module_faults": faults})


@pytest.mark.parametrize("assembly, k, phase, reason", [
    ("toy_v2.json", 1, "emergency", "module 1 disarmed by its supervisor: the other modules cannot hold the assembly"),
    ("random10_seed0_n30.json", 7, "done", "module 7 disarmed by its supervisor: landing on the other modules"),
])
def test_a_module_fault_lands_on_the_rest_or_stops(assembly, k, phase, reason):
    asm, _ = load_assembly(ROOT / "configs/assemblies" / assembly)
    with ModuleStops(asm, k, 3.0) as be:
        be._asm_n = asm.n
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 4.0))
        flight = Flight(asm, plan, be, PhysicsPoseSource(be))
        tilts = []
        flight.before_period = lambda t: tilts.append(np.degrees(np.arccos(min(be.true_state().rotation[2, 2], 1.0))))
        flight.run(SimClock(be), 250.0)
        assert flight.phase == phase and flight.reason == reason
        if phase == "done":  # landed on the other 29 modules: upright, module 7 given nothing after the fault
            assert max(tilts) < 15.0
            assert np.all(flight.model.allocation[:, 4 * k:4 * k + 4] == 0.0)
