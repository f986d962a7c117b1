"""``groundstation simulate``: closed-loop flight of an assembly in PyBullet, in lockstep (paper §VI)."""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path

import click
from rich.console import Console
from rich.live import Live
from rich.table import Table

from groundstation.cli.common import (
    FINITE,
    LABELS,
    STATUS_S,
    cell,
    json_safe,
    sim_physics_hz,
    status_text,
    stderr_console,
    writable_output,
)
from groundstation.errors import ConfigError, PreflightError, UsageError

EXIT_CRASHED = 1
ROWS = ("phase", "reason", "simulated_s", "pos_rmse_m", "pos_rmse_xyz_m", "max_pos_error_m", "max_pos_error_xyz_m",
        "max_orientation_error_deg", "orientation_error_p95_deg", "max_roll_error_deg", "max_yaw_error_deg",
        "max_motor_fraction", "saturation_fraction", "motor_change_rms", "mocap_age_p99_ms", "stalls", "periods",
        "realtime_factor")
"""The figures of the table, in its order, labelled as ``replay`` labels them (:data:`~groundstation.cli.common
.LABELS`); the loop's timing is left out (in lockstep it is the simulator's, not a loop's: ``--json`` has it)."""

OPTIONS = {"trajectory.kind": "--trajectory", "trajectory.duration": "--duration", "trajectory.height": "--height",
           "trajectory.size": "--size", "trajectory.period": "--period", "trajectory.roll_deg": "--roll",
           "rate_hz": "--control-hz", "backend.physics_hz": "--physics-hz", "allocation": "--allocation"}
"""The flight-config key each option sets: the options are checked as a flight config is (the same bounds)."""
NOISE = {"position_noise": 1e-3, "attitude_noise_deg": 0.2, "latency_s": 5e-3}
"""``--noise``: mocap-like noise (m, deg) and latency (s)."""
EXACT = {"position_noise": 0.0, "attitude_noise_deg": 0.0, "latency_s": 0.0}
"""Without ``--noise``: exact poses, at once (still at the mocap's rate, through the estimator)."""


@click.command("simulate")
@click.argument("assembly", type=click.Path(dir_okay=False))
@click.option("--trajectory", default="figure8", show_default=True, help="hover, circle or figure8.")
@click.option("--duration", type=FINITE, default=16.0, show_default=True, help="Tracking time, s.")
@click.option("--height", type=FINITE, default=1.0, show_default=True, help="Mean flight height h0, m.")
@click.option("--size", type=FINITE, default=0.6, show_default=True, help="Figure-8 l0 or circle radius, m.")
@click.option("--period", type=FINITE, default=8.0, show_default=True, help="Figure-8 t_c or circle period, s.")
@click.option("--roll", type=FINITE, default=0.0, show_default=True, help="Attitude target roll, degrees.")
@click.option("--control-hz", type=FINITE, default=250.0, show_default=True)
@click.option("--physics-hz", type=FINITE, default=sim_physics_hz, help="Physics rate, Hz (default: the simulator's).")
@click.option("--allocation", default="clip", show_default=True, help="clip (paper) or bounded (saturation-aware).")
@click.option("--noise", is_flag=True, help="Add mocap-like noise (1 mm, 0.2 deg) and 5 ms latency.")
@click.option("--realtime", is_flag=True, help="Pace to the wall clock instead of lockstep.")
@click.option("--gui", is_flag=True, help="Open PyBullet's GUI (needs a display).")
@click.option("--plot", default=None, metavar="FILE.png", help="Write the flight's figure (as replay --plot draws a "
              "log).")
