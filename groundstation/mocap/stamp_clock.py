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
        self._window: deque[tuple[float, float]] = deque()
        """(arrival, offset) of taken samples, offsets increasing from the left: the sliding minimum."""

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
        return late if late > 0 else early if early < 0 else 0.0

    def believable(self, stamp: float, earliest: float, latest: float) -> bool:
        return abs(self.disagreement(stamp, earliest, latest)) <= self.settings.max_skew_s

    def local(self, stamp: float) -> float:
        """The stamp on the local clock (the arrival time on the fastest path); needs a first sample."""
        offset = self.offset
        assert offset is not None, "no sample taken yet"
        return stamp + offset

    def take(self, stamp: float, arrival: float) -> None:
        """A believed sample: its offset enters the window."""
        offset = arrival - stamp
        w = self._window
        while w and w[-1][1] >= offset:
            w.pop()
        w.append((arrival, offset))
        while w[0][0] < arrival - self.settings.window_s:
            w.popleft()
