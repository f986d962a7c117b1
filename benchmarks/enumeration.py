"""Exhaustive enumeration vs the straightforward baseline, on one core (paper Table I).

    python -m benchmarks.enumeration [--n-max 13] [--baseline-max 10] [--repeats 3]

Prints a table like the paper's Table I (n, available, non-isomorphic, CPU s, peak memory) with the baseline's
CPU time measured in the same run and the ratio, per level and cumulative. Times are medians over ``--repeats``
runs for every level both implementations reach (levels above ``--baseline-max`` run once).
"""

from __future__ import annotations

import argparse
import sys

from benchmarks._util import median, pin_one_core, print_table
from benchmarks.enumeration_baseline import enumerate_baseline
from groundstation.design.enumeration import enumerate_levels

PAPER_TABLE_I = {1: (1, 1, 0.0), 2: (4, 1, 0.0006), 3: (6, 2, 0.0007), 4: (16, 7, 0.0017), 5: (68, 24, 0.0072),
                 6: (272, 97, 0.0261), 7: (1242, 401, 0.1147), 8: (5740, 1772, 0.5488), 9: (27960, 7930, 2.7293),
                 10: (136628, 36335, 14.1008), 11: (678204, 168249, 78.5251)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-max", type=int, default=13)
    ap.add_argument("--baseline-max", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    core = pin_one_core()

    ours: dict[int, list[float]] = {}
    info: dict[int, tuple[int, int, float]] = {}
    # Repeat only the levels the baseline also reaches; the largest levels run once (they take minutes of CPU).
    for rep in range(args.repeats):
        top = args.n_max if rep == 0 else min(args.n_max, args.baseline_max + 1)
        for lv in enumerate_levels(top):
            ours.setdefault(lv.n, []).append(lv.cpu_s)
            if rep == 0:
                info[lv.n] = (lv.available, lv.non_isomorphic, lv.peak_rss_mb)
    base: dict[int, list[float]] = {}
    for _ in range(args.repeats):
        for n, _avail, _iso, cpu in enumerate_baseline(args.baseline_max):
            base.setdefault(n, []).append(cpu)

    rows, cum_ours, cum_base = [], 0.0, 0.0
    for n in sorted(info):
        avail, iso, peak = info[n]
        t_ours = median(ours[n])
        cum_ours += t_ours
        paper = PAPER_TABLE_I.get(n)
        match = "" if paper is None else ("yes" if (avail, iso) == paper[:2] else "NO")
        if n in base:
            t_base = median(base[n])
            cum_base += t_base
            ratio = f"{t_base / t_ours:.0f}x" if t_ours > 1e-4 else "-"
            cum_ratio = f"{cum_base / cum_ours:.0f}x" if cum_ours > 1e-4 else "-"
        else:
            t_base, ratio, cum_ratio = "-", "-", "-"
        rows.append([n, avail, iso, match, t_ours, cum_ours, t_base, ratio, cum_ratio,
                     paper[2] if paper else "-", round(peak)])
    print_table(
        f"Exhaustive enumeration, C4, one core (core {core}); medians of {args.repeats} runs",
        ["n", "available", "non-isomorphic", "= paper", "ours CPU s", "ours cum. s", "baseline CPU s",
         "ratio", "cum. ratio", "paper CPU s", "peak MiB"],
        rows,
    )
    return 0 if all(r[3] != "NO" for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
