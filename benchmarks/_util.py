"""Shared benchmark plumbing: pin to one core, medians, table printing."""

from __future__ import annotations

import os
import statistics

from rich.console import Console
from rich.table import Table


def pin_one_core() -> int:
    """Run this process on a single CPU (the issues' targets are single-core); returns the core used."""
    core = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    return core


def median(values) -> float:
    return float(statistics.median(values))


def print_table(title: str, columns: list[str], rows: list[list]) -> None:
    table = Table(title=title)
    for c in columns:
        table.add_column(c, justify="right")
    for r in rows:
        table.add_row(*(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r))
    Console(width=max(140, 14 * len(columns))).print(table)
