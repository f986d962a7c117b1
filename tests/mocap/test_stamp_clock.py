"""The stamp clock's bounds when the offset was found late (the first poll, one after a pause), on made-up times."""

from groundstation.mocap.stamp_clock import StampClock

SKEW = StampClock().settings.max_skew_s


def test_an_offset_found_late_is_an_upper_bound_until_a_sample_is_found_promptly():
    """Found 0.4 s after the poll before, a sample 0.3 s old gave an offset 0.3 s too large: a stamp 0.3 s newer
    is no sign of the future, but one beyond the 0.4 s is. Once a sample found promptly is taken, the bound is
    ``max_skew_s`` again."""
    clock = StampClock()
    clock.take(100.0, 10.4, 10.0)  # found at 10.4, arrived after 10.0: offset -89.6, at most 0.4 s too large
    assert clock.believable(100.3, 10.4, 10.404)  # 0.3 s "from the future" by that offset
    assert not clock.believable(100.5, 10.4, 10.404)  # beyond what the late poll explains
    clock.take(100.3, 10.404, 10.4)  # found promptly: the offset is -89.896 now
    assert clock.offset == 10.404 - 100.3
    assert clock.believable(100.31, 10.408, 10.412)
    assert not clock.believable(100.31 + 2 * SKEW, 10.408, 10.412)


def test_a_prompt_sample_that_does_not_lower_the_offset_still_ends_the_leniency():
    clock = StampClock()
    clock.take(100.0, 10.4, 10.0)
    clock.take(100.001, 10.404, 10.4)  # a slower path: the late-found offset stays, confirmed within the skew
    assert clock.offset == 10.4 - 100.0
    assert not clock.believable(100.01 + 2 * SKEW, 10.408, 10.412)


def test_prompt_samples_keep_the_plain_bound():
    """Polled every 4 ms, nothing changes: a stamp more than ``max_skew_s`` ahead of the offset is from the future
    and one measured that long before its earliest arrival is late."""
    clock = StampClock()
    for k in range(10):
        clock.take(100.0 + 0.01 * k, 10.0 + 0.01 * k + 0.002, 10.0 + 0.01 * k - 0.002)
    t = 10.1
    assert clock.believable(100.1, t - 0.004, t)
    assert clock.disagreement(100.1 + SKEW + 0.01, t - 0.004, t) < -SKEW
    assert clock.disagreement(100.1 - SKEW - 0.02, t - 0.004, t) > SKEW


def _fed(clock: StampClock, seconds: float, delay, rate: float = 100.0, t0: float = 10.0) -> list[float]:
    """Samples of a ``rate`` Hz stream for ``seconds``, each arriving ``delay(t)`` s after its stamp (clocks equal)
    and polled promptly, taken when believed; the disagreement of each, s."""
    seen = []
    for k in range(int(seconds * rate)):
        stamp = 100.0 + k / rate
        arrival = t0 + k / rate + delay(k / rate)
        d = clock.disagreement(stamp, arrival - 0.004, arrival)
        seen.append(d)
        if abs(d) <= SKEW:
            clock.take(stamp, arrival, arrival - 0.004)
    return seen


def test_a_delay_that_grows_slowly_is_late_not_a_new_offset():
    """A man in the middle delaying the genuine samples by 24 ms more each second: before, a 2 s window's least
    offset followed it as drift and no sample was ever late (the estimator flew on poses 130 ms old taken for fresh:
    campaign 27). Now the offset rises at most ``max_drift``: late once the delay passes ``max_skew_s``."""
    clock = StampClock()
    seen = _fed(clock, 6.0, lambda t: 0.005 + 0.024 * max(0.0, t - 1.0))
    late = [k / 100.0 for k, d in enumerate(seen) if d > SKEW]
    assert late and 1.0 + SKEW / 0.024 - 0.1 < late[0] < 1.0 + SKEW / 0.024 + 0.3  # at ~50 ms of added delay
    assert all(d > SKEW for d in seen[int(late[0] * 100):])  # late from then on, never re-based


def test_clocks_drifting_apart_stay_believable():
    """The publisher's clock slower by 100 ppm (free-running crystals) for 3 minutes: 18 ms of drift, within
    ``max_rise_s``: every sample believed, and the offset follows (a stamp maps within a few ms of its arrival)."""
    clock = StampClock()
    seen = _fed(clock, 180.0, lambda t: 0.005 + 1e-4 * t)
    assert max(abs(d) for d in seen) <= SKEW and not clock.capped(10.0 + 180.0)
    stamp = 100.0 + 179.99
    assert abs(clock.local(stamp) - (10.0 + 179.99 + 0.005 + 1e-4 * 179.99)) < 0.005


def test_a_delay_grown_more_slowly_than_drift_is_followed_only_max_rise_s():
    """A man in the middle adding 0.4 ms each second (slower than the drift allowed): before, followed for good
    (130 ms after 5 minutes, the poses taken for fresh). Now the offset rises at most ``max_rise_s`` in all: a pose
    is never mapped more than that after the time it left the publisher on the stream's first path, and once the
    delay is ``max_skew_s`` beyond that, the samples are late from then on."""
    clock = StampClock()
    rise, late, mapped_after = clock.settings.max_rise_s, [], []
    for k in range(20000):  # 200 s at 100 Hz, polled promptly
        stamp, sent = 100.0 + k / 100.0, 10.0 + k / 100.0
        arrival = sent + 0.005 + 4e-4 * k / 100.0
        d = clock.disagreement(stamp, arrival - 0.004, arrival)
        if abs(d) <= SKEW:
            clock.take(stamp, arrival, arrival - 0.004)
            mapped_after.append(clock.local(stamp) - (sent + 0.005))  # how much fresher than it is it looks
        elif d > SKEW:
            late.append(k / 100.0)
            assert clock.capped(arrival)  # the rejection says the offset is at its bound
        else:
            assert not clock.capped(arrival) or k / 100.0 > rise / 4e-4 - 1.0
    assert max(mapped_after) <= rise + 1e-9
    expected = (rise + SKEW + 0.004) / 4e-4  # 185 s (it may have arrived at the poll before: 4 ms)
    assert late and expected - 1.0 < late[0] < expected + 1.0
    assert len(late) == 20000 - int(late[0] * 100)  # late from then on, never re-based


def test_a_silence_does_not_make_the_same_path_from_the_future():
    """The drift allowed since the fastest path was seen bounds how much later a sample may come, not how much
    earlier: measured on it, every sample after 101 s of silence was "from the future" (review)."""
    clock = StampClock()
    _fed(clock, 1.0, lambda t: 0.005)
    stamp, arrival = 100.0 + 1.0 + 300.0, 10.0 + 1.0 + 300.0 + 0.005
    assert abs(clock.disagreement(stamp, arrival - 0.004, arrival)) < 1e-9  # before: -0.15 s, rejected


def test_clocks_drifting_faster_than_allowed_are_late_before_they_are_mis_timed():
    """600 ppm (beyond the 500 allowed): the stamps mapped as they are judged, so a sample is either within
    ``max_skew_s`` of its time or rejected; mapped by the fastest path alone, they were 70 ms off after 2 minutes,
    every one believed (review)."""
    clock = StampClock()
    seen = _fed(clock, 120.0, lambda t: 0.005 + 6e-4 * t)
    for k in range(0, 12000, 500):
        if abs(seen[k]) <= SKEW:
            stamp = 100.0 + k / 100.0
            assert abs(clock.local(stamp) - (10.0 + k / 100.0 + 0.005 + 6e-4 * k / 100.0)) <= SKEW
