"""Failsafes of the flight state machine, injected through the pose source on a simulated backend."""

from pathlib import Path

import numpy as np
import pytest

from groundstation.assembly.assembly_file import load_assembly
from groundstation.control.trajectory import Attitude, Figure8, FlightPlan, Hover
from groundstation.estimation.measurement import PoseMeasurement
from groundstation.runtime.closed_loop import MOCAP_WAIT_S
from groundstation.runtime.flight import FailsafePolicy, Flight, MocapIntegrity, PhysicsPoseSource
from groundstation.runtime.loop import SimClock
from sim.pybullet_backend import PyBulletBackend

ROOT = Path(__file__).resolve().parents[2]


def ready(be):
    """The simulated mocap's first poses delivered, as ``fly_simulated`` (and ``fly``'s preflight) waits for them."""
    be.advance_to(be.time + MOCAP_WAIT_S)
    return be


class Tampered(PhysicsPoseSource):
    """The simulated mocap's poses, replaced by ``fault(pose)`` from ``t_fault`` on."""

    def __init__(self, backend, t_fault, fault):
        super().__init__(backend)
        self._t_fault, self._fault = t_fault, fault

    def measurements(self):
        out = super().measurements()
        return [self._fault(m) for m in out] if self._backend.time >= self._t_fault else out


def _tilt_deg(rotation) -> float:
    return float(np.degrees(np.arccos(min(rotation[2, 2], 1.0))))


@pytest.mark.parametrize("policy, hover, reason, crossed", [
    (FailsafePolicy(geofence_upper=(3.5, 3.5, 0.8)), Hover((0, 0, 1.0), 4.0), "left the geofence",
     lambda position, rotation: position[2] > 0.8),
    (FailsafePolicy(max_tilt_deg=3.0), Hover((0, 0, 1.0), 4.0, Attitude(roll=np.radians(-5.0))),
     "tilt beyond 3 deg", lambda position, rotation: _tilt_deg(rotation) > 3.0),
])
def test_failsafe_stops_motors_within_one_period(policy, hover, reason, crossed):
    """The estimate crosses the bound on the way to the hover: no command is computed from a state beyond it."""
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    with PyBulletBackend(asm) as be:
        plan = FlightPlan(tuple(be.start_position), hover)
        flight = Flight(asm, plan, ready(be), PhysicsPoseSource(be), policy=policy, record=True)
        flight.run(SimClock(be), 250.0)
        assert flight.phase == "emergency" and reason in flight.reason
        t_stop = [t for t, _, text in flight.events if "emergency" in text][0]
        r = flight.recording
        assert r.t and not any(crossed(p, rot) for p, rot in zip(r.position, r.rotation, strict=True))
        # airborne; stopped in the period after the last command (lockstep periods start on 1/240 s physics steps)
        assert 1.0 < t_stop <= r.t[-1] + 1 / 240 + 1e-9
        assert be.telemetry().motors.max() == 0.0  # motors commanded off


def test_non_finite_poses_never_reach_the_controller():
    """NaN positions from the mocap from 3 s on: rejected by the estimator (counted, named), a fault after 50 ms,
    and the flight lands on the estimate; every command stays finite."""
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    nan = lambda m: PoseMeasurement(m.t, m.position * np.nan, m.rotation)  # noqa: E731
    with PyBulletBackend(asm) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 4.0))
        flight = Flight(asm, plan, ready(be), Tampered(be, 3.0, nan), record=True)
        flight.run(SimClock(be), 250.0)
    assert flight.phase == "done" and flight.reason.startswith("mocap fault: every pose rejected for ")
    assert "(last: not finite)" in flight.reason
    assert np.all(np.isfinite(np.array(flight.recording.motors)))
    assert flight.estimator.rejected >= 5 and flight.integrity().why == "not finite"


def test_a_blind_landing_on_disowned_poses_sets_an_unsteady_disturbance_aside():
    """Poses that wobble 3 cm at 1 Hz (the estimator's disturbance absorbing them, as it absorbed mocap 60 ms late
    in hostile campaign 28), then 0.5 m off: every pose rejected, a blind landing. Flown on the disturbance the
    wobble left (-0.48 m/s^2 down), the estimate sank while the body climbed, and the motors stopped 1.5 m up,
    "landed blind"; set aside (named), the landing ends on the ground."""
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")

    def wobbled(m):
        dz = 0.03 * np.sin(2 * np.pi * m.t) if m.t < 5.5 else 0.5
        return PoseMeasurement(m.t, m.position + [0.0, 0.0, dz], m.rotation)

    with PyBulletBackend(asm) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 6.0))
        flight = Flight(asm, plan, ready(be), Tampered(be, 4.0, wobbled), record=True)
        flight.run(SimClock(be), 250.0)
        above = be.true_state().position[2] - be.start_position[2]
    assert flight.phase == "done" and flight.reason.startswith("mocap fault: every pose rejected")
    assert any("not on the disturbance learnt" in text and "the poses disowned, the disturbance unsteady" in text
               for *_, text in flight.events), flight.events
    assert above < 0.15, above  # motors off at most a few cm up (1.5 m before)


