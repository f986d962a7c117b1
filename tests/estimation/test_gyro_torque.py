"""The gyros against the commanded torque, on a body written here: its rate follows ``J^-1 tau`` through a
first-order motor lag, the torque a noisy attitude loop's."""

import math

import numpy as np
import pytest

from groundstation.estimation.gyro_torque import TorqueAgreement

INERTIA = np.diag([0.004, 0.002, 0.005])
"""kg m^2 (about the toy V's)."""
DT = 1 / 250


def _flown(seconds: float, sign: float, kick_nm: float = 0.03, gain: float = 0.05, lag_s: float = 0.03,
           seed: int = 0) -> TorqueAgreement:
    """An attitude loop (torque ``-gain`` times the rate it reads, plus random kicks of ``kick_nm`` std) on a body
    whose motors lag ``lag_s``; its gyros read ``sign`` times the rate. Returns the referee fed with it."""
    rng = np.random.default_rng(seed)
    check = TorqueAgreement(INERTIA)
    rate, applied = np.zeros(3), np.zeros(3)
    inverse = np.linalg.inv(INERTIA)
    for k in range(int(round(seconds / DT))):
        read = sign * rate
        check.add(k * DT, read)
        torque = -gain * read + rng.normal(0.0, kick_nm, 3)
        check.command(torque)
        applied += (torque - applied) * DT / lag_s
        rate = rate + inverse @ applied * DT
    return check


def test_gyros_that_follow_the_torque_are_not_against_it():
    check = _flown(1.0, +1.0, kick_nm=0.08)
    slope, excitation = check.slope()
    assert 0.3 < slope < 1.2 and excitation > 2.0  # the motors' lag takes some of it
    assert check.against() == ""


def test_flipped_gyros_turn_against_the_torque():
    """The loop on flipped gyros feeds the turn: the slope is negative and the referee names it."""
    check = _flown(0.3, -1.0)
    slope, excitation = check.slope()
    assert slope < -0.5 and excitation > 2.0
    assert check.against().startswith(f"slope {slope:+.2f} of their rate changes on the torque's over 100 ms")


def test_too_little_excitation_says_nothing():
    """Flipped gyros on a body the loop barely moves (hover-sized kicks of 0.2 mN m): not judged."""
    check = _flown(0.3, -1.0, kick_nm=2e-4)
    slope, excitation = check.slope()
    assert slope < 0.0 and excitation < 2.0 and check.against() == ""


def test_no_reading_restarts_the_history():
    check = _flown(0.3, -1.0)
    assert check.against()
    check.add(0.3, np.full(3, np.nan))
    assert check.slope() == (pytest.approx(math.nan, nan_ok=True), 0.0) and check.against() == ""
