"""``groundstation design``: pick the best configuration for a task (paper §IV-C, Algorithm 2)."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from groundstation.cli.common import FINITE, SEED, json_safe, progress_bar, stderr_console, writable_output
from groundstation.errors import UsageError

EXIT_INFEASIBLE = 1
TABLE_ROWS = 10
"""Feasible candidates the printed ranking shows at most (``--table`` has every row)."""
UNBOUNDED = 1_000_000
"""Console width, columns, at which a table is measured: wider than any table, so none is cropped to fit."""
MAX_WORKERS = 256
"""Most local worker processes ``--workers`` starts (each ~150 MB: 256 is ~40 GB, past any workstation)."""


@click.command("design")
@click.argument("tasks", type=click.Path(dir_okay=False))
@click.option("--max-modules", type=int, default=6, show_default=True, help="Give up after this many modules.")
@click.option("--min-modules", type=int, default=1, show_default=True,
              help="Start at this many modules (e.g. 4 and --max-modules 4 to compare all n = 4 candidates).")
@click.option("--modules", "modules", default=None, type=click.Path(dir_okay=False),
              help="Module parameter file (default: the paper's Table II).")
@click.option("--candidates", default=None, type=click.Path(dir_okay=False),
              help="Candidates file from 'enumerate --out' (default: enumerate here).")
@click.option("--sample", type=int, default=None, metavar="N_n", help="Sample N_n candidates per level.")
@click.option("--sigma", type=FINITE, default=1.0, show_default=True)
@click.option("--scheme", default="compact", show_default=True)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--no-modification", is_flag=True, help="Do not add n m g and the hover wrench to the task.")
@click.option("--workers", type=int, default=1, show_default=True,
              help=f"Local worker processes (1-{MAX_WORKERS}: each is a Python process of ~150 MB).")
@click.option("--scheduler", default=None, metavar="tcp://HOST:PORT", help="Dask distributed scheduler.")
@click.option("--results", default=None, metavar="FILE.jsonl",
              help="Results of every candidate, appended as they finish; rerun with it to resume.")
@click.option("--table", default=None, metavar="FILE.csv|FILE.json", help="Write the results table.")
@click.option("--least-u-max", "least", is_flag=True,
              help="Also find each candidate's least input bound u_max at which it is feasible (or that none is): "
                   "a column of the table and, with --figures, the cost against u_max; about doubles the time.")
@click.option("--figures", default=None, metavar="DIR",
              help="Write Fig. 1, 5 and 6 style figures here (with --least-u-max, the cost against u_max too).")
@click.option("--out", default=None, metavar="FILE.json", help="Write the best design as an assembly file.")
@click.option("--json", "as_json", is_flag=True, help="Print the best design as one JSON object.")
def design_command(tasks: str, max_modules: int, min_modules: int, modules: str | None, candidates: str | None,
                   sample: int | None, sigma: float, scheme: str, seed: int, no_modification: bool, workers: int,
                   scheduler: str | None, results: str | None, table: str | None, least: bool, figures: str | None,
                   out: str | None, as_json: bool) -> int:
    """Find the least-cost feasible configuration with the fewest modules for a task's wrench set."""
    from groundstation.assembly.assembly_file import save_assembly
    from groundstation.assembly.module import ModuleParams, load_module_params
    from groundstation.design.candidates import read_candidates
    from groundstation.design.enumeration import SamplingPolicy
    from groundstation.design.optimize import SolverOptions
    from groundstation.design.selection import results_table, select
    from groundstation.design.task import load_task
    from groundstation.output import writing

    if not 1 <= min_modules <= max_modules:
        raise UsageError(f"need 1 <= --min-modules <= --max-modules, got {min_modules} and {max_modules}")
    if not 1 <= workers <= MAX_WORKERS:  # unbounded, a typo started a million processes
        raise UsageError(f"--workers must be 1 to {MAX_WORKERS}, got {workers}")
    out_path = writable_output(out, (".json",)) if out else None
    table_path = writable_output(table, (".csv", ".json")) if table else None
    results_path = writable_output(results, (".jsonl",)) if results else None
    fig_dir = Path(figures) if figures else None
    if fig_dir is not None:
        try:
            fig_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # a file there, a read-only or looping path
            raise UsageError(f"--figures {figures}: cannot make the directory: {exc.strerror or exc}") from None
        writable_output(fig_dir / "fig1_assembly.png")
    params = load_module_params(modules) if modules else ModuleParams()
    task = load_task(tasks)
    if no_modification:
        task = dataclasses.replace(task, add_gravity=False, add_hover=False)
    sampling = SamplingPolicy(sample, sigma, scheme, seed) if sample is not None else None
    cand = None
    if candidates:
        cset = read_candidates(candidates)
        cand = {n: [t.code for t in tops] for n, tops in cset.levels.items()}

    console = stderr_console()
    with progress_bar(console) as progress:
        bar = {"task": None}

        def on_level(n: int, count: int) -> None:
            bar["task"] = progress.add_task(f"n = {n}: solving candidates", total=count)

        def on_result(_row) -> None:
            progress.advance(bar["task"])

        try:
            sel = select(task, params, max_modules, sampling=sampling, candidates=cand, opts=SolverOptions(),
                         workers=workers, scheduler=scheduler, results_path=results_path, on_level=on_level,
                         on_result=on_result, min_modules=min_modules, least=least)
        except KeyboardInterrupt:
            progress.stop()
            if results_path is not None:
                saved = sum(1 for line in results_path.read_text().splitlines() if line.strip()) \
                    if results_path.exists() else 0
                click.echo(f"groundstation: design stopped; {saved} finished candidates are in {results_path}, "
                           f"run the same command to resume", err=True)
            else:
                click.echo("groundstation: design stopped (with --results FILE a rerun resumes where it stopped)",
                           err=True)
            raise
    rows = results_table(sel.results)
    if table_path is not None:
        with writing(table_path):
            if table_path.suffix == ".json":
                table_path.write_text(json.dumps(json_safe(rows), indent=1) + "\n")
            else:
                with table_path.open("w", newline="") as fh:
                    writer = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["n"])
                    writer.writeheader()
                    writer.writerows(rows)
    if sel.best is None:
        click.echo(f"groundstation: no feasible design with up to {max_modules} modules "
                   f"({len(rows)} candidates solved)", err=True)
        return EXIT_INFEASIBLE
    if out_path is not None:
        save_assembly(out_path, sel.best.record)
    if fig_dir is not None:
        from groundstation.design.figures import plot_assembly, plot_cost_against_bound, plot_costs, plot_polytope
        from groundstation.design.selection import bound_grid, cost_against_bound

        plot_assembly(sel.best.assembly, fig_dir / "fig1_assembly.png", sel.best.row.cost)
        plot_costs(rows, sel.n, fig_dir / "fig5_costs.png")
        plot_polytope(sel.best.assembly, sel.best.wrenches[:, :3], fig_dir / "fig6_polytope.png")
    if fig_dir is not None and least:
        level = [r for r in sel.results if r.n == sel.n]
        grid = bound_grid(level, params.u_max)
        with progress_bar(console) as progress:
            bar = progress.add_task("cost against u_max", total=None)
            curves = cost_against_bound(task, params, level, grid, SolverOptions(),
                                        on_solve=lambda done, total: progress.update(bar, completed=done, total=total))
        plot_cost_against_bound(curves, params.u_max, sel.n, fig_dir / "fig5_cost_vs_u_max.png")
    if as_json:
        click.echo(json.dumps(sel.best.record))
    else:
        _print_ranking(sel, task.name, rows, params.u_max, least)
    for label, path in (("assembly", out_path), ("table", table_path), ("figures", fig_dir)):
        if path is not None:
            click.echo(f"{label}: {path}", err=True)
    return 0


