"""The fault table's registry: each ``tests/faults/test_*.py`` module adds its rows with :func:`fault` and runs
them with its own ``test_fault`` over :func:`rows`; ``test_readme.py`` checks the README counts them, in all and
per kind."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial, wraps

from tests.peers import attempted

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
        FAULTS.append(Fault(fn.__name__.removeprefix("f_").replace("_", "-"), injected, expected, kind,
                            _again_if_the_host_stopped(fn)))
        return fn
    return register


bad_input, lying_mocap, module_fault, link_or_load, estimate_fault, process_fault = (partial(fault, kind=k)
                                                                                     for k in KINDS)
""":func:`fault` for each of :data:`KINDS`."""


def _again_if_the_host_stopped(fn: Callable) -> Callable:
    """``fn(cli, tmp_path)`` run by :func:`tests.peers.attempted`: a row whose real-time flight the machine stopped
    (``tests.peers.HostStopped``, raised only where a top-priority probe saw the host hold a CPU off for as long
    as the stall that ended it) is flown again, each attempt in a fresh directory."""
    @wraps(fn)
    def run(cli, tmp_path):
        attempts = itertools.count(1)

        def once():
            n = next(attempts)
            path = tmp_path if n == 1 else tmp_path / f"attempt-{n}"
            path.mkdir(exist_ok=True)
            return fn(cli, path)
        once.__name__ = fn.__name__
        return attempted(once)
    return run


def rows(module: str) -> list[Fault]:
    """The rows registered by ``module`` (its ``__name__``)."""
    return [f for f in FAULTS if f.run.__module__ == module]
