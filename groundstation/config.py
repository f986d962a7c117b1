"""Loading TOML files into validated, frozen schemas; every error names the file and the key path."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import TypeVar

from pydantic import TypeAdapter, ValidationError

from groundstation.errors import ConfigError

T = TypeVar("T")


def read_toml(path: str | Path) -> dict:
    """Parse a TOML file; a missing file or a syntax error is a :class:`ConfigError` naming the file."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError("file not found", path=str(p)) from None
    except IsADirectoryError:
        raise ConfigError("is a directory, expected a TOML file", path=str(p)) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"invalid TOML: {exc}", path=str(p)) from None


def validate(schema: type[T], data: object, *, path: str | None = None, prefix: str = "") -> T:
    """Validate ``data`` against a pydantic dataclass; the first error becomes a :class:`ConfigError`.

    ``prefix`` is prepended to key paths, for sections validated on their own (e.g. ``module``).
    """
    try:
        return TypeAdapter(schema).validate_python(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in _key_path(data, err["loc"]))
        key = ".".join(k for k in (prefix, loc) if k) or None
        msg = err["msg"].removeprefix("Value error, ")  # our validators' own words, without pydantic's label
        if err["type"] == "unexpected_keyword_argument" or err["type"] == "extra_forbidden":
            msg = "unknown key"
        more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
        raise ConfigError(msg + more, path=path, key=key) from None


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
