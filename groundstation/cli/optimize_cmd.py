"""``groundstation optimize``: the downwash-aware NLP for one configuration (paper §IV-B)."""

from __future__ import annotations

import json

import click
from rich.console import Console
from rich.table import Table

from groundstation.cli.common import SEED, FiniteFloat, FloatList, json_safe, writable_output
from groundstation.errors import TopologyError, UsageError

EXIT_INFEASIBLE = 1


@click.command("optimize")
@click.argument("tasks", type=click.Path(dir_okay=False))
@click.option("--topology", "code", required=True, help="Topology code, e.g. oE or oS(W)E (see 'enumerate --out').")
@click.option("--modules", "modules", default=None, type=click.Path(dir_okay=False),
              help="Module parameter file (default: the paper's Table II).")
@click.option("--starts", "starts", type=FloatList(FiniteFloat(-90, 90)), default=None,
              help="Multi-start: tilt of the outermost module of each starting bowl, degrees in [-90, 90], e.g. "
                   "20,10,30,5 (0 = flat start). Default: chosen by size.")
@click.option("--max-starts", type=click.IntRange(min=1), default=None,
              help="Start budget (default: by size, see README). Stops earlier once two starts agree on the best "
                   "(never before 16 starts up to n = 20).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the random starts.")
@click.option("--fixed-yaw", is_flag=True, help="Do not optimize the body yaw (the paper's formulation).")
@click.option("--out", default=None, metavar="FILE.json", help="Write the assembly file.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as one JSON object.")
def optimize_command(tasks: str, code: str, modules: str | None, starts: tuple[float, ...] | None,
                     max_starts: int | None, seed: int, fixed_yaw: bool, out: str | None, as_json: bool) -> int:
    """Optimize connector angles and inputs of one configuration for a task's wrench set."""
    from groundstation.assembly.assembly_file import save_assembly
    from groundstation.assembly.module import ModuleParams, load_module_params
    from groundstation.assembly.topology import Topology
    from groundstation.design.optimize import SolverOptions, optimize
    from groundstation.design.task import load_task

    out_path = writable_output(out, (".json",)) if out else None
    try:
        topo = Topology.from_code(code)
    except TopologyError as exc:
        raise UsageError(f"--topology: {exc}") from None
    params = load_module_params(modules) if modules else ModuleParams()
    task = load_task(tasks)
    wrenches, weights = task.wrenches_for(topo.n, params)
    opts = SolverOptions(rim_tilts_deg=starts or None, free_yaw=not fixed_yaw, max_starts=max_starts, seed=seed)
    design = optimize(topo, params, wrenches, weights, opts)
    record = design.record(task.name)
    if out_path is not None:
        save_assembly(out_path, record)
    if as_json:
        click.echo(json.dumps(json_safe(record)))
    else:
        _print_summary(design, task.name)
    if out_path is not None:
        click.echo(f"assembly: {out_path}", err=True)
    if not design.feasible:
        why = design.certificate.reason if design.certificate else \
            (f"no start met the wrenches ({len(design.starts)} starts; least residual "
             f"{design.verification.max_wrench_residual:.3g}, min clearance "
             f"{design.verification.min_capsule_distance:.3f} m)")
        click.echo(f"groundstation: no feasible design for {code}: {why}", err=True)
        return EXIT_INFEASIBLE
    return 0


def _print_summary(design, task_name: str) -> None:
    import numpy as np

    v = design.verification
    table = Table(title=f"{design.topology.code}: {task_name}", show_header=False)
    table.add_row("status", f"{design.status} ({'feasible' if design.feasible else 'INFEASIBLE'})")
    table.add_row("cost", f"{design.cost:.6g} (rad^2/s^2)^2")
    table.add_row("angles (deg)", np.array2string(np.degrees(design.alpha), precision=2, suppress_small=True))
    table.add_row("yaw (deg)", f"{np.degrees(design.yaw):.2f}")
    table.add_row("max |Au - b|", f"{v.max_wrench_residual:.3g}")
    table.add_row("min clearance", f"{v.min_capsule_distance:.4f} m (need {v.required_distance:.3f})")
    feasible = sum(s.feasible for s in design.starts)
    table.add_row("starts", f"{len(design.starts)} ({feasible} feasible), stopped: {design.stop_reason}; "
                            f"{design.wall_s:.2f} s")
    if design.optima:
        spread = "" if design.spread is None else f", next {100 * design.spread:.2f} % above"
        table.add_row("local optima", f"{len(design.optima)} distinct; best reached by {design.best_hits}{spread}")
    Console().print(table)
