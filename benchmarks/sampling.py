"""Sampling-based enumeration (Algorithm 1) vs exhaustive, per-n CPU time (paper Fig. 4).

    python -m benchmarks.sampling [--n-max 100] [--keep 500] [--plot benchmarks/out/sampling.png]

Prints per-n CPU time of the sampled enumeration (medians over ``--repeats``), the total against the 60 s
target, a log-log slope of per-level time against n (1 = linear growth), and the exhaustive times for n <= 11
for comparison; writes the figure.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from benchmarks._util import median, pin_one_core, print_table
from groundstation.design.enumeration import SamplingPolicy, enumerate_levels


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-max", type=int, default=100)
    ap.add_argument("--keep", type=int, default=500)
    ap.add_argument("--sigma", type=float, default=1.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--exhaustive-max", type=int, default=11)
    ap.add_argument("--plot", default="benchmarks/out/sampling.png")
    args = ap.parse_args(argv)
    core = pin_one_core()

    sampled: dict[int, list[float]] = {}
    totals = []
    for rep in range(args.repeats):
        levels = list(enumerate_levels(args.n_max, sampling=SamplingPolicy(args.keep, args.sigma, seed=rep)))
        totals.append(sum(lv.cpu_s for lv in levels))
        for lv in levels:
            sampled.setdefault(lv.n, []).append(lv.cpu_s)
    exhaustive = {lv.n: lv.cpu_s for lv in enumerate_levels(args.exhaustive_max)}

    ns = np.array(sorted(sampled))
    t = np.array([median(sampled[n]) for n in ns])
    fit = ns >= 20
    slope = float(np.polyfit(np.log(ns[fit]), np.log(t[fit]), 1)[0]) if fit.sum() > 2 else float("nan")
    rows = [[int(n), median(sampled[n]), exhaustive.get(int(n), "-")] for n in ns if n <= 12 or n % 5 == 0]
    print_table(f"Sampled enumeration, N_n = {args.keep}, sigma = {args.sigma}, one core (core {core})",
                ["n", "sampled CPU s (median)", "exhaustive CPU s"], rows)
    total = median(totals)
    print(f"total CPU for n = 1..{args.n_max}: median {total:.2f} s over {args.repeats} runs "
          f"(target 60 s: {'met' if total <= 60 else 'MISSED'}); "
          f"per-level time grows as n^{slope:.2f} for n >= 20")

    out = Path(args.plot)
    out.parent.mkdir(parents=True, exist_ok=True)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.semilogy(ns, t, "o-", ms=2, label=f"sampling, $N_n$={args.keep}")
    ex = sorted(exhaustive.items())
    ax.semilogy([n for n, _ in ex][1:], [c for _, c in ex][1:], "s-", ms=3, label="exhaustive")
    ax.set_xlabel("number of modules n")
    ax.set_ylabel("CPU time per level (s)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    print(f"figure: {out}")
    return 0 if total <= 60 else 1


if __name__ == "__main__":
    sys.exit(main())
