"""The state estimator: its cost per control period, and what it does to a flight (issue 21).

    python -m benchmarks.estimator [--periods 20000] [--repeats 7] [--flights] [--duration 16]

Part 1 (one core): the estimator's work in one period of a 250 Hz loop with 100 Hz mocap, for n = 2 and n = 60:
the filter (predict with the body rate, a measurement fused every 2.5 periods, the state read, the commanded force
of ``4n`` rotor inputs), the check of the n modules' gyros against each other (``GyroAgreement``), and both in one
loop as the flight runs them (``Flight._estimate``, the gyros' torque referee fed too: ``TorqueAgreement``), against
the controller's own step (``control`` + allocation) in the same process: medians over repeats, and the ratio of
both to the controller. Targets: 50 us at n = 2, 200 us at n = 60.

Part 2 (``--flights``): the toy figure-8 in lockstep (``fly_simulated``, 1 mm / 0.2 deg mocap noise, 5 ms latency,
100 Hz) for several ``accel_noise`` settings: position RMSE, attitude error p95 against the controller's target,
and the change of the rotor commands from one period to the next in tracking (RMS over rotors and periods, and the
largest), fractions of u_max; with exact mocap for reference.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from functools import partial
from pathlib import Path

import numpy as np

from benchmarks._util import median, pin_one_core, print_table
from groundstation.control.allocation import allocate
from groundstation.control.geometric import Gains, control
from groundstation.control.model import ControlModel
from groundstation.control.phase import Phase
from groundstation.control.state import RigidState
from groundstation.control.trajectory import FlightPlan, euler_zyx, make_track
from groundstation.estimation.filter import EstimatorSettings, RigidBodyFilter
from groundstation.estimation.gyro_check import GyroAgreement
from groundstation.estimation.gyro_torque import TorqueAgreement
from groundstation.estimation.measurement import PoseMeasurement
from groundstation.runtime.flight import DISPUTE_FRESH_S, GYROS_DISPUTED_RAD
from groundstation.runtime.flight_config import read_assembly

ROOT = Path(__file__).resolve().parents[1]
ASSEMBLIES = {2: "toy_v2.json", 60: "random10_seed0_n60.json"}


def _period_costs(n: int, periods: int, repeats: int) -> tuple[float, float, float, float]:
    """Median per-period time of the filter, of the gyro check, of both as flown and of the controller + allocation,
    us."""
    asm = read_assembly(ROOT / "configs/assemblies" / ASSEMBLIES[n])
    model = ControlModel.from_assembly(asm)
    rng = np.random.default_rng(0)
    dt = 1 / 250
    gyros = rng.normal(0, 0.3, (periods, 3))
    hover = np.full(4 * n, model.u_max * 0.4)
    poses = [PoseMeasurement(k * dt - 0.007, np.array([0.0, 0.0, 1.0]) + rng.normal(0, 1e-3, 3),
                             euler_zyx(*rng.normal(0, 0.003, 3))) for k in range(periods)]
    plan = FlightPlan((0.0, 0.0, 0.1), make_track("figure8", 16.0, 1.0, 0.6, 8.0, 0.0))
    setpoints = [plan(3.0 + k * dt) for k in range(periods)]
    states = [RigidState(np.array([0.0, 0.0, 1.0]), np.zeros(3), euler_zyx(*rng.normal(0, 0.02, 3)), g)
              for g in gyros]
    module_gyros = gyros[:, None, :] + rng.normal(0, 0.01, (periods, n, 3))  # the modules' readings, in agreement
    ages = np.full(n, 0.004)  # each reading's age, as the hardware backends report them (all fresh)
    gains = Gains()
    filter_runs, gyro_runs, both_runs, ctrl_runs = [], [], [], []
    for _ in range(repeats):
        f = RigidBodyFilter(EstimatorSettings(gyro_delay=0.01), model.mass)
        t0 = time.perf_counter()
        for k in range(periods):
            f.predict(k * dt, gyros[k])
            if k % 5 in (0, 2):  # 100 Hz poses into a 250 Hz loop: two in five periods
                f.correct(poses[k])
            f.state()
            f.command(model.allocation[:3] @ hover)
        filter_runs.append((time.perf_counter() - t0) / periods * 1e6)
        agreement = GyroAgreement()
        t0 = time.perf_counter()
        for k in range(periods):
            agreement.rate(k * dt, module_gyros[k], gyros[k], None, ages, 0.004, 0.03)
        gyro_runs.append((time.perf_counter() - t0) / periods * 1e6)
        f, agreement = RigidBodyFilter(EstimatorSettings(gyro_delay=0.01), model.mass), GyroAgreement()
        torque = TorqueAgreement(model.inertia)
        t0 = time.perf_counter()
        for k in range(periods):
            now = k * dt
            rate, age = agreement.rate(now, module_gyros[k], gyros[k], partial(f.pose_rate, now), ages, 0.004, 0.03)
            f.predict(now, rate, age)
            torque.add(now, rate)
            if k % 5 in (0, 2):
                f.correct(poses[k])
            seen, off = f.attitude_seen
            if off > GYROS_DISPUTED_RAD and now - seen <= DISPUTE_FRESH_S:
                torque.against()
            f.state()
            wrench = model.allocation @ hover
            f.command(wrench[:3])
            torque.command(wrench[3:])
        both_runs.append((time.perf_counter() - t0) / periods * 1e6)
        t0 = time.perf_counter()
        for k in range(periods):
            allocate(control(states[k], setpoints[k], model, gains).wrench, model)
        ctrl_runs.append((time.perf_counter() - t0) / periods * 1e6)
    return median(filter_runs), median(gyro_runs), median(both_runs), median(ctrl_runs)


def _flight(settings: EstimatorSettings, noisy: bool, duration: float):
    from groundstation.runtime.closed_loop import fly_simulated
    from sim.pybullet_backend import PyBulletBackend, SimConfig

    asm = read_assembly(ROOT / "configs/assemblies/toy_v2.json")
    noise = dict(position_noise=1e-3, attitude_noise=math.radians(0.2), latency=5e-3) if noisy else {}
    with PyBulletBackend(asm, SimConfig(**noise)) as be:
        plan = FlightPlan(tuple(be.start_position), make_track("figure8", duration, 1.0, 0.6, 8.0, 0.0))
        rec = fly_simulated(asm, plan, be, estimator=settings)
    track = rec.phase == Phase.TRACK
    du = np.diff(rec.motors / asm.params.u_max, axis=0)[track[1:] & track[:-1]]
    m = rec.metrics
    return [m.pos_rmse_m * 100, m.orientation_error_p95_deg, float(np.sqrt(np.mean(du ** 2))),
            float(np.abs(du).max())]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--periods", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--flights", action="store_true", help="Also fly the accel_noise sweep (about a minute).")
    ap.add_argument("--duration", type=float, default=16.0, help="Tracking time of each flight, s.")
    a = ap.parse_args(argv)
    pin_one_core()
    rows = []
    for n, target in ((2, 50.0), (60, 200.0)):
        filt, gyro, both, ctrl = _period_costs(n, a.periods, a.repeats)
        rows.append([n, filt, gyro, both, target, ctrl, both / ctrl])
    print_table(f"estimator per 250 Hz period (100 Hz mocap), median of {a.repeats} x {a.periods} periods, one core",
                ["n", "filter (us)", "gyro check (us)", "both, as flown (us)", "target (us)",
                 "controller + allocation (us)", "ratio (both)"], rows)
    if a.flights:
        base = EstimatorSettings(position_noise=1e-3, attitude_noise=math.radians(0.2))
        rows = [["exact mocap, default", *_flight(EstimatorSettings(), False, a.duration)]]
        for q in (0.5, 0.1, 0.05, base.accel_noise):
            label = f"accel_noise {q:g}" + (" (default)" if q == base.accel_noise else "")
            rows.append([label, *_flight(dataclasses.replace(base, accel_noise=q), True, a.duration)])
        print_table(f"toy figure-8, {a.duration:g} s of tracking, 1 mm / 0.2 deg mocap at 100 Hz, 5 ms latency",
                    ["estimator", "position RMSE (cm)", "attitude error p95 (deg)",
                     "rotor change per period RMS (u_max)", "max (u_max)"], rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
