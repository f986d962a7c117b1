"""How old the modules' gyro readings were in a flight: the body rate the gyros gave (``/control`` state, bias
removed) against the rate the mocap poses show, matched over a range of delays. What ``backend.gyro_delay_s``
should be for these modules (the estimator compensates that delay; :mod:`groundstation.estimation.filter`).

The poses are timed at capture (their stamps on the log's clock by the fastest sample, less the configured mocap
latency), their rate is the rotation between poses :data:`BASELINE_S` apart over their stamp interval (from
consecutive poses, a 0.1 deg mocap noise alone would read 14 deg/s at 100 Hz); the gyro rate of a control period
is the newest reading then, averaged over the same interval. The delay is the shift of the gyro series that best
matches the pose rate, over the airborne periods, all three axes. It needs motion: a flight that hardly turns has
no delay to find (the match is then flat, and said to be: :data:`SHARPNESS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from groundstation.control.phase import Phase
from groundstation.errors import ConfigError
from groundstation.replay.analysis import log_config
from groundstation.replay.reader import open_log
from groundstation.rotations import matrix_to_rotvec, quat_to_matrix

LAGS_S = np.arange(-0.02, 0.0605, 0.001)
"""Delays tried, s."""
BASELINE_S = 0.05
"""Time between the two poses a rate is taken from, s."""
MIN_RATE = math.radians(5.0)
"""Least RMS body rate for a delay to be found, rad/s."""
SHARPNESS = 1.25
"""A delay is found only where the rate mismatch 10 ms either side of it is at least this many times larger: a
flat match (a calm flight, noise) names no delay."""


@dataclass(frozen=True)
class GyroLag:
    delay_s: float
    """The gyro readings' age that best matches the poses, s."""
    configured_s: float
    """``backend.gyro_delay_s`` the flight flew with, s."""
    rms_at_delay: float
    """RMS of the difference of the two rates (its norm) at that delay, rad/s."""
    rms_at_zero: float
    """...and with none, rad/s."""
    rate_rms: float
    """RMS of the pose rate's norm, rad/s (below :data:`MIN_RATE` the delay is not trusted)."""
    samples: int
    """Pose intervals compared."""
    sharpness: float
    """The smaller rate mismatch 10 ms either side of the delay, over the mismatch there."""

    @property
    def found(self) -> bool:
        return self.rate_rms >= MIN_RATE and self.sharpness >= SHARPNESS


def gyro_lag(path: str | Path) -> GyroLag:
    """The gyro delay of the flight logged at ``path`` (a ConfigError when it has no poses or no airborne
    period)."""
    log = open_log(path)
    src = str(path)
    arrivals, stamps, rotations, periods = [], [], [], []
    for rec in log.records():  # the metadata (the config: which body, the latency) is read along the way
        if rec.topic == "/control":
            d = rec.data
            if "state" in d and Phase(d["phase"]).airborne:
                periods.append((rec.log_time, d["state"]["omega_radps"]))
            continue
        if not rec.topic.startswith("/mocap/") or rec.topic == "/mocap/stats":
            continue
        pose = PoseInFrame()
        pose.ParseFromString(rec.data)
        q = pose.pose.orientation
        arrivals.append(rec.log_time)
        stamps.append(pose.timestamp.seconds + pose.timestamp.nanos * 1e-9)
        rotations.append(quat_to_matrix([q.x, q.y, q.z, q.w]))
    if len(stamps) < 3 or len(periods) < 3:
        raise ConfigError(f"the log has {len(stamps)} poses and {len(periods)} airborne control periods: no gyro "
                          f"delay to find", path=src)
    config = log_config(log.metadata, src)
    try:
        latency = float(config.get("mocap", {}).get("latency_s", 0.0))
        configured = float(config.get("backend", {}).get("gyro_delay_s", 0.0))
    except (AttributeError, TypeError, ValueError):  # a section that is not a table, a value that is not a number
        raise ConfigError("the log's config has no usable mocap.latency_s or backend.gyro_delay_s", path=src,
                          key="config") from None
    stamps_a = np.array(stamps)
    captured = stamps_a + np.min(np.array(arrivals) - stamps_a) - latency
    k = max(1, round(BASELINE_S / max(float(np.median(np.diff(stamps_a))), 1e-6)))
    dt = stamps_a[k:] - stamps_a[:-k]
    ok = dt > 0
    rates = np.array([matrix_to_rotvec(a.T @ b) for a, b in zip(rotations[:-k], rotations[k:], strict=True)])
    rates = rates[ok] / dt[ok, None]
    t0, t1 = captured[:-k][ok], captured[k:][ok]
    t_g = np.array([p[0] for p in periods])
    gyro = np.array([p[1] for p in periods], float)
    inside = (t0 > t_g[0]) & (t1 < t_g[-1])
    t0, t1, rates = t0[inside], t1[inside], rates[inside]
    if len(t0) < 3:
        raise ConfigError("the log's poses and airborne periods do not overlap: no gyro delay to find", path=src)
    # the gyro's angle, integrated over the log (trapezoids), to average it over any interval
    angle = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (gyro[1:] + gyro[:-1]) * np.diff(t_g)[:, None], 0)])

    def rms(lag: float) -> float:
        # a reading logged at t was measured lag earlier: the pose rate over [t0, t1] against the readings logged
        # over [t0 + lag, t1 + lag]
        turned = np.column_stack([np.interp(t1 + lag, t_g, angle[:, i]) - np.interp(t0 + lag, t_g, angle[:, i])
                                  for i in range(3)])
        return float(np.sqrt(np.mean(np.sum((turned / (t1 - t0)[:, None] - rates) ** 2, axis=1))))

    scores = [rms(lag) for lag in LAGS_S]
    best = int(np.argmin(scores))
    step = round(0.01 / (LAGS_S[1] - LAGS_S[0]))
    beside = min(scores[max(best - step, 0)], scores[min(best + step, len(scores) - 1)])
    return GyroLag(float(LAGS_S[best]), configured, scores[best],
                   rms(0.0), float(np.sqrt(np.mean(np.sum(rates ** 2, axis=1)))), len(t0),
                   beside / max(scores[best], 1e-12))
