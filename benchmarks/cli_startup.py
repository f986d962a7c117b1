"""Start-up time of the command line (issue 14: ``groundstation --help`` took 2 s; target < 0.3 s).

    python -m benchmarks.cli_startup [--repeats 7]

Each row is a fresh process, median over repeats: the bare interpreter (baseline), ``groundstation --help``,
``groundstation fly --help``, and importing the libraries help used to pull in (numpy, scipy.optimize, casadi,
numba), for scale.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchmarks._util import print_table

ROOT = Path(__file__).resolve().parents[1]
GROUNDSTATION = [sys.executable, "-m", "groundstation"]
TARGET_S = 0.3

CASES = {
    "python -c pass (baseline)": [sys.executable, "-c", "pass"],
    "groundstation --help": [*GROUNDSTATION, "--help"],
    "groundstation fly --help": [*GROUNDSTATION, "fly", "--help"],
    "groundstation design --help": [*GROUNDSTATION, "design", "--help"],
    "import numpy, scipy.optimize, casadi, numba": [sys.executable, "-c",
                                                    "import numpy, scipy.optimize, casadi, numba"],
}


def wall(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, cwd=ROOT)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    rows, medians = [], {}
    for label, cmd in CASES.items():
        wall(cmd)  # warm the file cache
        times = [wall(cmd) for _ in range(args.repeats)]
        medians[label] = statistics.median(times)
        rows.append([label, medians[label], max(times)])
    base = medians["python -c pass (baseline)"]
    for row in rows:
        row.append(row[1] / base)
    print_table(f"Start-up, fresh process, median of {args.repeats}", ["command", "median s", "worst s",
                                                                      "x baseline"], rows)
    ok = all(medians[k] < TARGET_S for k in CASES if k.startswith("groundstation"))
    print(f"target (every help < {TARGET_S} s):", "met" if ok else "MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
