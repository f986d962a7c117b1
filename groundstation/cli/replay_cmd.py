"""``groundstation replay``: the figure-8 analysis of flight logs, side by side."""

from __future__ import annotations

import contextlib
import errno
import json
import math
from dataclasses import asdict
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from groundstation.cli.common import FINITE, LABELS, cell, json_safe, progress_bar, stderr_console, writable_output
from groundstation.errors import UsageError
from groundstation.output import stdout_lost

ROWS = ("phase", "reason", "duration_s", "tracked_s", "pos_rmse_m", "max_pos_error_m", "max_orientation_error_deg",
        "orientation_error_p95_deg", "max_roll_error_deg", "max_yaw_error_deg", "max_motor_fraction",
        "saturation_fraction", "motor_change_rms", "loop_period_error_p99_ms", "overruns", "stalls", "mocap_rate_hz",
        "mocap_age_p99_ms", "mocap_rejected", "mocap_malformed", "estimator_rejected", "estimator_late",
        "position_sigma_max_m", "height_sigma_max_m", "innovation_position_p95_mm", "innovation_attitude_p95_deg",
        "battery_v_min",
        "link_latency_ms_max", "link_loss_max")
"""The figures of the table, in its order (labelled by :data:`~groundstation.cli.common.LABELS`)."""


@click.command("replay")
@click.argument("logs", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print the figures as JSON: a list of one object per log, in "
              "the order given (whatever their number).")
@click.option("--plot", default=None, metavar="FILE.png", help="Write the Fig. 9-style figure, the logs side by side.")
@click.option("--csv", "csv_dir", default=None, metavar="DIR", help="Write each log's periods, mocap poses and "
              "events (in the window) as CSV into DIR (made if missing).")
@click.option("--from", "t_from", type=FINITE, default=None, help="Start of the window, flight time s.")
@click.option("--to", "t_to", type=FINITE, default=None, help="End of the window, flight time s.")
@click.option("--rerun", is_flag=True, help="Feed the logged states through this code's controller and "
              "allocation and report how far the commands differ from the logged ones.")
@click.option("--rerun-with", "rerun_with", default=None, metavar="FLIGHT.toml",
              help="Re-run with the gains and allocation of this flight config instead of the log's.")
@click.option("--gyro-lag", "gyro_lag", is_flag=True, help="Find how old the modules' gyro readings were (match "
              "their rate to the poses'): what backend.gyro_delay_s should be for these modules.")
def replay_command(logs: tuple[str, ...], as_json: bool, plot: str | None, csv_dir: str | None,
                   t_from: float | None, t_to: float | None, rerun: bool, rerun_with: str | None,
                   gyro_lag: bool) -> int:
    """Analyse flight logs: tracking against the setpoint, attitude against its targets, loop timing, mocap,
    motors, battery, link, and every event. Several logs are compared side by side. A damaged chunk or record is
    skipped with a warning naming it, and the rest analysed."""
    from groundstation.replay.analysis import analyse

    plot_path = writable_output(plot, (".png", ".svg", ".pdf")) if plot else None
    if t_from is not None and t_to is not None and t_to <= t_from:
        raise UsageError(f"--to ({t_to:g}) must be after --from ({t_from:g})")
    if csv_dir is not None:
        try:
            Path(csv_dir).mkdir(parents=True, exist_ok=True)
        except FileExistsError:
            raise UsageError(f"{csv_dir}: not a directory") from None
        except OSError as exc:
            raise UsageError(f"{csv_dir}: cannot make the directory: {exc.strerror}") from None
    gains = allocation = None
    if rerun_with is not None:
        from groundstation.control.geometric import Gains
        from groundstation.runtime.flight_config import load_flight_config

        cfg, _ = load_flight_config(rerun_with)
        gains, allocation = Gains(**asdict(cfg.gains)), cfg.allocation
    console = stderr_console()
    replays = []
    with progress_bar(console) as bar:
        for path in logs:
            task = bar.add_task(Path(path).name, total=1.0)
            replays.append(analyse(path, t_from, t_to, rerun or rerun_with is not None, gains, allocation,
                                   progress=lambda f, task=task: bar.update(task, completed=f)))
            bar.update(task, completed=1.0)
    lags = {}
    if gyro_lag:
        from groundstation.replay.gyro_lag import gyro_lag as find_lag

        lags = {r.path: find_lag(r.path) for r in replays}
    for r in replays:  # damage is skipped, the rest analysed: the operator is told what was skipped
        for line in r.warnings:
            click.echo(f"groundstation: warning: {r.path.name}: {line}", err=True)
    if csv_dir is not None:
        from groundstation.replay.export import export_csv

        for path in logs:
            for out in export_csv(path, csv_dir, t_from, t_to):
                click.echo(f"csv: {out}", err=True)
    if plot_path is not None:
        from groundstation.replay.plots import plot_replays

        flown = [r for r in replays if r.metrics.periods]
        for r in replays:
            if not r.metrics.periods:
                click.echo(f"groundstation: warning: {r.path.name}: not plotted: it never flew (no control period)",
                           err=True)
        if flown:
            plot_replays(flown, plot_path)
            click.echo(f"plot: {plot_path}", err=True)
    try:
        _print(replays, lags, as_json, t_from, t_to)
    except OSError as exc:  # stdout on a full disk or closed: one line, not a traceback
        if exc.errno != errno.EPIPE:  # a pipe whose reader went (`| head`) chose to stop: quiet, as every command
            with contextlib.suppress(OSError):
                click.echo(f"groundstation: cannot print the replay ({exc.strerror or exc})", err=True)
        stdout_lost()
        return 1
    return 0


