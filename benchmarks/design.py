"""Design benchmarks (paper §IV-C): the default command's time at n = 30 and 90, where the time goes, and what
the multi-start finds.

    python -m benchmarks.design [--sizes 30,90] [--seeds 0,1,2] [--topologies 3] [--skip-starts] [--scan]

Part 1, the default command: ``groundstation optimize configs/tasks/random10_seed<k>.toml --topology CODE --json``
run as users run it (its own process, default options), on the most compact sampled topologies (3 at n = 30,
1 at n = 90) against each wrench set: wall time of the command, the start statistics of its JSON record, and the
split of solver time between Ipopt itself (KKT factorizations), function and derivative evaluations, and
building solvers. Targets (issue 13): median <= 10 s at n = 30 and <= 60 s at n = 90.

Part 2, starts on the §IV-C example (n = 4, all 7 topologies): feasible starts, local optima, stop reason,
certificates; and how many designs the paper's naive flat start and a single bowl start find, against the
default multi-start, on the toy case, §IV-C and sampled n = 10 / 20 candidates of the random sets.

``--scan`` adds the old Fig. 7 style sweep over n = 10..90 (in-process, default options).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks._util import median, print_table
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.design.enumeration import SamplingPolicy, enumerate_levels
from groundstation.design.optimize import SolverOptions, optimize
from groundstation.design.task import load_task

ROOT = Path(__file__).resolve().parents[1]
P = ModuleParams()
TARGETS = {30: 10.0, 90: 60.0}


def compact_topologies(n: int, count: int) -> list[Topology]:
    *_, lv = enumerate_levels(n, sampling=SamplingPolicy(keep=200, seed=0))
    order = np.argsort(lv.radii_of_gyration(), kind="stable")
    return [lv.topology(int(i)) for i in order[:count]]


def default_command(task: Path, code: str) -> tuple[float, dict]:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "groundstation", "optimize", str(task), "--topology", code,
                           "--json"], capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        raise RuntimeError(proc.stderr)
    return wall, json.loads(proc.stdout)


def part_default_command(sizes: list[int], seeds: list[int], topologies: int) -> bool:
    ok = True
    summary = []
    for n in sizes:
        walls, runs = [], []
        for topo in compact_topologies(n, topologies if n < 60 else 1):
            for seed in seeds:
                wall, rec = default_command(ROOT / f"configs/tasks/random10_seed{seed}.toml", topo.code)
                s = rec["solver"]
                split = {k: sum(st[k] for st in s["starts"]) for k in ("ipopt_s", "function_s", "build_s")}
                walls.append(wall)
                runs.append((rec, split))
                spread = "-" if s["spread"] is None else f"{100 * s['spread']:.2f} %"
                print(f"  n={n} seed {seed} {topo.code[:24]:24s} {wall:6.1f} s  feasible={rec['feasible']} "
                      f"cost {rec['cost'] or float('nan'):.5e}  starts {len(s['starts'])} "
                      f"({sum(st['feasible'] for st in s['starts'])} feasible), {len(s['optima'])} optima, "
                      f"best x{s['best_hits']}, next {spread}, stop: {s['stop_reason']}; Ipopt "
                      f"{split['ipopt_s']:.1f} s, functions {split['function_s']:.2f} s, builds "
                      f"{split['build_s']:.1f} s", flush=True)
        spreads = [r["solver"]["spread"] for r, _ in runs if r["solver"]["spread"] is not None]
        total = {k: sum(sp[k] for _, sp in runs) for k in ("ipopt_s", "function_s", "build_s")}
        med = median(walls)
        ok &= med <= TARGETS.get(n, float("inf"))
        summary.append([n, len(walls), f"{sum(r['feasible'] for r, _ in runs)}/{len(runs)}", med, max(walls),
                        TARGETS.get(n, "-"), median([len(r["solver"]["starts"]) for r, _ in runs]),
                        median([len(r["solver"]["optima"]) for r, _ in runs]),
                        median([r["solver"]["best_hits"] for r, _ in runs]),
                        f"{100 * median(spreads):.2f} %" if spreads else "-",
                        " / ".join(f"{100 * v / sum(walls):.0f}" for v in total.values())])
    print_table("Default command: groundstation optimize random10_seed<k>.toml --topology CODE (own process, "
                "default options)",
                ["n", "runs", "feasible", "median wall s", "worst wall s", "target s", "starts (median)",
                 "distinct optima", "best reached by", "gap to 2nd optimum", "% of wall: Ipopt / functions / builds"],
                summary)
    return ok


def part_starts() -> None:
    task = load_task(ROOT / "configs/tasks/paper_iv_c_three_wrenches.toml")
    b, w = task.wrenches_for(4, P)
    rows = []
    *_, lv4 = enumerate_levels(4)
    for topo in lv4.topologies():
        d = optimize(topo, P, b, w)
        rows.append([topo.code, f"{d.cost:.5g}" if d.feasible else "infeasible", len(d.starts),
                     sum(s.feasible for s in d.starts), len(d.optima), d.best_hits, d.stop_reason,
                     f"{d.verification.max_wrench_residual:.3g}", d.certificate.kind if d.certificate else "",
                     d.wall_s])
    rows.sort(key=lambda r: (r[1] == "infeasible", r[1]))
    print_table("§IV-C example, n = 4, default options", ["topology", "cost", "starts", "feasible starts",
                                                          "optima", "best reached by", "stopped", "residual N",
                                                          "certificate", "wall s"], rows)

    cases = []
    toy = load_task(ROOT / "configs/tasks/toy_push_y.toml")
    cases += [("toy n=2", Topology.from_code(c), *toy.wrenches_for(2, P)) for c in ("oE", "oS")]
    cases += [("§IV-C n=4", t, b, w) for t in lv4.topologies()]
    for seed, n in ((0, 10), (1, 10), (2, 20)):
        rnd = load_task(ROOT / f"configs/tasks/random10_seed{seed}.toml")
        cases += [(f"random n={n}", t, *rnd.wrenches_for(n, P)) for t in compact_topologies(n, 4)]
    one = {"yaw_turns": (0,), "random_starts": 0, "min_starts": 1, "max_starts": 1}
    strategies = {"naive flat start": SolverOptions(rim_tilts_deg=(0.0,), **one),
                  "one bowl start": SolverOptions(rim_tilts_deg=(10.0,), **one),
                  "default multi-start": SolverOptions()}
    found = {k: 0 for k in strategies}
    best = {k: 0 for k in strategies}
    any_feasible = 0
    for label, topo, bb, ww in cases:
        designs = {k: optimize(topo, P, bb, ww, o) for k, o in strategies.items()}
        costs = [d.cost for d in designs.values() if d.feasible]
        any_feasible += bool(costs)
        for k, d in designs.items():
            found[k] += d.feasible
            best[k] += d.feasible and d.cost <= min(costs) * (1 + 1e-6)
        print(f"  {label:12s} {topo.code[:28]:28s} " + " ".join(
            f"{k}={d.cost:.4e}" if d.feasible else f"{k}=--" for k, d in designs.items()), flush=True)
    print_table(f"Designs found on {len(cases)} cases ({any_feasible} feasible for at least one strategy)",
                ["strategy", "feasible", "least cost of the three"],
                [[k, f"{found[k]}/{len(cases)}", f"{best[k]}/{any_feasible}"] for k in strategies])


def part_scan(sizes: list[int], seeds: list[int]) -> None:
    rows = []
    for n in sizes:
        times = []
        for topo in compact_topologies(n, 1):
            for seed in seeds:
                bb, ww = load_task(ROOT / f"configs/tasks/random10_seed{seed}.toml").wrenches_for(n, P)
                d = optimize(topo, P, bb, ww)
                times.append(d.wall_s)
                print(f"  n={n} seed {seed}: feasible={d.feasible} {d.wall_s:.1f} s, {len(d.starts)} starts",
                      flush=True)
        rows.append([n, len(times), median(times), max(times)])
    print_table("Scan (in-process, default options, most compact sampled topology)",
                ["n", "runs", "median s", "worst s"], rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="30,90")
    ap.add_argument("--seeds", default="0,1,2", help="random wrench sets (configs/tasks/random10_seed<k>.toml)")
    ap.add_argument("--topologies", type=int, default=3, help="compact topologies per n below 60 (1 above)")
    ap.add_argument("--skip-starts", action="store_true")
    ap.add_argument("--scan", action="store_true", help="also sweep n = 10..90 in-process")
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    ok = part_default_command([int(s) for s in args.sizes.split(",")], seeds, args.topologies)
    if not args.skip_starts:
        part_starts()
    if args.scan:
        part_scan(list(range(10, 100, 10)), seeds)
    print("targets (median: n = 30 <= 10 s, n = 90 <= 60 s):", "met" if ok else "MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
