"""``groundstation simulate``: closed-loop flight of an assembly in PyBullet, in lockstep (paper §VI)."""

from __future__ import annotations

import json
from dataclasses import asdict

import click
from rich.console import Console
from rich.table import Table

from groundstation.cli.common import json_safe, sim_physics_hz, writable_output
from groundstation.errors import UsageError

EXIT_CRASHED = 1


@click.command("simulate")
@click.argument("assembly", type=click.Path(dir_okay=False))
@click.option("--trajectory", default="figure8", show_default=True, help="hover, circle or figure8.")
@click.option("--duration", type=float, default=16.0, show_default=True, help="Tracking time, s.")
@click.option("--height", type=float, default=1.0, show_default=True, help="Mean flight height h0, m.")
@click.option("--size", type=float, default=0.6, show_default=True, help="Figure-8 l0 or circle radius, m.")
@click.option("--period", type=float, default=8.0, show_default=True, help="Figure-8 t_c or circle period, s.")
@click.option("--roll", type=float, default=0.0, show_default=True, help="Attitude target roll, degrees.")
@click.option("--control-hz", type=float, default=250.0, show_default=True)
@click.option("--physics-hz", type=float, default=sim_physics_hz, help="Physics rate, Hz (default: the simulator's).")
@click.option("--allocation", default="clip", show_default=True, help="clip (paper) or bounded (saturation-aware).")
@click.option("--noise", is_flag=True, help="Add mocap-like noise (1 mm, 0.2 deg) and 5 ms latency.")
@click.option("--realtime", is_flag=True, help="Pace to the wall clock instead of lockstep.")
@click.option("--gui", is_flag=True, help="Open PyBullet's GUI (needs a display).")
@click.option("--plot", default=None, metavar="FILE.png", help="Write a plot of the flight.")
@click.option("--json", "as_json", is_flag=True, help="Print the metrics as one JSON object.")
def simulate_command(assembly: str, trajectory: str, duration: float, height: float, size: float, period: float,
                     roll: float, control_hz: float, physics_hz: float, allocation: str, noise: bool,
                     realtime: bool, gui: bool, plot: str | None, as_json: bool) -> int:
    """Take off, track a trajectory and land, in PyBullet."""
    import numpy as np

    from groundstation.assembly.assembly_file import load_assembly
    from groundstation.control.geometric import Gains
    from groundstation.control.trajectory import FlightPlan, make_track
    from groundstation.runtime.closed_loop import FlightVolume, fly_simulated
    from sim.pybullet_backend import PyBulletBackend, SimConfig

    plot_path = writable_output(plot, (".png", ".svg", ".pdf")) if plot else None
    if allocation not in ("clip", "bounded"):
        raise UsageError(f"unknown allocation {allocation!r}; choose clip or bounded")
    for name, value in (("--duration", duration), ("--period", period), ("--control-hz", control_hz),
                        ("--physics-hz", physics_hz), ("--size", size)):
        if not value > 0:
            raise UsageError(f"{name} must be positive, got {value}")
    asm, _ = load_assembly(assembly)
    track = make_track(trajectory, duration, height, size, period, roll)
    cfg = SimConfig(physics_hz=physics_hz, realtime=realtime, gui=gui,
                    position_noise=1e-3 if noise else 0.0, attitude_noise=np.radians(0.2) if noise else 0.0,
                    latency=5e-3 if noise else 0.0)
    with PyBulletBackend(asm, cfg) as backend:
        plan = FlightPlan(ground=tuple(backend.start_position), track=track)
        rec = fly_simulated(asm, plan, backend, Gains(), control_hz, allocation, FlightVolume())
    metrics = asdict(rec.metrics) | dict(assembly=assembly, trajectory=trajectory, n=asm.n,
                   controllable_dof=asm.controllable_dof, crash_reason=rec.crash_reason)
    if plot_path is not None:
        from groundstation.runtime.plots import plot_flight

        plot_flight(rec, plot_path, f"{trajectory}, n = {asm.n}, roll target {roll:g} deg", asm.params.u_max)
        metrics["plot"] = str(plot_path)
    if as_json:
        click.echo(json.dumps(json_safe(metrics)))
    else:
        table = Table(title=f"Simulated {trajectory}: {assembly}", show_header=False)
        for k, v in metrics.items():
            table.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
        Console().print(table)
    if plot_path is not None:
        click.echo(f"plot: {plot_path}", err=True)
    if rec.crashed:
        click.echo(f"groundstation: the flight failed: {rec.crash_reason}", err=True)
        return EXIT_CRASHED
    return 0
