"""The firmware-parameter check for the modules a flight config names (``groundstation params``, ``fly``)."""

from __future__ import annotations

from pathlib import Path

from groundstation.backend_kinds import backend_kind, load
from groundstation.backends.section import BackendSection
from groundstation.errors import ConfigError
from groundstation.firmware.params import ParamCheck, load_param_file


def required_params(backend: BackendSection, base: Path, param_file: str | Path | None = None) -> dict[str, float]:
    """What every module must have: ``param_file`` (or the config's ``backend.firmware_params``, relative to
    ``base``), plus what the config itself implies (PX4 modules: the PWM range it assumes)."""
    kind = backend_kind(backend.kind)
    if kind.check_params is None:
        raise ConfigError(f"the {kind.name} backend has no module firmware", key="backend.kind")
    path = param_file if param_file is not None else backend.firmware_params
    if path is None:
        raise ConfigError("no parameter file: set backend.firmware_params or pass one", key="backend.firmware_params")
    wanted = load_param_file(base / path)
    if kind.implied_params is not None:
        wanted |= load(kind.implied_params)(backend)
    return wanted


def check_modules(backend: BackendSection, wanted: dict[str, float], apply: bool = False,
                  cache_dir: Path | None = None, on_module=None) -> list[ParamCheck]:
    """Check (and with ``apply``, set) ``wanted`` on every module of ``backend``, one module after the other;
    ``on_module(i)`` is called before module i (progress). ``cache_dir`` keeps what a kind may reuse between runs
    (Crazyflie parameter tables of contents)."""
    check = load(backend_kind(backend.kind).check_params)
    checks: list[ParamCheck] = []
    for i, link in enumerate(backend.modules):
        if on_module is not None:
            on_module(i)
        checks += check(link, i, wanted, apply, cache_dir)
    return checks
