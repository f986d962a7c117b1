"""Controller + allocation step time, and closed-loop simulation speed (issue: n = 60 within 100 us per step;
n = 60 at 240 Hz physics and 250 Hz control at >= 10x real time, one core).

    python -m benchmarks.control [--repeats 5]

Step times are medians over 2000 steps per run (64 random states near hover on a circle reference), then the
median over runs. The bounded (saturation-aware) allocation is shown for comparison: it runs a bounded
least-squares solve whenever a rotor saturates, which these perturbed states often make happen.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks._util import median, pin_one_core, print_table
from groundstation.assembly.assembly_file import load_assembly
from groundstation.control.allocation import allocate, allocate_bounded
from groundstation.control.geometric import Gains, control
from groundstation.control.model import ControlModel
from groundstation.control.state import RigidState
from groundstation.control.trajectory import Circle, FlightPlan, euler_zyx

ROOT = Path(__file__).resolve().parents[1]
ASSEMBLIES = {2: "configs/assemblies/toy_v2.json", 30: "configs/assemblies/random10_seed0_n30.json",
              60: "configs/assemblies/random10_seed0_n60.json"}


def step_times(model: ControlModel, alloc, steps: int = 2000) -> float:
    plan = FlightPlan((0, 0, 0.1), Circle((-0.5, 0, 1), 0.5, 8, 8))
    rng = np.random.default_rng(0)
    states = [RigidState(rng.normal(0, 0.1, 3) + [0, 0, 1], rng.normal(0, 0.1, 3),
                         euler_zyx(*rng.normal(0, 0.05, 3)), rng.normal(0, 0.1, 3)) for _ in range(64)]
    sps = [plan(t) for t in np.linspace(5, 12, 64)]
    gains = Gains()
    times = np.empty(steps)
    for k in range(steps):
        t0 = time.perf_counter()
        out = control(states[k % 64], sps[k % 64], model, gains)
        alloc(out.wrench, model)
        times[k] = time.perf_counter() - t0
    return float(np.median(times))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    core = pin_one_core()
    rows, ok = [], True
    for n, path in ASSEMBLIES.items():
        asm, _ = load_assembly(ROOT / path)
        model = ControlModel.from_assembly(asm)
        clip = median([step_times(model, allocate) for _ in range(args.repeats)]) * 1e6
        bounded = median([step_times(model, allocate_bounded) for _ in range(args.repeats)]) * 1e6
        rows.append([n, model.actuation, clip, bounded])
        ok &= n != 60 or clip <= 100
    print_table(f"Controller + allocation step, median us (core {core}, {args.repeats} runs)",
                ["n", "actuation", "clip (paper) us", "bounded LSQ us"], rows)

    from groundstation.runtime.closed_loop import fly_simulated
    from sim.pybullet_backend import PyBulletBackend

    rows = []
    for n, path in ASSEMBLIES.items():
        asm, _ = load_assembly(ROOT / path)
        factors = []
        for _ in range(max(1, args.repeats // 2)):
            with PyBulletBackend(asm) as be:
                plan = FlightPlan(tuple(be.start_position), Circle((-0.5, 0, 1), 0.5, 8.0, 8.0))
                factors.append(fly_simulated(asm, plan, be).metrics.realtime_factor)
        rows.append([n, median(factors), min(factors)])
        ok &= n != 60 or median(factors) >= 10
    print_table("Closed loop in PyBullet, 240 Hz physics, 250 Hz control, lockstep: real-time factor",
                ["n", "median x real time", "worst"], rows)
    print("targets (n = 60: step <= 100 us, >= 10x real time):", "met" if ok else "MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
