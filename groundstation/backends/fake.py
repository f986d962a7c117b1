"""A backend that records what it is told: for tests of the flight logic and for the conformance suite."""

from __future__ import annotations

import numpy as np

from groundstation.backends.base import BackendBase, PreflightReport, Telemetry, applied_command


class FakeBackend(BackendBase):
    """Records every command; enforces the same rules as a real backend (bounds, arming, stop)."""

    def __init__(self, n_modules: int, u_max: float) -> None:
        self.u_max = u_max
        self.commands: list[np.ndarray] = []
        """Every command as applied (after arming and bounds), in order."""
        self.stops = 0
        self.disarms = 0
        self.link_ok = True
        self._connected = False
        self._armed = False
        self._u = np.zeros(4 * n_modules)

    def connect(self) -> None:
        self._connected = True

    def preflight(self) -> PreflightReport:
        return PreflightReport(self._connected, () if self._connected else ("not connected",))

    def arm(self) -> None:
        self._armed = True

    def send(self, u: np.ndarray) -> None:
        self._u = applied_command(u, self._u.size, self._armed, self.u_max)
        self.commands.append(self._u.copy())

    def telemetry(self) -> Telemetry:
        return Telemetry(stamp=float(len(self.commands)), link_ok=self._connected and self.link_ok,
                         motors=self._u.copy())

    def disarm(self) -> None:
        self._armed = False
        self._u = np.zeros_like(self._u)
        self.disarms += 1

    def emergency_stop(self) -> None:
        self._armed = False
        self._u = np.zeros_like(self._u)
        self.stops += 1

    def close(self) -> None:
        self._connected = False