def test_stale_mocap_with_stop_policy():
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")

    class Stale(PhysicsPoseSource):
        def measurements(self):
            out = super().measurements()
            return out if self._backend.time < 2.0 else []

    with PyBulletBackend(asm) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 4.0))
        flight = Flight(asm, plan, ready(be), Stale(be), policy=FailsafePolicy(on_mocap_stale="stop"))
        flight.run(SimClock(be), 250.0)
    assert flight.phase == "emergency" and flight.reason.startswith("mocap stale (25")


def test_a_stale_stream_names_only_the_rejections_in_flight():
    """45 samples rejected before arming ("sequence jumps 83 ahead", the preflight's), then the stream stops in
    flight: the reason says it went stale, not that those rejections caused it (campaign 25 read them so); rejections
    in flight are named with their count."""
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")

    class Stops(Silenced):  # from 2 s, with the counts the ground station's subscriber would give
        def __init__(self, backend, rejected_in_flight):
            super().__init__(backend, 2.0)
            self._in_flight = rejected_in_flight

        def integrity(self):
            rejected = 45 + (self._in_flight if self._backend.time >= 2.0 else 0)
            why = "sequence jumps 83 ahead" if self._backend.time < 2.0 else "moves 0.40 m in 4 ms"
            return MocapIntegrity(rejected=rejected, why=why)

    for in_flight, said in ((0, "mocap stale (25"), (7, "; 7 samples rejected in flight, last: moves 0.40 m in 4 ms")):
        with PyBulletBackend(asm) as be:
            plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 4.0))
            flight = Flight(asm, plan, ready(be), Stops(be, in_flight), policy=FailsafePolicy(on_mocap_stale="stop"))
            flight.run(SimClock(be), 250.0)
        assert flight.phase == "emergency" and said in flight.reason and "83 ahead" not in flight.reason, flight.reason


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
        flight = Flight(asm, plan, ready(be), PhysicsPoseSource(be))
        tilts = []
        flight.before_period = lambda t: tilts.append(np.degrees(np.arccos(min(be.true_state().rotation[2, 2], 1.0))))
        flight.run(SimClock(be), 250.0)
        assert flight.phase == phase and flight.reason == reason
        if phase == "done":  # landed on the other 29 modules: upright, module 7 given nothing after the fault
            assert max(tilts) < 15.0
            assert np.all(flight.model.allocation[:, 4 * k:4 * k + 4] == 0.0)


def test_a_module_fault_in_a_landing_goes_on_from_the_landing():
    """An operator landing, then 1 s into it a module of a 30-module assembly stops: the landing goes on, on the
    other modules, from where its reference was (it used to start again from the flight plan, 0.5 m up at the
    hover point)."""
    asm, _ = load_assembly(ROOT / "configs/assemblies/random10_seed0_n30.json")
    with ModuleStops(asm, 7, 0.0) as be:
        be._asm_n = asm.n
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 4.0))
        t_land = plan.phases[2][1] + 1.0  # hovering
        be._t_fault = t_land + 1.0
        flight = Flight(asm, plan, ready(be), PhysicsPoseSource(be), record=True)
        flight.before_period = lambda t: flight.requests.land.set() if t >= t_land else None
        flight.run(SimClock(be), 250.0)
    assert flight.phase == "done" and flight.reason == "operator land"
    assert [text for _, _, text in flight.events if "module 7" in text] == [
        "module 7 disarmed by its supervisor: landing on the other modules: the landing goes on"]
    ref = np.array(flight.recording.position_ref)
    steps = np.linalg.norm(np.diff(ref, axis=0), axis=1)
    assert steps.max() < 0.01, steps.max()  # per 4 ms period: no jump when the fault came
    assert ref[-1][2] < plan.ground[2]  # and it went on down to the ground


class Silenced(PhysicsPoseSource):
    """The simulated mocap, silent from ``t_quiet`` on (a tracker that lost the body)."""

    def __init__(self, backend, t_quiet):
        super().__init__(backend)
        self._t_quiet = t_quiet

    def measurements(self):
        out = super().measurements()
        return [] if self._backend.time >= self._t_quiet else out


