"""Running flight figures against the same figures computed here from the whole series at once."""

import math

import numpy as np

from groundstation.runtime.metrics import FlightMetrics


def test_the_rotor_change_per_period_counts_tracking_periods_only():
    rng = np.random.default_rng(0)
    phases = ["takeoff"] * 20 + ["track"] * 200 + ["hold"] * 20 + ["track"] * 30 + ["landing"] * 10
    motors = rng.uniform(0.3, 0.6, (len(phases), 2, 4))
    m = FlightMetrics(2)
    for k, (phase, u) in enumerate(zip(phases, motors, strict=True)):
        m.add(k / 250, phase, np.zeros(3), np.zeros(3), np.eye(3), np.eye(3), 0.0, 0.0, u)
    # consecutive tracking periods only: the two stretches, not across the hold between them
    changes = np.concatenate([np.diff(motors[20:220], axis=0).ravel(), np.diff(motors[240:270], axis=0).ravel()])
    f = m.result()
    assert math.isclose(f.motor_change_rms, float(np.sqrt(np.mean(changes ** 2))), rel_tol=1e-12)
    assert f.motor_change_max == float(np.abs(changes).max())


def test_no_tracking_no_rotor_change():
    m = FlightMetrics(1)
    m.add(0.0, "takeoff", np.zeros(3), np.zeros(3), np.eye(3), np.eye(3), 0.0, 0.0, np.full((1, 4), 0.4))
    assert math.isnan(m.result().motor_change_rms) and math.isnan(m.result().motor_change_max)
