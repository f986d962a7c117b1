import math

import numpy as np
import pytest

from groundstation.estimation.gyro_check import GyroAgreement

DT = 0.004
NOISE = 1e-4
"""Gyro noise of the readings below, rad/s (a real gyro's reading changes every time: one repeated to the last
bit is frozen)."""
_rng = np.random.default_rng(0)


def _noisy(rates):
    return rates + _rng.normal(0.0, NOISE, np.shape(rates))


def _run(agreement, rates_at, seconds=0.3, referee=None):
    """Feed ``rates_at(t)`` ((n, 3)), with noise, every 4 ms for ``seconds``; the body rates returned."""
    out = []
    for k in range(round(seconds / DT)):
        t = k * DT
        rates = _noisy(rates_at(t))
        out.append(agreement.rate(t, rates, rates.mean(axis=0), None if referee is None else lambda t=t: referee(t))[0])
    return np.array(out)


def test_noise_and_delays_between_modules_are_no_fault():
    """Two modules turning at up to 5 rad/s (a V's pitch swinging at 4 Hz), one reading 10 ms behind the other,
    with 0.01 rad/s of noise each."""
    rng = np.random.default_rng(1)
    swing = lambda t: np.array([0.0, 5.0 * math.sin(2 * math.pi * 4 * t), 0.3])  # noqa: E731
    agreement = GyroAgreement()
    _run(agreement, lambda t: np.array([swing(t), swing(t - 0.01)]) + rng.normal(0, 0.01, (2, 3)), 2.0)
    assert agreement.fault == "" and agreement.excluded is None
    # 5 rad/s x 2 pi 4 Hz x 10 ms = 1.26 rad/s apart at most (plus noise), within the tolerance (0.5 rad/s, a
    # quarter of the rate and what the rate changed over the last 25 ms)
    assert agreement.worst == pytest.approx(5 * 2 * math.pi * 4 * 0.01, rel=0.05)


@pytest.mark.parametrize("lag", [0.015, 0.020, 0.025])
def test_readings_apart_in_time_are_no_fault(lag):
    """The same swing (4 Hz, 5 rad/s), one module's readings up to 25 ms behind the other's (Crazyflie links 12-20
    ms apart): apart by up to 3 rad/s where the rate crosses zero, within what the rate changed over 25 ms."""
    swing = lambda t: np.array([0.0, 5.0 * math.sin(2 * math.pi * 4 * t), 0.3])  # noqa: E731
    agreement = GyroAgreement()
    _run(agreement, lambda t: np.array([swing(t), swing(t - lag)]), 2.0)
    assert agreement.fault == "" and agreement.worst > 0.9 * 5 * 2 * math.pi * 4 * lag


def test_a_stalled_loop_is_not_a_disagreement_that_lasted():
    """One reading 0.2 rad/s beyond the tolerance, then a 200 ms gap (a loop stall), then agreement: 0.2 rad/s x
    10 ms at most, not x 200 ms (2.3 deg, a fault)."""
    agreement = GyroAgreement()
    for t, second in ((0.0, 0.0), (0.004, 0.8), (0.204, 0.8), (0.208, 0.0)):
        agreement.rate(t, _noisy(np.array([[0.0, 0.0, 0.0], [0.0, second, 0.0]])), np.zeros(3))
    assert agreement.fault == ""


def test_a_gyro_stuck_at_full_scale_is_left_out_in_the_period_it_shows():
    """Module 1 reads 2000 deg/s about x from 0.1 s: the disagreement beyond the tolerance, over one period, is
    far more than the 1.5 deg budget; the poses' rate (still) picks module 1, and the body rate is module 0's."""
    agreement = GyroAgreement()
    good = np.array([0.0, 0.3, 0.0])
    full = lambda t: np.array([good, good if t < 0.1 else np.radians([2000.0, 0.0, 0.0])])  # noqa: E731
    rates = _run(agreement, full, referee=lambda t: good + 0.05)
    k = round(0.1 / DT)  # the first period with the failed reading
    assert agreement.excluded == 1 and agreement.fault.startswith("module 1's gyro disagrees with the other's by "
                                                                  "2000 deg/s for 0 ms")
    np.testing.assert_allclose(rates[k:], np.tile(good, (len(rates) - k, 1)), atol=5 * NOISE)  # never flown on


