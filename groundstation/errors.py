"""One exception root for the package; every error raised on purpose is one of these.

::

    GroundstationError                 exit status 2 at the command line (bad input), unless below BackendError
     ├── ConfigError        a file or value given by the user is malformed (names the file and key path)
     ├── UsageError         a command-line argument or API argument is out of range
     ├── TopologyError      cells, edges or a code do not form a tree of adjacent lattice modules (also ValueError)
     ├── PreflightError     the flight must not start: the assembly cannot hover, the plan leaves the flight volume,
     │                      mocap does not see the body, a module reports a problem (nothing armed)
     ├── SessionError       a Zenoh session will not open (endpoint in use, malformed, unreachable)
     └── BackendError       exit status 1: the modules cannot be reached or refuse (a runtime failure)
          ├── LinkError     a module's link will not open (no dongle, bad address, serial port missing)
          └── ArmingError   a module did not arm (nothing spins)

Foreign exceptions (cflib's, pymavlink's, OSError, Zenoh's) are mapped to these where they are raised, so a caller
catches ours only. Infeasible designs are results carrying a status, never exceptions.
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


class TopologyError(GroundstationError, ValueError):
    """The cells and edges given do not form a tree of adjacent lattice modules."""


class PreflightError(GroundstationError):
    """The flight must not start (the assembly cannot hover, the plan leaves the flight volume, ...)."""


class SessionError(GroundstationError):
    """A Zenoh session could not be opened (endpoint in use, malformed, unreachable)."""


class BackendError(GroundstationError):
    """The modules could not be reached or refused a request: a runtime failure, not bad input."""


class LinkError(BackendError):
    """A module's link could not be opened (no dongle, bad address, no such serial port)."""


class ArmingError(BackendError):
    """A module did not confirm arming; no module is left armed."""
