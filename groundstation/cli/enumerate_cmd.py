"""``groundstation enumerate``: non-isomorphic configurations per number of modules (paper §III)."""

from __future__ import annotations

import json

import click
from rich.console import Console
from rich.table import Table

from groundstation.choices import SAMPLING_SCHEMES, SYMMETRY_GROUPS
from groundstation.cli.common import FINITE, SEED, progress_bar, stderr_console, writable_output
from groundstation.errors import UsageError

LARGEST_DRAWABLE = {"C4": 7, "D4": 8, "none": 6}
"""Per symmetry group, the largest n whose whole level fits in one drawing (``drawing.MAX_DRAWN``; C4: 401 at
n = 7, 1772 at 8; D4: 908 and 4011; none: 364 and 1574; tests/cli/test_enumerate_cmd.py counts them): a larger
``--draw`` is refused before enumerating, not after minutes of it."""


@click.command("enumerate")
@click.argument("n", type=int)
@click.option("--symmetry", type=click.Choice(SYMMETRY_GROUPS), default="C4", show_default=True,
              help="Isomorphism group: C4 (rotations, paper), D4 (rotations and mirrors) or none.")
@click.option("--sample", "sample", type=int, default=None, metavar="N_n",
              help="Keep at most N_n configurations per level, drawn without replacement (Algorithm 1).")
@click.option("--sigma", type=FINITE, default=1.0, show_default=True,
              help="Width of the Gaussian weight on the radius of gyration, in module pitches.")
@click.option("--scheme", type=click.Choice(SAMPLING_SCHEMES), default="compact", show_default=True,
              help="Sampling weights: compact (the paper's: near the smallest radius of gyration), uniform or "
                   "spread (near the largest).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Random seed of the sampling.")
@click.option("--out", "out", default=None, metavar="FILE",
              help="Write the configurations of every level (.json: readable codes; .npz: compact arrays).")
@click.option("--draw", "draw", default=None, metavar="FILE.png",
              help="Draw every configuration of level N (like the paper's Fig. 3).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object per level instead of a table.")
def enumerate_command(n: int, symmetry: str, sample: int | None, sigma: float, scheme: str, seed: int,
                      out: str | None, draw: str | None, as_json: bool) -> None:
    """Enumerate non-isomorphic configurations of 1..N modules on the square lattice."""
    from groundstation.assembly.lattice import group_matrices
    from groundstation.design.candidates import SUFFIXES, write_candidates
    from groundstation.design.drawing import MAX_DRAWN
    from groundstation.design.enumeration import SamplingPolicy, compile_kernels, enumerate_levels

    group_matrices(symmetry)  # validates the name before any work
    sampling = SamplingPolicy(keep=sample, sigma=sigma, scheme=scheme, seed=seed) if sample is not None else None
    if sample is None and (scheme != "compact" or sigma != 1.0 or seed != 0):
        raise UsageError("--sigma, --scheme and --seed only apply with --sample")
    out_path = writable_output(out, SUFFIXES) if out else None
    draw_path = writable_output(draw, (".png", ".svg", ".pdf")) if draw else None
    if n < 1:
        raise UsageError(f"number of modules must be at least 1, got {n}")
    if draw_path is not None and n > LARGEST_DRAWABLE[symmetry] and (sample is None or sample > MAX_DRAWN):
        raise UsageError(f"--draw: level n={n} ({symmetry}) has more than {MAX_DRAWN} configurations, too many to "
                         f"draw; draw n <= {LARGEST_DRAWABLE[symmetry]}, or sample it (--sample {MAX_DRAWN} or less)")

    console = stderr_console()
    with console.status("loading the enumeration kernels (the first run on a machine compiles them, ~10 s)"):
        compile_kernels()
    levels = []
    table = Table(title=f"Non-isomorphic configurations ({symmetry}{', sampled' if sampling else ''})")
    for col in ("n", "available", "non-isomorphic", "kept", "CPU s", "peak MiB"):
        table.add_column(col, justify="right")
    with progress_bar(console) as progress:
        task = progress.add_task("enumerating levels", total=n)
        try:
            for level in enumerate_levels(n, symmetry, sampling):
                levels.append(level)
                progress.advance(task)
                row = {"n": level.n, "available": level.available, "non_isomorphic": level.non_isomorphic,
                       "kept": level.kept, "cpu_s": round(level.cpu_s, 4), "peak_rss_mb": round(level.peak_rss_mb, 1)}
                if as_json:
                    click.echo(json.dumps(row))
                else:
                    table.add_row(*(str(v) for v in row.values()))
        except (KeyboardInterrupt, MemoryError) as exc:
            # Ctrl-C (exit 130), or a level too large for this machine's memory (exit 1: a MemoryError traceback
            # at level 13 under a 3 GB limit): the finished levels (printed as they came with --json).
            if not as_json:
                Console().print(table)
            done = f"; levels 1 to {len(levels)} are complete" if levels else ""
            unwritten = f"; {out_path} not written" if out_path is not None else ""  # it was asked for: say so
            why = "" if isinstance(exc, KeyboardInterrupt) else \
                " (out of memory: sample the levels, --sample N_n, as the paper's Algorithm 1 does)"
            click.echo(f"groundstation: enumeration stopped in level {len(levels) + 1}{why}{done}{unwritten}",
                       err=True)
            if isinstance(exc, KeyboardInterrupt):
                raise
            raise SystemExit(1) from None
        if out_path is not None:
            total = sum(lv.kept for lv in levels) if out_path.suffix == ".json" else None
            wtask = progress.add_task(f"writing {out_path.name}", total=total)
            write_candidates(out_path, levels, symmetry, sampling, progress=lambda k: progress.advance(wtask, k))
    if not as_json:
        Console().print(table)
    if draw_path is not None:
        from groundstation.design.drawing import draw_level

        last = levels[-1]
        draw_level(last.topologies(), draw_path,
                   f"{last.kept} non-isomorphic configurations of {last.n} modules ({symmetry})")
        click.echo(f"drawing: {draw_path}", err=True)
    if out_path is not None:
        click.echo(f"configurations: {out_path}", err=True)
