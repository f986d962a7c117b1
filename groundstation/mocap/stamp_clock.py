"""The mocap publisher's stamps, checked against and mapped onto the ground station's own clock.

A pose's stamp is the publisher's wall clock; the ground station times arrivals on its monotonic clock. Their
difference ``arrival - stamp`` is the clock offset plus the transport delay (plus up to one control period, as
arrivals are timed when polled). Its least value is the offset of the fastest path: mapping a stamp by it gives the
sample's time on the local clock, with the stamps' precise spacing and the local clock's trust.

Samples are taken when the ground station polls, so a sample's arrival is known only to lie between the poll
before and the poll that found it. A stamp is believed only when that interval agrees with the stream's offset
within ``max_skew_s``: a stamp far in the future (forged, a stepped publisher clock) or measured long before it
could have arrived (a capture re-sent later) is rejected whatever it says, so it can never widen a gate that
scales with the time between samples; a poll that came late (a busy ground station, a pause between preflight
and take-off) is not held against the samples it finds.

The offset is the least ``arrival - stamp`` of the stream's life, allowed to rise only as fast as two clocks drift
apart (``max_drift``): a path that grows slower, however gradually, is late, never a new offset. Before, the least of
a sliding 2 s window was the offset, and a delay grown by less than 25 ms/s was followed as drift: a man in the
middle delaying the genuine samples (valid MACs) had the estimator fly on poses 30-130 ms old taken for fresh (the
V unstable at 130 ms, blind landings 3-14 m away, 1.2 m/s touchdowns; hostile campaign 27). Nor may it rise by
more than ``max_rise_s`` in all over the stream's life (above its least): a delay grown more slowly than clocks
drift was followed without that bound, 27 ms after a minute and 130 ms after five; with it, at most ``max_rise_s``
of a delay is ever taken for the clocks, the rest is the pose's age, and beyond ``max_skew_s`` more it is late.

A sample found late (in a poll more than ``max_skew_s`` after the one before: the first poll, which finds what
queued since the subscriber was declared, one after a pause) gives only an upper bound of the offset, too large by
up to that poll's interval. While such a sample is the stream's offset, a stamp is not from the future unless it is
beyond that interval too; the first sample found promptly confirms the offset (or, faster, replaces it) and the
bound is ``max_skew_s`` again. Before, a first poll whose burst held a 70-110 ms stall of the publisher took the
offset from the stall's last sample, 0.3 s old by then, and every genuine sample after it was "from the future" for
good (a ground station's preflight, hostile campaign 25: rescued only by a later pause in the polls).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class StampClockSettings:
    max_skew_s: float = 0.05
    """A stamp whose ``arrival - stamp`` differs from the stream's offset by more than this is rejected, s: a
    100 Hz stream polled at 250 Hz jitters by ~5 ms on loopback; a forged or stale stamp is off by much more."""
    max_drift: float = 5e-4
    """How fast the offset may rise (the two clocks drifting apart), s per s: an NTP-disciplined clock slews at most
    500 ppm, free-running crystals differ by ~100 ppm."""
    max_rise_s: float = 0.02
    """How far the offset may rise in all above the least of the stream's life (the clocks drifting apart over a
    flight), s: the most of a slowly grown delay ever taken for drift, not for the poses' age."""


class StampClock:
    """Offset of one publisher's clock (its fastest path) against the local clock, from accepted samples."""

    def __init__(self, settings: StampClockSettings | None = None) -> None:
        self.settings = settings or StampClockSettings()
        self._least: float | None = None
        """The least offset of the stream's life, s: the offset never rises more than ``max_rise_s`` above it."""
        self._floor: tuple[float, float, float] | None = None
        """(offset, arrival, looseness) of the fastest path: the least ``arrival - stamp`` taken, whose arrival
        started the drift allowed since. Looseness: how much after its arrival that sample may have been found (0
        when found promptly, within ``max_skew_s``), s."""

    @property
    def offset(self) -> float | None:
        """Local time minus publisher time on the fastest path, s (None before the first sample)."""
        return self._floor[0] if self._floor is not None else None

    def _offset_at(self, t: float) -> float:
        """The largest offset the clocks' drift allows at local time ``t``, s."""
        offset, since, _ = self._floor
        s = self.settings
        return min(offset + s.max_drift * max(0.0, t - since), self._least + s.max_rise_s)

    def capped(self, t: float) -> bool:
        """Whether the offset allowed at local time ``t`` is held at ``max_rise_s`` above the stream's least (the
        drift allowed since its fastest path would take it further)."""
        if self._floor is None:
            return False
        offset, since, _ = self._floor
        return offset + self.settings.max_drift * max(0.0, t - since) > self._least + self.settings.max_rise_s

    def skew(self, stamp: float, arrival: float) -> float:
        """How much later than the fastest path (drift allowed) a sample arriving at ``arrival`` came, s (negative:
        faster; 0 before the first)."""
        return 0.0 if self._floor is None else (arrival - stamp) - self._offset_at(arrival)

    def disagreement(self, stamp: float, earliest: float, latest: float) -> float:
        """How far the stamp is from any arrival time in [``earliest``, ``latest``] on the stream's offset, s
        (positive: measured too long before; negative: from the future; 0: believable at some arrival)."""
        late = self.skew(stamp, earliest)
        if late > 0:
            return late
        if self._floor is None:
            return 0.0
        # From the future against the fastest path itself: the drift allowed since it was seen is a bound on how
        # much later a sample may come, and measured here it rejected every sample after a silence of 100 s.
        early = (latest - stamp) - self._floor[0] + self._floor[2]  # an offset found late may be that much too large
        return early if early < 0 else 0.0

    def believable(self, stamp: float, earliest: float, latest: float) -> bool:
        return abs(self.disagreement(stamp, earliest, latest)) <= self.settings.max_skew_s

    def local(self, stamp: float) -> float:
        """The stamp on the local clock (the arrival time on the fastest path, drift allowed as the samples are
        judged: mapped by the fastest path alone, clocks drifting 600 ppm apart were 70 ms off after 2 minutes
        with every sample believed); needs a first sample."""
        offset = self.offset
        assert offset is not None, "no sample taken yet"
        return stamp + self._offset_at(stamp + offset)

    def take(self, stamp: float, arrival: float, earliest: float | None = None) -> None:
        """A believed sample, found at ``arrival`` (arrived after ``earliest``: the poll before; None: promptly):
        the fastest path's offset if it is as fast (drift allowed)."""
        offset = arrival - stamp
        found = 0.0 if earliest is None else arrival - earliest
        loose = found if found > self.settings.max_skew_s else 0.0
        floor = self._floor
        if floor is None or offset <= self._offset_at(arrival):
            self._floor = (offset, arrival, loose)
            self._least = offset if self._least is None else min(self._least, offset)
        elif floor[2] and not loose:  # found promptly, no faster: the late-found offset is the fastest path's
            self._floor = (floor[0], floor[1], 0.0)
