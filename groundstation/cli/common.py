"""Helpers shared by the commands: stderr console, progress bars, output path checks."""

from __future__ import annotations

import math
import os
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from groundstation.errors import UsageError


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
    return p


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