def _least_bound(row: dict, nominal: float) -> str:
    """A row's least input bound and its distance to the nominal one, or why there is none."""
    if row["never_feasible"]:
        return "never"
    if row["least_u_max"] == float("inf"):
        return "none found"
    return f"{row['least_u_max']:.5g} ({100 * (row['least_u_max'] / nominal - 1):+.2f}%)"


def _print_ranking(sel, task_name: str, rows: list[dict], nominal: float, least: bool) -> None:
    """The smaller n Algorithm 2 went through; then the candidates of the chosen n: the feasible ones (the best
    :data:`TABLE_ROWS`) in a table with their start statistics and (``least``) least input bound, the others with
    why (a certificate's proof, or that no start met the wrenches, which proves nothing) and the bound they would
    need; then the best and the runner-up, and the best's angles."""
    from groundstation.design.figures import design_angles

    for n in sorted({r["n"] for r in rows} - {sel.n}):
        below = [r for r in rows if r["n"] == n]
        certified = sum(bool(r["certificate"]) for r in below)
        click.echo(f"n = {n}: 0 of {len(below)} candidates feasible ({certified} certified infeasible, "
                   f"{len(below) - certified} not found feasible)")
    level = [r for r in rows if r["n"] == sel.n]
    ranking = sel.ranking
    shown = ranking[:TABLE_ROWS]
    which = "the feasible ones, best first" if len(shown) == len(ranking) else \
        f"the {len(shown)} best of the {len(ranking)} feasible; --table FILE has every row"
    click.echo(f"{task_name}: n = {sel.n}, {len(ranking)} of {len(level)} candidates feasible; the table shows "
               f"{len(shown)} of {len(level)} candidates ({which})")
    t = Table()
    # starts: run (feasible); optima: distinct local optima reached; hits: starts reaching the best; spread: gap
    # to the topology's second local optimum; least u_max: the least input bound at which it is feasible (and
    # against the nominal one); s: wall time of both searches.
    columns = ("code", "cost", "vs best", "starts", "optima", "hits", "spread") + (("least u_max",) if least else ())
    for col in (*columns, "s"):
        t.add_column(col, justify="right", overflow="fold")  # (a terminal too narrow folds a cell, never cuts it)
    best_cost = ranking[0].cost
    by_code = {r["code"]: r for r in level}
    for r in shown:
        cells = [r.code, f"{r.cost:.5g}", f"{100 * (r.cost / best_cost - 1):+.2f}%",
                 f"{r.starts} ({r.feasible_starts})", str(r.optima), str(r.best_hits),
                 "-" if r.spread is None else f"{100 * r.spread:.2f}%"]
        t.add_row(*cells, *([_least_bound(by_code[r.code], nominal)] if least else []),
                  f"{r.wall_s + r.least_u_max_s:.1f}")
    console = Console()
    if not console.is_terminal:  # a pipe or a file has no width (rich would crop to 80 columns): the table's own
        console = Console(width=Console(width=UNBOUNDED).measure(t).maximum)
    console.print(t)
    for r in level:
        if not r["feasible"]:
            # a certificate proves it; a multi-start that met no wrench set proves nothing
            why = f"infeasible: {r['certificate']}" if r["certificate"] else \
                f"not found feasible: no start met the wrenches (least residual {r['max_wrench_residual']:.3g}, " \
                f"{r['starts']} starts)"
            if least:
                needs = _least_bound(r, nominal)
                why += "; " + {"never": "no u_max makes it feasible",
                               "none found": "no start of the least-u_max search met the wrenches either"}.get(
                    needs, f"feasible from u_max = {needs}")
            click.echo(f"  {r['code']}: {why}")
    best, runner = ranking[0], sel.runner_up
    second = f"runner-up {runner.code} ({runner.cost:.5g}, {100 * (runner.cost / best_cost - 1):+.2f} %)" \
        if runner is not None else f"no runner-up: the only feasible candidate with n = {sel.n}"
    click.echo(f"best {best.code} ({best_cost:.5g}); {second}")
    click.echo(f"angles of {best.code} (deg): {', '.join(design_angles(sel.best.assembly))}")
