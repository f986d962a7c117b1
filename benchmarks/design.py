"""Design benchmarks (paper §IV-C): solve time per n on the random-wrench sets (Fig. 7), and how often a start
fails.

    python -m benchmarks.design [--sizes 10,20,30,...,90] [--topologies 2] [--seeds 0,1,2]
                                [--plot benchmarks/out/design.png] [--starts-only | --timing-only]

Part 1: for each n, the most compact sampled topologies of n modules against each random wrench set
``configs/tasks/random10_seed<k>`` (10 random wrenches, no modification, as in the paper); wall time of the
whole multi-start on one core (median and worst over topologies x sets), verified feasibility, NLP size.
Part 2: success rate of the naive single start (flat, the paper's), of one bowl start, and of the default
multi-start, on the toy case, all n = 4 candidates of the §IV-C example and sampled n = 10 / 20 candidates of
the random sets.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from benchmarks._util import median, pin_one_core, print_table
from groundstation.assembly.module import ModuleParams
from groundstation.design.enumeration import SamplingPolicy, enumerate_levels
from groundstation.design.optimize import SolverOptions, optimize
from groundstation.design.task import load_task

ROOT = Path(__file__).resolve().parents[1]
P = ModuleParams()


def compact_topologies(n: int, count: int):
    *_, lv = enumerate_levels(n, sampling=SamplingPolicy(keep=200, seed=0))
    order = np.argsort(lv.radii_of_gyration(), kind="stable")
    return [lv.topology(int(i)) for i in order[:count]]


def timing(sizes: list[int], count: int, seeds: list[int], plot: str | None) -> bool:
    tasks = {s: load_task(ROOT / f"configs/tasks/random10_seed{s}.toml") for s in seeds}
    rows, med, worst = [], {}, {}
    for n in sizes:
        times, feas, converged = [], [], 0
        for topo in compact_topologies(n, count):
            for seed, task in tasks.items():
                b, w = task.wrenches_for(n, P)
                d = optimize(topo, P, b, w, SolverOptions(max_starts_feasible=1))
                times.append(d.wall_s)
                feas.append(d.feasible)
                converged += d.status == "Solve_Succeeded"
                print(f"  n={n} seed {seed} {topo.code[:30]}: {d.status}, feasible={d.feasible}, {d.wall_s:.1f} s, "
                      f"{d.iterations} it, {d.active_pairs} pairs", flush=True)
        med[n], worst[n] = median(times), max(times)
        rows.append([n, (4 * n * len(b)) + n + 1, 6 * len(b), n * (n - 1) // 2, f"{sum(feas)}/{len(feas)}",
                     f"{converged}/{len(feas)}", med[n], worst[n]])
    print_table(f"Downwash-aware NLP, 10 random wrenches, {count} topologies x {len(seeds)} wrench sets per n, one "
                "core (paper: n = 90 median 5460 s)",
                ["n", "paper's variables", "equalities", "module pairs", "feasible (verified)",
                 "converged (others: feasible at the iteration cap)", "median wall s", "worst wall s"], rows)
    if plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3.5))
        ax.semilogy(list(med), list(med.values()), "o-", label="median")
        ax.semilogy(list(worst), list(worst.values()), "v--", label="worst")
        ax.semilogy([90], [5460], "rs", label="paper, n = 90 median")
        ax.legend()
        ax.set_xlabel("number of modules n")
        ax.set_ylabel("solve time (s)")
        ax.grid(True, which="both", alpha=0.3)
        Path(plot).parent.mkdir(parents=True, exist_ok=True)
        fig.tight_layout()
        fig.savefig(plot, dpi=120)
        print(f"figure: {plot}")
    return all(d.get(30, 0) <= 20 and d.get(90, 0) <= 120 for d in (med, worst))


def starts() -> None:
    cases = []
    toy = load_task(ROOT / "configs/tasks/toy_push_y.toml")
    from groundstation.assembly.topology import Topology

    cases += [("toy n=2", Topology.from_code(c), *toy.wrenches_for(2, P)) for c in ("oE", "oS")]
    ivc = load_task(ROOT / "configs/tasks/paper_iv_c_three_wrenches.toml")
    *_, lv4 = enumerate_levels(4)
    cases += [("§IV-C n=4", t, *ivc.wrenches_for(4, P)) for t in lv4.topologies()]
    for seed, n in ((0, 10), (1, 10), (2, 20)):
        task = load_task(ROOT / f"configs/tasks/random10_seed{seed}.toml")
        cases += [(f"random n={n}", t, *task.wrenches_for(n, P)) for t in compact_topologies(n, 4)]
    strategies = {"naive flat start": (0.0,), "one bowl start": (10.0,), "multi-start": None}
    counts = {k: 0 for k in strategies}
    any_feasible = 0
    for label, topo, b, w in cases:
        ok = {k: optimize(topo, P, b, w, SolverOptions(rim_tilts_deg=v, max_starts_feasible=1)).feasible
              for k, v in strategies.items()}
        any_feasible += any(ok.values())
        for k, v in ok.items():
            counts[k] += v
        print(f"  {label:12s} {topo.code[:28]:28s} " + " ".join(f"{k}={'ok' if v else '--'}" for k, v in ok.items()),
              flush=True)
    rows = [[k, f"{counts[k]}/{len(cases)}", f"{any_feasible - counts[k]}"] for k in strategies]
    print_table(f"Feasible designs found on {len(cases)} cases ({any_feasible} solved by at least one strategy)",
                ["strategy", "feasible", "missed (solved by another)"], rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="10,20,30,40,50,60,70,80,90")
    ap.add_argument("--topologies", type=int, default=2)
    ap.add_argument("--seeds", default="0,1,2", help="random wrench sets (configs/tasks/random10_seed<k>.toml)")
    ap.add_argument("--timing-only", action="store_true")
    ap.add_argument("--plot", default="benchmarks/out/design.png")
    ap.add_argument("--starts-only", action="store_true")
    args = ap.parse_args(argv)
    pin_one_core()
    if not args.timing_only:
        starts()
    if args.starts_only:
        return 0
    ok = timing([int(s) for s in args.sizes.split(",")], args.topologies, [int(s) for s in args.seeds.split(",")],
                args.plot)
    print("targets (n = 30 <= 20 s, n = 90 <= 120 s, median and worst case):", "met" if ok else "MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
