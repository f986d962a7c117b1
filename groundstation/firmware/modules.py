"""The firmware-parameter check for the modules a flight config names (``groundstation params``, ``fly``)."""

from __future__ import annotations

from pathlib import Path

from groundstation.backends.section import BackendSection
from groundstation.errors import ConfigError
from groundstation.firmware.crazyflie_params import check_crazyflie
from groundstation.firmware.params import ParamCheck, load_param_file
from groundstation.firmware.px4_params import check_px4

TOC_CACHE = ".cflib-toc"
"""Directory (in the flight's log directory) keeping cflib's parameter tables of contents between runs."""


def required_params(backend: BackendSection, base: Path, param_file: str | Path | None = None) -> dict[str, float]:
    """What every module must have: ``param_file`` (or the config's ``backend.firmware_params``, relative to
    ``base``), plus for PX4 modules the PWM range the config assumes."""
    if backend.kind == "sim":
        raise ConfigError("the sim backend has no module firmware", key="backend.kind")
    path = param_file if param_file is not None else backend.firmware_params
    if path is None:
        raise ConfigError("no parameter file: set backend.firmware_params or pass one", key="backend.firmware_params")
    wanted = load_param_file(base / path)
    if backend.kind == "mavlink":
        wanted |= {"PWM_MAIN_MIN": float(backend.pwm_min), "PWM_MAIN_MAX": float(backend.pwm_max)}
    return wanted


def check_modules(backend: BackendSection, wanted: dict[str, float], apply: bool = False,
                  cache_dir: Path | None = None, on_module=None) -> list[ParamCheck]:
    """Check (and with ``apply``, set) ``wanted`` on every module of ``backend``, one module after the other;
    ``on_module(i)`` is called before module i (progress)."""
    checks: list[ParamCheck] = []
    for i, link in enumerate(backend.modules):
        if on_module is not None:
            on_module(i)
        if backend.kind == "crazyflie":
            checks += check_crazyflie(link, i, wanted, apply, toc_cache=cache_dir / TOC_CACHE if cache_dir else None)
        else:
            checks += check_px4(link, i, wanted, apply)
    return checks
