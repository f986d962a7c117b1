"""The fault table's registry: each ``tests/faults/test_*.py`` module adds its rows with :func:`fault` and runs
them with its own ``test_fault`` over :func:`rows`; ``test_readme.py`` checks the README counts them, in all and
per kind."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

KINDS = ("Bad input", "Mocap that lies", "Modules", "Links and load", "The state estimate", "Process, log and disk")
"""The README's classes of faults, each a bullet of its reliability section that counts its rows."""


@dataclass(frozen=True)
class Fault:
    id: str
    injected: str
    """The fault, as injected."""
    expected: str
    """The defined outcome."""
    kind: str
    """One of :data:`KINDS`."""
    run: Callable


FAULTS: list[Fault] = []


def fault(injected: str, expected: str, *, kind: str):
    if kind not in KINDS:
        raise ValueError(f"fault kind {kind!r} is not one of {KINDS}")

    def register(fn):
        FAULTS.append(Fault(fn.__name__.removeprefix("f_").replace("_", "-"), injected, expected, kind, fn))
        return fn
    return register


bad_input, lying_mocap, module_fault, link_or_load, estimate_fault, process_fault = (partial(fault, kind=k)
                                                                                     for k in KINDS)
""":func:`fault` for each of :data:`KINDS`."""


def rows(module: str) -> list[Fault]:
    """The rows registered by ``module`` (its ``__name__``)."""
    return [f for f in FAULTS if f.run.__module__ == module]
