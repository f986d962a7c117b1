"""The fault table's registry: each ``tests/faults/test_*.py`` module adds its rows with :func:`fault` and runs
them with its own ``test_fault`` over :func:`rows`; ``test_readme.py`` checks the README counts them all."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Fault:
    id: str
    injected: str
    """The fault, as injected."""
    expected: str
    """The defined outcome."""
    run: Callable


FAULTS: list[Fault] = []


def fault(injected: str, expected: str):
    def register(fn):
        FAULTS.append(Fault(fn.__name__.removeprefix("f_").replace("_", "-"), injected, expected, fn))
        return fn
    return register


def rows(module: str) -> list[Fault]:
    """The rows registered by ``module`` (its ``__name__``)."""
    return [f for f in FAULTS if f.run.__module__ == module]
