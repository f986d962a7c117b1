"""One exception root for the package.

::

    GroundstationError
     ├── ConfigError        a file or value given by the user is malformed (names the file and key path)
     └── UsageError         a command-line argument or API argument is out of range

Infeasible designs are results carrying a status, never exceptions.
"""

from __future__ import annotations


class GroundstationError(Exception):
    """Root of every error raised on purpose by this package."""


class ConfigError(GroundstationError):
    """A configuration file or value is invalid.

    The message always names the file (when there is one) and the offending key path, e.g.
    ``configs/modules/x.toml: c_f: Input should be greater than 0``.
    """

    def __init__(self, message: str, *, path: str | None = None, key: str | None = None) -> None:
        self.path = path
        self.key = key
        prefix = ": ".join(p for p in (path, key) if p)
        super().__init__(f"{prefix}: {message}" if prefix else message)


class UsageError(GroundstationError):
    """An argument is outside its documented range (e.g. ``n < 1``, an unknown symmetry group)."""