def test_a_touchdown_kick_read_by_one_module_is_no_fault_but_a_nan_still_is():
    """A touchdown: module 1 reads the contact's kick (-8 rad/s about y, one reading; module 0 samples a few ms off
    and misses it). In the air that reading is a fault in the period it shows (the kick of a CI run's touchdown,
    248 deg/s apart); touching the ground it is not judged. A reading that is not a number still is a fault."""
    kick = lambda t: np.array([[0.0, 0.1, 0.0], [0.0, -8.0 if 0.1 <= t < 0.11 else 0.1, 0.0]])  # noqa: E731
    rng = np.random.default_rng(2)
    for touching, fault in ((False, "the gyros of modules 0 and 1 disagree by 464 deg/s"), (True, "")):
        agreement = GyroAgreement()
        for k in range(round(0.3 / DT)):
            rates = kick(k * DT) + rng.normal(0.0, NOISE, (2, 3))
            agreement.rate(k * DT, rates, rates.mean(axis=0), touching=touching)
        assert agreement.fault.startswith(fault) and (agreement.fault == "") == (not fault)
    agreement.rate(0.3, np.array([[0.0, 0.1, 0.0], [math.nan, 0.1, 0.0]]), np.zeros(3), touching=True)
    assert agreement.fault == "module 1's gyro is not a number: a failed IMU, left out of the body rate"


def test_a_gyro_stuck_while_the_body_turns_is_named_once_its_error_adds_up():
    """Module 1 holds 0 from 0.1 s while the body turns at 60 deg/s: 31 deg/s over the tolerance, 1.5 deg of
    attitude after ~50 ms."""
    agreement = GyroAgreement()
    turn = np.radians([0.0, 60.0, 0.0])
    held = lambda t: np.array([turn, turn if t < 0.1 else np.zeros(3)])  # noqa: E731
    rates = _run(agreement, held, referee=lambda t: turn)
    assert agreement.excluded == 1
    lasted = float(agreement.fault.split(" for ")[1].split(" ms")[0])
    assert 40 <= lasted <= 60, agreement.fault
    np.testing.assert_allclose(rates[-1], turn, atol=5 * NOISE)


def test_two_that_disagree_without_poses_are_named_and_both_stay_in():
    agreement = GyroAgreement()
    turn = np.radians([0.0, 60.0, 0.0])
    held = lambda t: np.array([turn, turn if t < 0.1 else np.zeros(3)])  # noqa: E731
    rates = _run(agreement, held)
    assert agreement.fault.startswith("the gyros of modules 0 and 1 disagree by 60 deg/s for ")
    assert agreement.fault.endswith("no poses to tell which") and agreement.excluded is None
    np.testing.assert_allclose(rates[-1], turn / 2, atol=5 * NOISE)  # the mean: neither can be told wrong


@pytest.mark.parametrize("bad", [np.array([0.0, 0.0, 0.0]), np.array([np.nan, 0.0, 0.0])])
def test_of_three_the_odd_one_is_left_out(bad):
    agreement = GyroAgreement()
    good = np.array([0.2, -1.0, 0.1])
    three = lambda t: np.array([good, good, good if t < 0.1 else bad])  # noqa: E731
    rates = _run(agreement, three)
    assert agreement.excluded == 2
    expected = "is not a number" if np.isnan(bad).any() else "disagrees with the others' by "
    assert agreement.fault.startswith(f"module 2's gyro {expected}"), agreement.fault
    np.testing.assert_allclose(rates[-1], good, atol=5 * NOISE)  # the body rate from the other two


def test_a_short_glitch_is_forgotten():
    """0.64 rad/s beyond the tolerance for 12 ms: 0.44 deg, under the budget, then agreement again."""
    agreement = GyroAgreement()
    glitch = lambda t: np.array([[0.0, 0.0, 0.0], [0.0, 2.0 if 0.1 <= t < 0.112 else 0.0, 0.0]])  # noqa: E731
    _run(agreement, glitch)
    assert agreement.fault == "" and math.degrees(agreement.worst) == pytest.approx(114.6, abs=0.1)


