"""One exception root for the package.

::

    GroundstationError
     ├── ConfigError        a file or value given by the user is malformed (names the file and key path)
     ├── UsageError         a command-line argument or API argument is out of range
     └── BackendError       the modules cannot be reached or refuse (a link will not open, arming refused)
          └── ArmingError   a module did not arm (nothing spins)

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


class BackendError(GroundstationError):
    """The modules could not be reached or refused a request: a runtime failure, not bad input."""


class ArmingError(BackendError):
    """A module did not confirm arming; no module is left armed."""
