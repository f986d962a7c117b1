"""The mocap publisher's stamps, checked against and mapped onto the ground station's own clock.

A pose's stamp is the publisher's wall clock; the ground station times arrivals on its monotonic clock. Their
difference ``arrival - stamp`` is the clock offset plus the transport delay (plus up to one control period, as
arrivals are timed when polled). Its smallest recent value is the offset of the fastest path: mapping a stamp by
it gives the sample's time on the local clock, with the stamps' precise spacing and the local clock's trust.

Samples are taken when the ground station polls, so a sample's arrival is known only to lie between the poll
before and the poll that found it. A stamp is believed only when that interval agrees with the stream's offset
within ``max_skew_s``: a stamp far in the future (forged, a stepped publisher clock) or measured long before it
could have arrived (a capture re-sent later) is rejected whatever it says, so it can never widen a gate that
scales with the time between samples; a poll that came late (a busy ground station, a pause between preflight
and take-off) is not held against the samples it finds. The offset follows slow clock drift (it is the minimum
over a sliding window), never a jump.

A sample found late (in a poll more than ``max_skew_s`` after the one before: the first poll, which finds what
queued since the subscriber was declared, one after a pause) gives only an upper bound of the offset, too large by
up to that poll's interval. While such a sample is the stream's offset, a stamp is not from the future unless it is
beyond that interval too; the first sample found promptly confirms the offset (or, faster, replaces it) and the
bound is ``max_skew_s`` again. Before, a first poll whose burst held a 70-110 ms stall of the publisher took the
offset from the stall's last sample, 0.3 s old by then, and every genuine sample after it was "from the future" for
good (a ground station's preflight, hostile campaign 25: rescued only by a later pause in the polls).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class StampClockSettings:
    max_skew_s: float = 0.05
    """A stamp whose ``arrival - stamp`` differs from the stream's offset by more than this is rejected, s: a
    100 Hz stream polled at 250 Hz jitters by ~5 ms on loopback; a forged or stale stamp is off by much more."""
    window_s: float = 2.0
    """The offset is the least ``arrival - stamp`` of the samples taken in this last stretch of arrival time, s
    (long enough to hold a fast sample, short enough to follow a drift of 100 ppm)."""


class StampClock:
    """Offset of one publisher's clock (its fastest path) against the local clock, from accepted samples."""

    def __init__(self, settings: StampClockSettings | None = None) -> None:
        self.settings = settings or StampClockSettings()
        self._window: deque[tuple[float, float, float]] = deque()
        """(arrival, offset, looseness) of taken samples, offsets increasing from the left: the sliding minimum.
        Looseness: how much after its arrival the sample may have been found (0 when found promptly, within
        ``max_skew_s``), s."""

    @property
    def offset(self) -> float | None:
        """Local time minus publisher time on the fastest recent path, s (None before the first sample)."""
        return self._window[0][1] if self._window else None

    def skew(self, stamp: float, arrival: float) -> float:
        """How much later than the fastest path a sample arriving at ``arrival`` came, s (negative: faster; 0
        before the first)."""
        offset = self.offset
        return 0.0 if offset is None else (arrival - stamp) - offset

    def disagreement(self, stamp: float, earliest: float, latest: float) -> float:
        """How far the stamp is from any arrival time in [``earliest``, ``latest``] on the stream's offset, s
        (positive: measured too long before; negative: from the future; 0: believable at some arrival)."""
        late, early = self.skew(stamp, earliest), self.skew(stamp, latest)
        if late > 0:
            return late
        early += self._window[0][2] if self._window else 0.0  # an offset found late may be that much too large
        return early if early < 0 else 0.0

    def believable(self, stamp: float, earliest: float, latest: float) -> bool:
        return abs(self.disagreement(stamp, earliest, latest)) <= self.settings.max_skew_s

    def local(self, stamp: float) -> float:
        """The stamp on the local clock (the arrival time on the fastest path); needs a first sample."""
        offset = self.offset
        assert offset is not None, "no sample taken yet"
        return stamp + offset

    def take(self, stamp: float, arrival: float, earliest: float | None = None) -> None:
        """A believed sample, found at ``arrival`` (arrived after ``earliest``: the poll before; None: promptly):
        its offset enters the window."""
        offset = arrival - stamp
        found = 0.0 if earliest is None else arrival - earliest
        loose = found if found > self.settings.max_skew_s else 0.0
        w = self._window
        while w and w[-1][1] >= offset:
            w.pop()
        if not loose and any(e[2] for e in w):  # found promptly: the offset is the fastest path's again
            self._window = w = deque((a, o, 0.0) for a, o, _ in w)
        w.append((arrival, offset, loose))
        while w[0][0] < arrival - self.settings.window_s:
            w.popleft()