@click.option("--json", "as_json", is_flag=True, help="Print the metrics as one JSON object.")
def simulate_command(assembly: str, trajectory: str, duration: float, height: float, size: float, period: float,
                     roll: float, control_hz: float, physics_hz: float, allocation: str, noise: bool,
                     realtime: bool, gui: bool, plot: str | None, as_json: bool) -> int:
    """Take off, track a trajectory and land, in PyBullet."""
    import numpy as np

    from groundstation.control.geometric import Gains
    from groundstation.control.model import ControlModel
    from groundstation.control.trajectory import FlightPlan, make_track
    from groundstation.runtime.closed_loop import FlightVolume, dynamics_check, fly_simulated
    from groundstation.runtime.flight_config import estimator_settings
    from sim.pybullet_backend import PyBulletBackend, SimConfig

    plot_path = writable_output(plot, (".png", ".svg", ".pdf")) if plot else None
    cfg, asm = _checked(assembly, {
        "assembly": assembly, "rate_hz": control_hz, "allocation": allocation,
        "backend": {"kind": "sim", "physics_hz": physics_hz}, "mocap": NOISE if noise else EXACT,
        "trajectory": {"kind": trajectory, "duration": duration, "height": height, "size": size, "period": period,
                       "roll_deg": roll}})
    t, m = cfg.trajectory, cfg.mocap
    track = make_track(t.kind, t.duration, t.height, t.size, t.period, t.roll_deg)
    model = ControlModel.from_assembly(asm)
    try:  # here, to name the options (fly_simulated checks it again after PyBullet started, for its other callers)
        dynamics_check(model, FlightPlan((0.0, 0.0, asm.resting_height), track), np.inf, cfg.gains.max_tilt_deg)
    except PreflightError as exc:
        raise UsageError(f"{exc} (--trajectory {t.kind} --duration {t.duration:g} --height {t.height:g} "
                         f"--size {t.size:g} --period {t.period:g} --roll {t.roll_deg:g})") from None
    sim = SimConfig(physics_hz=cfg.backend.physics_hz, gyro_delay=cfg.backend.gyro_delay_s, realtime=realtime,
                    gui=gui, mocap_rate_hz=m.rate_hz,
                    position_noise=m.position_noise, attitude_noise=np.radians(m.attitude_noise_deg),
                    latency=m.latency_s)
    started = time.time()
    console = stderr_console()
    # On a terminal, a status line as fly's (none in the GUI, whose window shows the flight).
    live = Live(console=console, auto_refresh=False, transient=True) if console.is_terminal and not gui else None
    shown = [0.0]

    def on_status(s) -> None:  # on the loop's thread, at most every STATUS_S of wall time (a render: ~0.5 ms)
        now = time.monotonic()
        if now - shown[0] >= STATUS_S:
            shown[0] = now
            live.update(status_text(s, console.width), refresh=True)

    if live is not None:
        live.start()
        live.update("[bold]preflight[/]", refresh=True)
    try:
        with PyBulletBackend(asm, sim) as backend:
            plan = FlightPlan(ground=tuple(backend.start_position), track=track)
            rec = fly_simulated(asm, plan, backend, Gains(**asdict(cfg.gains)), cfg.rate_hz, cfg.allocation,
                                FlightVolume(), estimator=estimator_settings(cfg),
                                on_status=on_status if live is not None else None)
    finally:
        if live is not None:
            live.stop()  # transient: the status line goes, and what follows starts on a line of its own
    metrics = asdict(rec.metrics) | dict(assembly=assembly, trajectory=trajectory, n=asm.n,
                   controllable_dof=asm.controllable_dof, crash_reason=rec.crash_reason)
    if plot_path is not None:
        _plot(rec, asm, plot_path, assembly, started, f"{trajectory}, roll target {roll:g} deg",
              f"simulate (PyBullet {cfg.backend.physics_hz:g} Hz, {'noisy' if noise else 'exact'} mocap)")
        metrics["plot"] = str(plot_path)
    if as_json:
        click.echo(json.dumps(json_safe(metrics)))
    else:
        figures = metrics | {"phase": "emergency" if rec.crashed else "done", "reason": rec.crash_reason}
        table = Table(title=f"Simulated {trajectory}: {assembly} (n = {asm.n}, {asm.controllable_dof} DOF)",
                      show_header=False)
        for key in ROWS:
            table.add_row(LABELS[key], cell(figures[key]))
        out = Console()
        if not out.is_terminal:  # piped: the labels whole (a terminal's width is kept: a wider table would wrap)
            out = Console(width=160)
        out.print(table)
    if plot_path is not None:
        click.echo(f"plot: {plot_path}", err=True)
    if rec.crashed:
        click.echo(f"groundstation: the flight failed: {rec.crash_reason}", err=True)
        return EXIT_CRASHED
    return 0


def _plot(rec, asm, path: Path, assembly: str, started: float, label: str, config: str) -> None:
    """The flight figure of ``rec`` (:mod:`groundstation.runtime.plots`, as ``replay --plot`` draws a log)."""
    from groundstation.control.geometric import free_angles
    from groundstation.control.model import ControlModel
    from groundstation.runtime.fly import code_version
    from groundstation.runtime.plots import assembly_fact, date_fact, save_flight_figure, trace_of_record

    facts = (assembly_fact(Path(assembly).stem, asm.n, asm.controllable_dof), ("config", config),
             date_fact(started), ("code", f"code {code_version()}"))
    save_flight_figure([trace_of_record(rec, label, facts, free_angles(ControlModel.from_assembly(asm)),
                                        asm.params.u_max)], path)


def _checked(assembly: str, options: dict):
    """The options as a flight config and the assembly, every number within the bounds a flight config has
    (:func:`~groundstation.runtime.flight_config.bound_issues`); a value beyond one is a UsageError naming the
    option (the gains, fixed here, name the loop rate that cannot realise them)."""
    from groundstation import config
    from groundstation.runtime.flight_config import FlightConfig, bound_issues, read_assembly

    physics_hz, control_hz = options["backend"]["physics_hz"], options["rate_hz"]

    def option(key: str) -> str:
        if key.startswith("gains."):
            return OPTIONS["backend.physics_hz" if physics_hz < control_hz else "rate_hz"]
        return OPTIONS.get(key, key)

    try:
        cfg = config.validate(FlightConfig, options)
    except ConfigError as exc:
        raise UsageError(f"{option(exc.key)}: {str(exc).removeprefix(f'{exc.key}: ')}") from None
    from groundstation.control.model import ControlModel

    asm = read_assembly(Path(assembly))
    for key, problem in bound_issues(cfg, asm.inertia, ControlModel.from_assembly(asm)):
        raise UsageError(f"{option(key)}: {problem}")
    return cfg, asm
