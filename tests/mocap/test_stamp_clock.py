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