def _print(replays, lags: dict, as_json: bool, t_from: float | None, t_to: float | None) -> None:
    """The figures of ``replays`` on stdout: JSON, or a table with each log's timeline and warnings."""
    if as_json:
        objs = [json_safe({"log": str(r.path), "complete": r.complete, "warnings": list(r.warnings),
                           **asdict(r.metrics),
                           "events": [{"t": t, "level": level, "text": text} for t, level, text in r.events],
                           "timeline": [{"t": t, "phase": p} for t, p in r.timeline],
                           **({"rerun": asdict(r.rerun)} if r.rerun is not None else {}),
                           **({"gyro_lag": asdict(lags[r.path]) | {"found": lags[r.path].found}} if lags else {})})
                for r in replays]
        click.echo(json.dumps(objs))
        return
    window = "" if t_from is None and t_to is None else \
        f", flight time {'start' if t_from is None else f'{t_from:g} s'} to {'end' if t_to is None else f'{t_to:g} s'}"
    table = Table(title="flight logs" + window)
    table.add_column("")
    for r in replays:
        table.add_column(r.path.name + ("" if r.complete else " (damaged)" if r.warnings else " (cut short)"))
    for key in ROWS:
        table.add_row(LABELS[key], *(cell(getattr(r.metrics, key)) for r in replays))
    if any(r.rerun is not None for r in replays):
        table.add_row("re-run: max rotor diff (u/u_max)",
                      *("-" if r.rerun is None else cell(r.rerun.max_motor_diff) for r in replays))
    out = Console(width=160)
    out.print(table)
    for path, lag in lags.items():
        if lag.found:
            out.print(f"[bold]{path.name}[/]: gyro readings {lag.delay_s * 1e3:.0f} ms old (backend.gyro_delay_s: "
                      f"{lag.configured_s * 1e3:.0f} ms); rate mismatch {math.degrees(lag.rms_at_delay):.1f} deg/s "
                      f"RMS there, {math.degrees(lag.rms_at_zero):.1f} at 0 ms, over {lag.samples} pose intervals")
        else:
            out.print(f"[bold]{path.name}[/]: no gyro delay found: the body turned at "
                      f"{math.degrees(lag.rate_rms):.1f} deg/s RMS (at least 5 needed) and the rates matched "
                      f"{lag.sharpness:.2f} times better at {lag.delay_s * 1e3:.0f} ms than 10 ms beside it (at "
                      f"least 1.25 needed): fly a manoeuvre that turns")
    for r in replays:
        out.print(f"[bold]{r.path.name}[/]: " + " -> ".join(f"{p} ({t:.1f} s)" for t, p in r.timeline))
        for t, level, text in r.events:
            if level in ("warning", "error", "fatal"):
                out.print(f"  [yellow]{t:8.2f} s {level}: {text}[/]")

