"""The gyros checked against the torque the flight commands: the referee when the poses and the gyros disagree.

Every module's gyro wrong alike (a sign flipped, axes swapped: a firmware or configuration error) agrees with
itself, so :class:`~groundstation.estimation.gyro_check.GyroAgreement` sees nothing, and the estimator sees only that
the poses' attitude leaves the gyros' prediction, which a frozen or forged stream does too. The third witness is
the model: the body's angular acceleration follows the torque commanded, ``J^-1 tau`` (the inertia ``J``, the
allocated torque). Over the last ``window_s`` the change of the gyros' rate across ``span_s`` is regressed on the
change the commanded torque predicts across the same span; the slope is about +0.5 in flight (motor lag, the
controller's pre-allocation wrench against the allocated one, disturbances the controller answers) and turns
negative when the gyros turn against the torque: a sign-flipped set makes the attitude loop a positive feedback,
and the torque it then commands is answered by the opposite reading. Measured on the toy V (``all_flip_tracking``,
hostile campaign): +0.3..+0.9 before, -0.46..-0.67 from 25 ms after the flip, with an excitation (the squared
predicted changes summed) of 4 to 900 against at most 0.8 where the slope was ever negative in a nominal flight.

Asked only while the poses and the gyros disagree (the newest pose compared, captured within the last 0.1 s, more
than a degree from the estimate's attitude: :attr:`RigidBodyFilter.attitude_seen`) and every module's frame clears
the ground by 3 cm (:meth:`Flight._clear_of_the_ground`): a shove or a gust turns the gyros and the poses alike, and
the ground's contact torques are no command's.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from groundstation.rotations import Vec3


@dataclass(frozen=True)
class TorqueAgreementSettings:
    window_s: float = 0.1
    """Time judged, s."""
    span_s: float = 0.04
    """Changes compared across this long, s (several gyro readings at 100 Hz; the motors' lag is ~30 ms)."""
    min_excitation: float = 2.0
    """Sum of the squared predicted rate changes, (rad/s)^2, below which the slope says nothing."""
    max_slope: float = -0.25
    """A slope below this is the gyros turning against the torque."""


class TorqueAgreement:
    """Feed :meth:`add` (the rate flown on) and :meth:`command` (the torque sent) every period; :meth:`against`
    judges. Kept in Python floats, as the filter (numpy's cost is per call on 3-vectors)."""

    def __init__(self, inertia: np.ndarray, settings: TorqueAgreementSettings | None = None) -> None:
        self.settings = settings or TorqueAgreementSettings()
        self._inverse = np.linalg.inv(np.asarray(inertia, float)).tolist()
        self._recent: deque[tuple[float, Vec3, Vec3]] = deque()
        """(t s, the gyros' rate rad/s, the commanded angular acceleration integrated since the start rad/s) of the
        last ``window_s + span_s``."""
        self._alpha: Vec3 = (0.0, 0.0, 0.0)
        """The angular acceleration of the torque last commanded, rad/s^2."""
        self._integral: Vec3 = (0.0, 0.0, 0.0)

    def add(self, t: float, rate: np.ndarray | None) -> None:
        """The body rate the gyros give at ``t`` (s; rad/s, body frame; None or not finite: none, and the history
        restarts)."""
        recent = self._recent
        if recent:
            dt = t - recent[-1][0]
            ax, ay, az = self._alpha
            ix, iy, iz = self._integral
            self._integral = (ix + ax * dt, iy + ay * dt, iz + az * dt)
        w = None if rate is None else rate.tolist()
        if w is None or not math.isfinite(w[0] + w[1] + w[2]):
            recent.clear()
            return
        recent.append((t, (w[0], w[1], w[2]), self._integral))
        while recent[0][0] < t - self.settings.window_s - self.settings.span_s:
            recent.popleft()

    def command(self, torque: np.ndarray | None) -> None:
        """The torque commanded from now on (N m, body frame; None: motors off)."""
        if torque is None:
            self._alpha = (0.0, 0.0, 0.0)
            return
        tx, ty, tz = torque.tolist()
        (a, b, c), (d, e, f), (g, h, i) = self._inverse
        self._alpha = (a * tx + b * ty + c * tz, d * tx + e * ty + f * tz, g * tx + h * ty + i * tz)

    def slope(self) -> tuple[float, float]:
        """(slope, excitation) of the gyros' rate changes on the torque's over the window (NaN slope: no pairs)."""
        s = self.settings
        recent = list(self._recent)
        if not recent:
            return math.nan, 0.0
        newest = recent[-1][0]
        both = excitation = 0.0
        j = 0
        for t, w, m in recent:
            if t < newest - s.window_s:
                continue
            while j + 1 < len(recent) and recent[j + 1][0] <= t - s.span_s:
                j += 1
            t0, w0, m0 = recent[j]
            if t0 > t - s.span_s:
                continue  # nothing that far back yet
            dw = (w[0] - w0[0], w[1] - w0[1], w[2] - w0[2])
            dm = (m[0] - m0[0], m[1] - m0[1], m[2] - m0[2])
            both += dw[0] * dm[0] + dw[1] * dm[1] + dw[2] * dm[2]
            excitation += dm[0] * dm[0] + dm[1] * dm[1] + dm[2] * dm[2]
        return (both / excitation if excitation > 0.0 else math.nan), excitation

    def against(self) -> str:
        """Why the gyros turn against the commanded torque ("" while they do not, or cannot be told)."""
        k, excitation = self.slope()
        if excitation < self.settings.min_excitation or not k < self.settings.max_slope:
            return ""
        return f"slope {k:+.2f} of their rate changes on the torque's over {self.settings.window_s * 1e3:.0f} ms"
