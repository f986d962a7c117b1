"""Reading input files (TOML, JSON: text only, size-capped) into validated, frozen schemas; every error names the
file and the key path."""

from __future__ import annotations

import json
import os
import stat
import tomllib
from pathlib import Path
from typing import TypeVar

from pydantic import TypeAdapter, ValidationError

from groundstation.errors import ConfigError

T = TypeVar("T")


MAX_TEXT_BYTES = 4 * 2**20
"""Largest text input read (flight, task, module and parameter TOML, assembly JSON), bytes. The largest shipped
is an assembly of 60 modules, 0.14 MB; a file many times that size is not a configuration (a log, a disk image), and
reading stops here, so a device that never ends (``/dev/zero``) costs one bounded read."""


def read_text(path: str | Path) -> str:
    """The text of an input file, read with a size cap: a file larger than :data:`MAX_TEXT_BYTES`, one holding a
    NUL byte (a binary: an MCAP log, an executable, ``/dev/zero``) or not UTF-8 is a :class:`ConfigError` naming
    the file, and never read whole."""
    p = Path(path)
    try:
        # Opened without blocking, to see what it is first: a FIFO without a writer blocked the open for good (a
        # hung `fly`, its first Ctrl-C swallowed; hostile campaign 28).
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
        kind = os.fstat(fd).st_mode
        if stat.S_ISFIFO(kind) or stat.S_ISSOCK(kind):
            os.close(fd)
            raise ConfigError("not a regular file (a pipe or socket), expected a text file", path=str(p))
        os.set_blocking(fd, True)
        with os.fdopen(fd, "rb") as fh:
            data = fh.read(MAX_TEXT_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError("file not found", path=str(p)) from None
    except IsADirectoryError:
        raise ConfigError("is a directory, expected a text file", path=str(p)) from None
    except OSError as exc:
        raise ConfigError(f"cannot be read: {exc.strerror or exc}", path=str(p)) from None
    if b"\0" in data:
        raise ConfigError("not a text file (it holds NUL bytes: a binary file?)", path=str(p))
    if len(data) > MAX_TEXT_BYTES:
        raise ConfigError(f"larger than {MAX_TEXT_BYTES // 2**20} MiB: not a configuration file", path=str(p))
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"not UTF-8 text (byte {exc.start})", path=str(p)) from None


def read_toml(path: str | Path) -> dict:
    """Parse a TOML file (read by :func:`read_text`); a syntax error is a :class:`ConfigError` naming the file."""
    text = read_text(path)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"invalid TOML: {exc}", path=str(path)) from None
    except RecursionError:  # arrays or tables nested thousands deep: the parser recurses per level
        raise ConfigError("invalid TOML: nested deeper than the parser can follow", path=str(path)) from None


def _no_constant(name: str):
    raise ValueError(f"{name} is not a finite number")


def _no_duplicate(pairs: list[tuple[str, object]]) -> dict:
    seen: dict = {}
    for key, value in pairs:
        if key in seen:  # Python's parser keeps the last silently; TOML refuses a duplicate key, so does this
            raise ValueError(f"key {key!r} given twice in one object")
        seen[key] = value
    return seen


def read_json(path: str | Path) -> object:
    """Parse a JSON file (read by :func:`read_text`); a syntax error, a key given twice in one object or a
    non-finite number (JSON has none, but Python's parser takes ``NaN`` and ``Infinity``) is a
    :class:`ConfigError` naming the file."""
    text = read_text(path)
    try:
        return json.loads(text, parse_constant=_no_constant, object_pairs_hook=_no_duplicate)
    except ValueError as exc:
        raise ConfigError(f"invalid JSON: {exc}", path=str(path)) from None
    except RecursionError:
        raise ConfigError("invalid JSON: nested deeper than the parser can follow", path=str(path)) from None


def validate(schema: type[T], data: object, *, path: str | None = None, prefix: str = "") -> T:
    """Validate ``data`` against a pydantic dataclass; the first error becomes a :class:`ConfigError`.

    ``prefix`` is prepended to key paths, for sections validated on their own (e.g. ``module``).
    """
    try:
        value = TypeAdapter(schema).validate_python(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in _key_path(data, err["loc"]))
        key = ".".join(k for k in (prefix, loc) if k) or None
        msg = err["msg"].removeprefix("Value error, ")  # our validators' own words, without pydantic's label
        if err["type"] == "unexpected_keyword_argument" or err["type"] == "extra_forbidden":
            msg = "unknown key"
        more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
        raise ConfigError(msg + more, path=path, key=key) from None
    coerced = _coerced_number(data, value, ())
    if coerced is not None:
        where, raw = coerced
        key = ".".join(k for k in (prefix, ".".join(map(str, where))) if k) or None
        raise ConfigError(f"expected a number, not {'true' if raw is True else 'false' if raw is False else repr(raw)}",
                          path=path, key=key)
    return value


def _coerced_number(raw: object, value: object, where: tuple) -> tuple[tuple, object] | None:
    """The first place (key path, value as written) where a boolean or a string of the input became a number:
    pydantic's lax mode takes ``size = true`` as 1 m and ``rate_hz = "250"`` as 250 Hz (hostile campaign 30)."""
    if isinstance(raw, bool | str):
        return (where, raw) if isinstance(value, int | float) and not isinstance(value, bool) else None
    if isinstance(raw, dict):
        for k, v in raw.items():
            inner = value.get(k) if isinstance(value, dict) else getattr(value, str(k), None)
            if inner is not None and (found := _coerced_number(v, inner, (*where, k))) is not None:
                return found
    elif isinstance(raw, list | tuple) and isinstance(value, list | tuple) and len(raw) == len(value):
        for i, (v, inner) in enumerate(zip(raw, value, strict=True)):
            if (found := _coerced_number(v, inner, (*where, i))) is not None:
                return found
    return None


def _key_path(data: object, loc: tuple) -> list:
    """The user's key path of an error location. pydantic puts the tag of a tagged union (``backend``'s kind) in
    the location although it is no key of the file: an element that is not a key of the input there but one of
    its values (the tag, e.g. ``crazyflie``) is dropped."""
    out, node = [], data
    for part in loc:
        if isinstance(node, dict) and part not in node and part in node.values():
            continue
        out.append(part)
        node = node.get(part) if isinstance(node, dict) else None
    return out


def load(schema: type[T], path: str | Path) -> T:
    """Read a TOML file and validate it against ``schema``."""
    return validate(schema, read_toml(path), path=str(path))