@pytest.mark.parametrize("kind, at", [("operator", "speed"), ("operator", "acceleration"), ("mocap lost", "speed")])
def test_a_landing_begun_in_motion_goes_on_from_it(kind, at):
    """A landing begun at the figure-8's fastest point (0.67 m/s) or where it accelerates most (0.79 m/s^2): the
    operator's, or the blind one when mocap goes quiet. The landing reference goes on from the reference's
    motion and brakes, so the V's attitude target moves smoothly and it tilts no more than it did tracking (a
    landing reference starting at rest asked for a stop in one period: on the Crazyflie link of the fault table
    the pitch target stepped by 16 deg and the rotors saturated)."""
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    with PyBulletBackend(asm) as be:
        plan = FlightPlan(tuple(be.start_position), Figure8(0.6, 8.0, 1.0, 16.0))
        _, start, end = plan.phases[2]
        size, t_land = max((float(np.linalg.norm(getattr(plan(t), "velocity" if at == "speed" else at))), t)
                           for t in np.arange(start + 4.0, end, 0.01))
        source = Silenced(be, t_land) if kind == "mocap lost" else PhysicsPoseSource(be)
        flight = Flight(asm, plan, ready(be), source, record=True)
        if kind == "operator":
            flight.before_period = lambda t: flight.requests.land.set() if t >= t_land else None
        flight.run(SimClock(be), 250.0)
    assert size > (0.6 if at == "speed" else 0.75) and flight.phase == "done"
    r = flight.recording
    t = np.array(r.t)
    k = int(np.argmax(np.array(r.phase) == "landing"))
    assert 0.0 <= t[k] - t_land < 0.3, (t[k], flight.reason)
    target_step = [np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1)))
                   for a, b in zip(r.rotation_desired[k - 1:k + 75], r.rotation_desired[k:k + 76], strict=True)]
    tilt = [_tilt_deg(rot) for rot in r.rotation]
    assert max(target_step) < 0.5, max(target_step)  # per 4 ms period, over the first 0.3 s of the landing
    assert max(tilt[k:]) < max(tilt[:k]) + 1.0, (max(tilt[k:]), max(tilt[:k]))


def test_a_request_while_arming_disarms_before_take_off():
    """Ctrl-C during an arming that takes a second (PX4 modules): the modules armed meanwhile are disarmed, never
    emergency-stopped (on PX4 a termination that latches until a reboot), and nothing spins (hostile campaign 29:
    two SIGINTs while arming ended in the emergency stop at t = 0)."""
    from groundstation.runtime.flight import Requests

    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    requests = Requests(source="SIGINT")

    class SlowToArm(PyBulletBackend):
        stops = 0

        def arm(self):
            super().arm()
            requests.land.set()  # the operator's signal, while the modules confirm

        def emergency_stop(self):
            self.stops += 1
            super().emergency_stop()

    with SlowToArm(asm) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 2.0))
        flight = Flight(asm, plan, ready(be), PhysicsPoseSource(be), requests=requests)
        flight.run(SimClock(be), 250.0)
        assert flight.phase == "aborted" and flight.reason == ("stopped by the operator while arming (SIGINT): "
                                                               "disarmed before take-off")
        assert be.stops == 0 and not be.armed and be.telemetry().motors.max() == 0.0


class SlowLinks(PyBulletBackend):
    """Both modules' round trips as ``rtt_at(t)`` says (``t`` since ``t0``, s; the round trip s, NaN for unmeasured),
    as a hardware backend reports them."""

    def __init__(self, asm, rtt_at):
        super().__init__(asm)
        self._rtt_at, self.t0 = rtt_at, 0.0

    def telemetry(self):
        tel = super().telemetry()
        return type(tel)(**{**tel.__dict__, "link_latency_s": np.full(2, self._rtt_at(self.time - self.t0))})


