"""The firmware-parameter check for the modules a flight config names (``groundstation params``, ``fly``)."""

from __future__ import annotations

import queue
import threading
from pathlib import Path

from groundstation.backend_kinds import backend_kind, load
from groundstation.backends.section import BackendSection
from groundstation.errors import ConfigError
from groundstation.firmware.params import ParamCheck, load_param_file

PARALLEL = 16
"""Modules checked at once (each check holds a connection and its threads)."""


def required_params(backend: BackendSection, base: Path, param_file: str | Path | None = None,
                    config: str | Path | None = None) -> dict[str, float]:
    """What every module must have: ``param_file`` (or the config's ``backend.firmware_params``, relative to
    ``base``), plus what the config itself implies (PX4 modules: the PWM range it assumes). ``config``: the flight
    config's file, named in its errors."""
    kind = backend_kind(backend.kind)
    source = None if config is None else str(config)
    if kind.check_params is None:
        raise ConfigError(f"the {kind.name} backend has no module firmware", path=source, key="backend.kind")
    path = param_file if param_file is not None else backend.firmware_params
    if path is None:
        raise ConfigError("no parameter file: set backend.firmware_params or pass one", path=source,
                          key="backend.firmware_params")
    wanted = load_param_file(base / path)
    if kind.implied_params is not None:
        wanted |= load(kind.implied_params)(backend)
    return wanted


def check_modules(backend: BackendSection, wanted: dict[str, float], apply: bool = False,
                  cache_dir: Path | None = None, on_module=None) -> list[ParamCheck]:
    """Check (and with ``apply``, set) ``wanted`` on every module of ``backend``, up to ``PARALLEL`` modules at
    once: a module that does not answer costs its wait once, not once per module (two modules answering
    everything but their parameters kept `params` 51 s). ``on_module(done)`` is called as each module's check
    ends (progress). ``cache_dir`` keeps what a kind may reuse between runs (Crazyflie parameter tables of
    contents). The checks come back in module order; a check that raised raises here."""
    check = load(backend_kind(backend.kind).check_params)
    links = backend.modules
    results: list = [None] * len(links)
    ended: queue.SimpleQueue[int] = queue.SimpleQueue()
    slots = threading.Semaphore(PARALLEL)

    def run(i: int, link: str) -> None:
        with slots:
            try:
                results[i] = check(link, i, wanted, apply, cache_dir)
            except BaseException as exc:  # handed to the caller's thread
                results[i] = exc
        ended.put(i)

    # Daemon threads: an interrupted check (Ctrl-C) returns at once; the checks under way end on their own bounded
    # waits, and the process does not wait for them on its way out (a pool's threads are joined at exit: 5 s).
    for i, link in enumerate(links):
        threading.Thread(target=run, args=(i, link), name=f"module-params-{i}", daemon=True).start()
    for done in range(1, len(links) + 1):
        ended.get()
        if on_module is not None:
            on_module(done)
    for r in results:
        if isinstance(r, BaseException):
            raise r
    return [c for r in results for c in r]