def _swing(t):
    """A V's pitch swinging at 4 Hz, 5 rad/s."""
    return np.array([0.0, 5.0 * math.sin(2 * math.pi * 4 * t), 0.3])


def _held_reading(gap_start, gap):
    """Module 1's reading held from ``gap_start`` for ``gap`` s (its packets late: the loop hears none), with
    each module's age; module 0 fresh every period."""
    def at(t):
        held = gap_start <= t < gap_start + gap
        t1 = gap_start if held else t
        return np.array([_swing(t), _swing(t1)]), np.array([0.002, 0.002 + (t - t1)])
    return at


def test_a_reading_late_by_packets_in_a_turn_is_not_judged_and_not_flown_on():
    """Module 1's packets 60 ms late where the swing's rate changes fastest (the suite beside a CPU hog: "module
    1's gyro disagrees with the other's by 111 deg/s for 32 ms"): judged as it was, a fault; with each reading's
    age, the stale one is left out (the rate is module 0's, with module 0's age) and nothing is judged."""
    reading = _held_reading(gap_start=0.25, gap=0.06)
    blind, aware = GyroAgreement(), GyroAgreement()
    for k in range(round(0.6 / DT)):
        t = k * DT
        rates, ages = reading(t)
        blind.rate(t, rates, rates.mean(axis=0))
        rate, age = aware.rate(t, rates, rates.mean(axis=0), ages=ages, age=float(ages.max()), stale_s=0.03)
        if ages[1] > 0.03:
            np.testing.assert_array_equal(rate, rates[0])
            assert age == pytest.approx(0.002)
        else:
            np.testing.assert_allclose(rate, rates.mean(axis=0))
    assert "module" in blind.fault, "the case must be one the check without ages gets wrong"
    assert aware.fault == "" and aware.excluded is None


def test_a_stuck_gyro_whose_packets_arrive_is_still_found():
    """Ages do not hide a failed gyro: module 1 reads 2000 deg/s from 0.1 s with fresh packets."""
    agreement = GyroAgreement()
    good = np.array([0.0, 0.3, 0.0])
    for k in range(round(0.2 / DT)):
        t = k * DT
        rates = np.array([_noisy(good), _noisy(good) if t < 0.1 else np.radians([2000.0, 0.0, 0.0])])
        agreement.rate(t, rates, rates.mean(axis=0), lambda: good, np.array([0.003, 0.004]), 0.004, 0.03)
    assert agreement.excluded == 1 and "module 1" in agreement.fault


def test_a_module_taken_out_of_the_flight_leaves_the_body_rate():
    """An isolated module (infinite age: it sends nothing more) with its last reading frozen: the rate is the
    others', with their age."""
    agreement = GyroAgreement()
    rates = np.array([[0.0, 0.5, 0.0], [0.0, 0.4, 0.0], [0.0, -3.0, 0.0]])
    rate, age = agreement.rate(0.0, rates, rates.mean(axis=0), ages=np.array([0.004, 0.006, np.inf]), age=np.inf,
                               stale_s=0.03)
    np.testing.assert_allclose(rate, [0.0, 0.45, 0.0])
    assert age == pytest.approx(0.006)


def test_with_one_module_out_of_the_flight_the_others_stay_judged():
    """Module 2 isolated (infinite age, its last reading frozen), then module 1's gyro stuck at 2000 deg/s: the
    fault latches on module 1 (fresh modules judged against each other; it was not while any module was stale),
    and the body rate is module 0's."""
    agreement = GyroAgreement()
    good = np.array([0.0, 0.3, 0.0])
    ages = np.array([0.004, 0.004, np.inf])
    for k in range(round(0.2 / DT)):
        t = k * DT
        stuck = good if t < 0.1 else np.radians([2000.0, 0.0, 0.0])
        rates = np.array([_noisy(good), _noisy(stuck), [0.0, -3.0, 0.0]])
        rate, _ = agreement.rate(t, rates, rates.mean(axis=0), lambda: good, ages, np.inf, 0.03)
    assert agreement.excluded == 1 and agreement.fault.startswith("module 1's gyro disagrees with the other's")
    np.testing.assert_allclose(rate, good, atol=5 * NOISE)