def test_a_bandwidth_cut_for_a_slow_link_holds_for_the_rest_of_the_flight(monkeypatch):
    """Round trips of 20 ms, then 16 ms, then unmeasured, then 30 ms, then back to 5 ms: the gains are cut for the
    worst seen so far at every period from the first slow one on (a relay's forged answers read 16-18 ms against
    its 20, and recut at each period the landing swung 25 deg at 4 Hz; an unmeasured round trip is not a fast
    one), each deeper cut said."""
    import groundstation.runtime.flight as flight_module
    from groundstation.control.geometric import Gains, delay_limited

    steps = [(2.0, 0.020), (2.3, 0.016), (2.5, float("nan")), (2.7, 0.030), (2.9, 0.005)]

    def rtt_at(t):
        return next((rtt for start, rtt in reversed(steps) if t >= start), 0.003)

    used = []
    real_control = flight_module.control
    monkeypatch.setattr(flight_module, "control",
                        lambda state, sp, model, gains: used.append(gains) or real_control(state, sp, model, gains))
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    policy = FailsafePolicy(on_link_degraded="land")
    with SlowLinks(asm, rtt_at) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 2.0))
        flight = Flight(asm, plan, ready(be), PhysicsPoseSource(be), policy=policy, record=True)
        be.t0 = be.time  # the flight's t = 0
        flight.run(SimClock(be), 250.0)
    t = np.array(flight.recording.t)
    hz = np.array([g.attitude_hz for g in used[-len(t):]])
    period, bound = 1 / 250, policy.max_link_latency_s + 1 / 250
    full = Gains().attitude_hz
    # The backend's telemetry is read at the period's start, before the physics steps to it: a period late.
    late = 1.5 / 250
    assert np.all(hz[t < steps[0][0]] == full)
    expect_20 = delay_limited(Gains(), 0.020 + period, bound).attitude_hz
    expect_30 = delay_limited(Gains(), 0.030 + period, bound).attitude_hz
    assert np.allclose(hz[(t > steps[0][0] + late) & (t < steps[3][0])], expect_20)  # 16 ms and NaN: held
    assert np.allclose(hz[t > steps[3][0] + late], expect_30)  # 30 ms: cut further, then held at 5 ms
    assert flight.phase == "done" and flight.reason.startswith("link degraded")
    said = [text for _, _, text in flight.events if "bandwidths cut" in text]  # each cut said: 20 ms, then 30
    assert len(said) == 2 and "round trip 20 ms" in said[0] and "round trip 30 ms" in said[1], said


def test_a_link_too_slow_to_land_on_stops_the_motors_after_a_re_route():
    """A re-route's note lands the flight; the round trip then passing the stop bound (60 ms > 50) for 0.1 s stops
    the motors all the same (the note stood for the link for the rest of the flight: the bound was never read
    again), and the re-route is said once, in the landing. A burst of 60 ms shorter than 0.1 s (a stall's late
    answers) only lands it."""
    class Rerouted(SlowLinks):
        def telemetry(self):
            tel = super().telemetry()
            note = "module 1's messages came on module 0's link" if self.time - self.t0 >= 2.0 else ""
            return type(tel)(**{**tel.__dict__, "rerouted": note})

    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    with Rerouted(asm, lambda t: 0.060 if t >= 2.3 else 0.003) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 2.0))
        flight = Flight(asm, plan, ready(be), PhysicsPoseSource(be), record=True)
        be.t0 = be.time
        flight.run(SimClock(be), 250.0)
    assert flight.phase == "emergency" and "round trip 60 ms > 50 ms for 100 ms" in flight.reason, flight.reason
    said = [text for _, _, text in flight.events if "came on" in text]
    assert len(said) == 1 and said[0].endswith("-> landing: link degraded: module 1's messages came on module 0's "
                                               "link"), said
    assert abs(flight.recording.t[-1] - 2.4) < 0.02  # stopped 0.1 s into the round trip, within a few periods


def test_a_burst_of_late_answers_lands_without_a_stop():
    """A round trip of 60 ms for 60 ms (an 80 ms stall's late answers): the flight lands on it, upright, never
    stopping (it stopped the motors 0.93-0.95 m up: hostile campaign 34), and the gains are held cut for twice the
    bound at most (a quarter of each bandwidth; held at 60 ms, a tenth for the rest of the flight)."""
    import groundstation.runtime.flight as flight_module
    from groundstation.control.geometric import Gains, delay_limited

    used = []
    real_control = flight_module.control
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    with SlowLinks(asm, lambda t: 0.060 if 2.3 <= t < 2.36 else 0.003) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1.0), 2.0))
        flight = Flight(asm, plan, ready(be), PhysicsPoseSource(be), record=True)
        be.t0 = be.time
        flight_module.control = lambda state, sp, model, gains: used.append(gains) or real_control(state, sp, model,
                                                                                                   gains)
        try:
            flight.run(SimClock(be), 250.0)
        finally:
            flight_module.control = real_control
    assert flight.phase == "done" and "round trip 60 ms > 14 ms" in flight.reason, flight.reason
    bound = FailsafePolicy().max_link_latency_s + 1 / 250
    assert used[-1].attitude_hz == pytest.approx(delay_limited(Gains(), 2 * bound, bound).attitude_hz)
    assert used[-1].attitude_hz == pytest.approx(used[0].attitude_hz / 4)
    assert max(_tilt_deg(r) for r in flight.recording.rotation) < 10.0
