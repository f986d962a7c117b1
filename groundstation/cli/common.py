"""Helpers shared by the commands: number types of the options, stderr console, progress bars, output path checks,
the labels of the flight figures in tables, the status line of a flight."""

from __future__ import annotations

import math
import os
from pathlib import Path

import click
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from groundstation.errors import UsageError


class FiniteFloat(click.FloatRange):
    """The type of every float option: a finite number (``nan``, ``inf``: one line naming the option, exit 2),
    optionally within a range like :class:`click.FloatRange` (whose bounds alone let ``nan`` through)."""

    name = "float"

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number

    def _describe_range(self) -> str:
        return super()._describe_range() if self.min is not None or self.max is not None else ""


FINITE = FiniteFloat()
"""Any finite float."""

SEED = click.IntRange(min=0)
"""A random seed: numpy's generators take non-negative integers."""


class FloatList(click.ParamType):
    """Comma-separated numbers (``20,10,30,5``), each converted by ``item`` (a :class:`FiniteFloat`)."""

    name = "list"

    def __init__(self, item: FiniteFloat) -> None:
        self.item = item

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        return tuple(self.item.convert(v.strip(), param, ctx) for v in str(value).split(","))


def stderr_console() -> Console:
    return Console(stderr=True)


def progress_bar(console: Console) -> Progress:
    """A progress bar on stderr, shown only when stderr is a terminal."""
    return Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        console=console, disable=not console.is_terminal, transient=True,
    )


def writable_output(path: str | Path, suffixes: tuple[str, ...] | None = None) -> Path:
    """Check, before any work is done, that ``path`` can be written; return it as a Path."""
    p = Path(path)
    if suffixes is not None and p.suffix not in suffixes:
        raise UsageError(f"{p}: unsupported file type {p.suffix!r}; use one of {', '.join(suffixes)}")
    if p.is_dir():
        raise UsageError(f"{p}: is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise UsageError(f"{p}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise UsageError(f"{p}: not writable")
    # Whatever its name: a log renamed a.png was written over by `replay a.png --plot a.png` (a .mcap output
    # refuses any file that exists, itself).
    if p.suffix != ".mcap" and _is_flight_log(p):
        raise UsageError(f"{p}: is a flight log (MCAP); no output is ever written over one")
    return p


def _is_flight_log(path: Path) -> bool:
    """``path`` is a regular file that begins as an MCAP file does."""
    from groundstation.flightlog.salvage import MAGIC

    try:
        if not path.is_file():
            return False
        with open(path, "rb") as fh:
            return fh.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def json_safe(x):
    """``x`` with NaN and inf as null, so ``--json`` output is strict JSON (jq, JavaScript)."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    return x


def sim_physics_hz() -> float:
    """Default of ``--physics-hz``: the simulator's physics rate (imported when a command runs, not for help)."""
    from groundstation.backends.section import SIM_PHYSICS_HZ

    return SIM_PHYSICS_HZ


LABELS = {
    "phase": "end", "reason": "why", "duration_s": "flight time analysed (s)",
    "simulated_s": "flight time simulated (s)", "tracked_s": "tracking time (s)",
    "pos_rmse_m": "position RMSE, tracking (m)", "pos_rmse_xyz_m": "position RMSE x, y, z, tracking (m)",
    "max_pos_error_m": "max position error, tracking (m)",
    "max_pos_error_xyz_m": "max position error x, y, z, tracking (m)",
    "max_orientation_error_deg": "max attitude error, airborne (deg)",
    "orientation_error_p95_deg": "attitude error p95, airborne (deg)",
    "max_roll_error_deg": "max roll error, airborne (deg)", "max_yaw_error_deg": "max yaw error, airborne (deg)",
    "max_motor_fraction": "max rotor (u/u_max)", "saturation_fraction": "saturated (airborne, per module)",
    "motor_change_rms": "rotor change per period RMS, tracking (u/u_max)",
    "loop_period_error_p99_ms": "loop start error p99 (ms)", "overruns": "late periods", "stalls": "loop stalls",
    "mocap_rate_hz": "mocap rate, poses arrived (Hz)", "mocap_age_p99_ms": "mocap age p99 (ms)",
    "mocap_rejected": "mocap rejected", "mocap_malformed": "mocap malformed",
    "estimator_rejected": "poses the estimator rejected", "estimator_late": "poses too late for the estimator",
    "position_sigma_max_m": "horizontal std max (m)", "height_sigma_max_m": "height std max (m)",
    "innovation_position_p95_mm": "innovation p95 (mm)",
    "innovation_attitude_p95_deg": "innovation p95 (deg)", "battery_v_min": "battery min (V)",
    "link_latency_ms_max": "link round trip max (ms)", "link_loss_max": "link loss max",
    "periods": "control periods", "realtime_factor": "flight time per wall-clock time"}
"""The label of each flight figure in the commands' tables (``replay``, ``simulate``): a figure over part of the
flight says which (tracking: the tracking phase; airborne: settle, tracking and hold), the others cover every
period analysed."""


def cell(v) -> str:
    """A figure as a table cell: 4 significant digits, a tuple's items (per axis, per module) comma-separated,
    "-" for nothing (NaN, None, empty)."""
    if isinstance(v, float):
        return "-" if math.isnan(v) else f"{v:.4g}"
    if isinstance(v, tuple | list):
        return ", ".join(cell(x) for x in v) or "-"
    return str(v) if v not in (None, "") else "-"


STATUS_S = 0.2
"""Status line refresh interval, s."""


def status_text(s, width: int, hint: str = "") -> str:
    """A flight's status line (rich markup; ``s``: a :class:`~groundstation.runtime.flight.Status`) for a terminal
    ``width`` columns wide: flight time out of the plan's, the tracking error, the loop rate, mocap, the largest
    rotor command, battery, late periods; ``hint`` only if it fits."""
    battery = f"  battery {s.battery_v:4.2f} V" if s.battery_v is not None else ""
    rate = f"{s.rate_hz:3.0f} Hz" if s.rate_hz is not None else "--- Hz"
    total = f" / {s.planned_s:.1f}" if s.planned_s is not None else ""
    error = f"  error {s.position_error_m * 1e3:5.1f} mm" if s.position_error_m is not None else ""
    m = s.mocap
    bad = f" rej {m.rejected}" if m.rejected else ""
    bad += f" bad {m.malformed}" if m.malformed else ""
    bad += f" FOREIGN {m.foreign}" if m.foreign else ""
    text = (f"{s.phase:>9} t={s.t:6.1f}{total} s{error}  {rate}  mocap {s.mocap_age * 1e3:4.1f} ms{bad}  motor "
            f"{s.worst_motor:4.0%}{battery}  late {s.overruns}")
    if len(text) + len(hint) <= width:
        text += hint
    return f"[bold]{text[:9]}[/]{text[9:width]}"
