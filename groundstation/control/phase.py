"""The phases of a flight, in the order a nominal flight passes through them (``FlightPlan`` times the airborne
ones; the flight's state machine adds the rest, see :mod:`groundstation.runtime.flight`)."""

from __future__ import annotations

from enum import StrEnum


class Phase(StrEnum):
    """A ``str``: logs and JSON carry the value (``"track"``)."""

    PREFLIGHT = "preflight"
    TAKEOFF = "takeoff"
    SETTLE = "settle"
    TRACK = "track"
    HOLD = "hold"
    LANDING = "landing"
    DONE = "done"
    """Landed; motors off, the modules disarmed."""
    EMERGENCY = "emergency"
    """Motors stopped by the emergency stop."""
    ABORTED = "aborted"
    """Ended before take-off: never armed, or armed while the operator asked to stop and disarmed at once."""

    @property
    def airborne(self) -> bool:
        """Takeoff to hold: the phases a landing may interrupt."""
        return self in (Phase.TAKEOFF, Phase.SETTLE, Phase.TRACK, Phase.HOLD)

    @property
    def final(self) -> bool:
        return self in (Phase.DONE, Phase.EMERGENCY, Phase.ABORTED)
