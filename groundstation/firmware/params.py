"""Firmware parameters every module of an assembly must have before flight: the file, and the check's result.

A parameter file (``firmware_params/crazyflie.toml``, ``firmware_params/px4/module_params.toml``) is TOML with one
table, ``[params]``, of parameter name -> number. ``groundstation params FLIGHT.toml`` reads each module's values
over its link (cflib for Crazyflies, MAVLink for PX4) and compares; with ``--apply`` it writes the wrong ones
first and reads them back. ``fly`` runs the same check (never the writes) in preflight when the flight config
names a file in ``backend.firmware_params``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from pydantic import ConfigDict
from pydantic.dataclasses import dataclass as pydantic_dataclass

from groundstation import config

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


@pydantic_dataclass(frozen=True, config=_STRICT)
class ParamFile:
    params: dict[str, float]
    """Parameter name (``group.name`` for Crazyflies, ``NAME`` for PX4) -> required value."""


def load_param_file(path: str | Path) -> dict[str, float]:
    """The required values in a parameter file; errors name the file and key."""
    return dict(config.load(ParamFile, path).params)


WIRE_RANGES = {"uint8_t": (0, 2**8 - 1), "int8_t": (-2**7, 2**7 - 1), "uint16_t": (0, 2**16 - 1),
               "int16_t": (-2**15, 2**15 - 1), "uint32_t": (0, 2**32 - 1), "int32_t": (-2**31, 2**31 - 1),
               "uint64_t": (0, 2**64 - 1), "int64_t": (-2**63, 2**63 - 1), "float": (-3.4028234663852886e38,
                                                                                      3.4028234663852886e38)}
"""What a parameter of each C type can hold (cflib's type names; PX4's are mapped onto them)."""
FLOAT32_TINY = 1.1754943508222875e-38
"""The smallest normal float32: a float parameter set below it is stored as 0 (or a denormal PX4 flushes)."""


def outside_type(value: float, ctype: str) -> str:
    """Why ``value`` cannot be written to a parameter of C type ``ctype`` ("" if it can, or the type is not one we
    know): out of its range (a uint8 of 256 ended in a cflib traceback) or, for an integer, not whole (written
    rounded, it was then reported as a mismatch)."""
    lo, hi = WIRE_RANGES.get(ctype, (-math.inf, math.inf))
    if not lo <= value <= hi:
        return f"{value:g} is outside what a {ctype} parameter holds ({lo:g} to {hi:g}): fix the file"
    if ctype != "float" and ctype in WIRE_RANGES and value != int(value):
        return f"{value:g} is not a whole number, as a {ctype} parameter must be: fix the file"
    if ctype == "float" and 0.0 < abs(value) < FLOAT32_TINY:  # it would be written as 0 and read back "ok"
        return f"{value:g} is below the smallest float32 ({FLOAT32_TINY:g}): it would be written as 0: fix the file"
    return ""


def held_anyway(why: str, actual: float) -> str:
    """A file's value its parameter's type cannot hold (:func:`outside_type`), said whatever the module holds now:
    a float of 1e-50 "matched" a module at 0, the same file value was "ok" on one module and refused on another."""
    return f"{why} (the module holds {actual:g})"


def matches(actual: float, expected: float) -> bool:
    """Parameters travel as float32 (MAVLink) or their C type: equal at float32 resolution."""
    return math.isclose(actual, expected, rel_tol=1e-6, abs_tol=1e-9)


@dataclass(frozen=True)
class ParamCheck:
    """One parameter of one module."""

    module: int
    """Index in the assembly."""
    link: str
    """The module's link (URI or connection string)."""
    name: str
    expected: float
    actual: float | None
    """Value read back from the module; None if the module does not have the parameter or did not answer."""
    written: bool = False
    """``--apply`` wrote it in this run."""
    stored: bool = False
    """``--apply`` stored it in the module's EEPROM (persistent parameters: it survives a reboot)."""
    note: str = ""
    """Why ``actual`` is None or the parameter could not be set (e.g. read-only)."""
    unreachable: bool = False
    """The module itself did not answer (every parameter of it carries the same note)."""

    @property
    def ok(self) -> bool:
        return self.actual is not None and matches(self.actual, self.expected)


def issues(checks: list[ParamCheck]) -> list[str]:
    """One line per parameter that is not as required, one per module that does not answer (empty: all good)."""
    out = []
    silent: set[int] = set()
    for c in checks:
        if c.ok or c.module in silent:
            continue
        if c.unreachable:
            silent.add(c.module)
            out.append(f"module {c.module} ({c.link}) does not answer: {c.note}")
            continue
        got = c.note or "unknown" if c.actual is None else f"{c.actual:g}"
        extra = f" ({c.note})" if c.actual is not None and c.note else ""
        out.append(f"module {c.module} ({c.link}): {c.name} is {got}, must be {c.expected:g}{extra}")
    return out
