"""Helpers shared by the commands: number types of the options, stderr console, progress bars, output path checks."""

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