@pytest.mark.parametrize("ages", [[np.nan, 0.004], [0.004, np.nan]])
def test_an_age_that_is_not_a_number_is_stale_wherever_it_is(ages):
    agreement = GyroAgreement()
    rates = np.array([[0.0, 0.5, 0.0], [0.0, 0.1, 0.0]])
    rate, age = agreement.rate(0.0, rates, rates.mean(axis=0), ages=np.array(ages), age=np.nan, stale_s=0.03)
    fresh = 1 if np.isnan(ages[0]) else 0
    np.testing.assert_allclose(rate, rates[fresh])
    assert age == pytest.approx(0.004)


def test_a_reading_repeated_to_the_last_bit_is_frozen_and_left_out():
    """Module 1's packets keep coming (fresh) but repeat one reading from 0.1 s: frozen after 40 ms, left out;
    module 0's readings, which change, are the body rate. A reading held between packets (2-3 periods) is not."""
    agreement = GyroAgreement()
    good = np.array([0.0, 0.3, 0.0])
    stuck = _noisy(good)
    module1 = _noisy(good)
    for k in range(round(0.3 / DT)):
        t = k * DT
        module1 = stuck if t >= 0.1 else _noisy(good) if k % 3 == 0 else module1  # a packet every third period
        rates = np.array([_noisy(good), module1])
        rate, _ = agreement.rate(t, rates, rates.mean(axis=0), ages=np.array([0.002, 0.004]), age=0.004,
                                 stale_s=0.03)
        if t < 0.1:
            assert agreement.fault == ""
    assert agreement.excluded == 1 and agreement.lost_since is None
    stuck_deg = ", ".join(f"{x:.1f}" for x in np.degrees(stuck))  # its noise may round to -0.0
    assert agreement.fault.startswith(f"module 1's gyro has read ({stuck_deg}) deg/s to the last bit for "), \
        agreement.fault
    assert stuck_deg.replace("-0.0", "0.0") == "0.0, 17.2, 0.0"
    lasted = float(agreement.fault.split(" for ")[1].split(" ms")[0])
    assert 40 <= lasted <= 44
    np.testing.assert_allclose(rate, good, atol=5 * NOISE)


@pytest.mark.parametrize("value", [np.nan, 0.0, 1.0])
@pytest.mark.parametrize("n", [1, 2, 3])
def test_every_gyro_failed_alike_gives_no_rate_and_blames_no_module(value, n):
    """Every module's gyro NaN, or stuck at one value (they agree with each other), from 0.1 to 0.2 s: no module
    is blamed or left out; the rate is NaN, as old as the last usable reading (the start of a freeze); after,
    the readings are flown on again."""
    agreement = GyroAgreement()
    good = np.array([0.1, -0.2, 0.05])
    lost = []
    for k in range(round(0.3 / DT)):
        t = k * DT
        rates = np.full((n, 3), value) if 0.1 <= t < 0.2 else _noisy(np.tile(good, (n, 1)))
        rate, age = agreement.rate(t, rates, rates.mean(axis=0), lambda: good)
        if np.isnan(rate).any():
            lost.append((t, age, agreement.lost_since))
        elif t >= 0.2:
            np.testing.assert_allclose(rate, good, atol=5 * NOISE)
    whose = "the gyro" if n == 1 else "every module's gyro"
    assert agreement.fault.startswith(whose) and agreement.fault.endswith("no body rate, the attitude from the "
                                                                          "poses alone"), agreement.fault
    assert agreement.excluded is None
    first_lost = 0.1 if np.isnan(value) else 0.1 + 0.04  # frozen: seen once it has lasted 40 ms
    assert lost[0][0] == pytest.approx(first_lost, abs=DT + 1e-9) and lost[-1][0] == pytest.approx(0.2 - DT)
    for t, age, since in lost:  # the last usable reading: the one before the NaN, or before the freeze
        assert since == pytest.approx(0.1 - DT if np.isnan(value) else 0.1, abs=1e-9)
        assert age == pytest.approx(t - since)
