"""Reference trajectories with analytic derivatives (paper §V, §VI).

Every trajectory maps time (s, from its own start) to a :class:`Setpoint`. A :class:`FlightPlan` chains
take-off, the tracking trajectory and landing so the reference is continuous in position and velocity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from groundstation.control.phase import Phase
from groundstation.control.state import Setpoint

TWO_PI = 2.0 * np.pi
QUINTIC_SPEED = 1.875
"""Largest slope of the quintic smoothstep 10 s^3 - 15 s^4 + 6 s^5 on [0, 1] (at s = 1/2)."""
QUINTIC_ACCEL = 10.0 / math.sqrt(3.0)
"""Largest |second derivative| of the quintic smoothstep on [0, 1] (at s = 1/2 -+ 1/sqrt(12))."""


@dataclass(frozen=True)
class Bounds:
    """Analytic bounds of a reference over its whole duration (no sampling): what preflight checks."""

    lower: tuple[float, float, float]
    """Smallest position per axis, world, m."""
    upper: tuple[float, float, float]
    speed: float
    """Largest speed, m/s."""
    accel: float
    """Largest acceleration, m/s^2."""

    def union(self, other: Bounds) -> Bounds:
        return Bounds(tuple(np.minimum(self.lower, other.lower)), tuple(np.maximum(self.upper, other.upper)),
                      max(self.speed, other.speed), max(self.accel, other.accel))


def euler_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation ``R_z(yaw) R_y(pitch) R_x(roll)``, radians (scalar ``math``: this runs several times per control
    period, where numpy's per-call overhead on scalars dominates)."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def roll_pitch_yaw(r: np.ndarray) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) of a rotation matrix, radians."""
    r20 = min(1.0, max(-1.0, float(r[2, 0])))
    return (math.atan2(float(r[2, 1]), float(r[2, 2])), -math.asin(r20), math.atan2(float(r[1, 0]), float(r[0, 0])))


@dataclass(frozen=True)
class Attitude:
    """Fixed attitude target, radians."""

    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0

    @property
    def matrix(self) -> np.ndarray:
        return euler_zyx(self.roll, self.pitch, self.yaw)


@dataclass(frozen=True)
class Hover:
    """Hold ``point`` (world, m)."""

    point: tuple[float, float, float]
    duration: float
    """s"""
    attitude: Attitude = field(default_factory=Attitude)

    def __call__(self, t: float) -> Setpoint:
        z = np.zeros(3)
        return Setpoint(np.array(self.point, float), z, z.copy(), self.attitude.matrix)

    def bounds(self) -> Bounds:
        return Bounds(self.point, self.point, 0.0, 0.0)


@dataclass(frozen=True)
class Ramp:
    """Smooth move from ``start`` to ``end`` (world, m) with a quintic profile: zero velocity and acceleration at
    both ends. Take-off and landing are ramps."""

    start: tuple[float, float, float]
    end: tuple[float, float, float]
    duration: float
    """s"""
    attitude: Attitude = field(default_factory=Attitude)

    def __call__(self, t: float) -> Setpoint:
        s = min(1.0, max(0.0, t / self.duration))
        inside = 0.0 < t < self.duration
        h = 10 * s**3 - 15 * s**4 + 6 * s**5
        dh = (30 * s**2 - 60 * s**3 + 30 * s**4) / self.duration if inside else 0.0
        ddh = (60 * s - 180 * s**2 + 120 * s**3) / self.duration**2 if inside else 0.0
        a, b = np.array(self.start, float), np.array(self.end, float)
        return Setpoint(a + h * (b - a), dh * (b - a), ddh * (b - a), self.attitude.matrix)

    def bounds(self) -> Bounds:
        a, b = np.array(self.start, float), np.array(self.end, float)
        length = float(np.linalg.norm(b - a))
        return Bounds(tuple(np.minimum(a, b)), tuple(np.maximum(a, b)), QUINTIC_SPEED * length / self.duration,
                      QUINTIC_ACCEL * length / self.duration**2)


LANDING_BRAKE = 1.0
"""Horizontal deceleration a landing begun in motion brakes with, m/s^2 (a tilt of ~6 deg; up to 10 % more when
its acceleration at the start points elsewhere, or as much as that acceleration if it is larger)."""


def _to_rest(p0: np.ndarray, v0: np.ndarray, a0: np.ndarray, p1: np.ndarray, duration: float, t: float):
    """Per axis, the quintic from ``p0`` moving at ``v0`` and accelerating at ``a0`` to rest at ``p1`` after
    ``duration`` s: position, velocity and acceleration at ``t`` (held at ``p1`` after)."""
    if t >= duration:
        return p1, np.zeros(3), np.zeros(3)
    d, tt = p1 - p0, duration
    c3 = (20.0 * d - 12.0 * v0 * tt - 3.0 * a0 * tt ** 2) / (2.0 * tt ** 3)
    c4 = (-30.0 * d + 16.0 * v0 * tt + 3.0 * a0 * tt ** 2) / (2.0 * tt ** 4)
    c5 = (12.0 * d - 6.0 * v0 * tt - a0 * tt ** 2) / (2.0 * tt ** 5)
    return (p0 + v0 * t + 0.5 * a0 * t ** 2 + c3 * t ** 3 + c4 * t ** 4 + c5 * t ** 5,
            v0 + a0 * t + 3.0 * c3 * t ** 2 + 4.0 * c4 * t ** 3 + 5.0 * c5 * t ** 4,
            a0 + 6.0 * c3 * t + 12.0 * c4 * t ** 2 + 20.0 * c5 * t ** 3)


def _pieces(w: float, dist: float, cruise: float, end: float, accel: float) -> list[tuple[float, float]] | None:
    """Constant-acceleration pieces (duration s, acceleration m/s^2, along the motion) from speed ``w`` to speed
    ``end`` over ``dist``, m, cruising at up to ``cruise`` between, changing speed at ``accel`` (or, to make
    ``end`` where it cannot at ``accel``, braking harder, at most twice that: it then ends past ``dist``); None if
    there is no way down (``dist`` <= 0)."""
    if dist <= 0.0:
        return None
    if w > end and (w * w - end * end) / (2.0 * accel) > dist:  # too fast to slow down at accel: brake harder
        a = min((w * w - end * end) / (2.0 * dist), 2.0 * accel)
        return [((w - end) / a, -a)]
    # The peak speed c of speeding up then slowing down over exactly dist: (c^2 - w^2 + c^2 - end^2) / 2a = dist
    # (signed speeds: w < 0 climbs).
    c = max(end, min(cruise, math.sqrt(accel * dist + 0.5 * (w * w + end * end))) if w <= cruise else cruise)
    first = (c * c - w * w) / (2.0 * math.copysign(accel, c - w)) if c != w else 0.0
    last = (c * c - end * end) / (2.0 * accel)
    pieces = [(abs(c - w) / accel, math.copysign(accel, c - w)), (max(0.0, dist - first - last) / c, 0.0),
              ((c - end) / accel, -accel)]
    return [(d, a) for d, a in pieces if d > 0.0]


DESCENT_BLEND_S = 0.3
"""How long a :class:`Descent` blends its start's acceleration into its first piece's, s."""


@dataclass(frozen=True)
class Descent:
    """A vertical descent flown without a height measurement (a blind landing): at up to ``cruise_mps`` while
    higher than ``slow_m`` above the ground, then at ``touchdown_mps`` to it, changing speed at ``accel_mps2``
    (only the collective thrust changes: the attitude does not); past the ground it speeds up at ``press_mps2``,
    to ``depth_m`` below and on (the flight ends it): a body already on the ground is pressed onto it by that
    much less than its weight's thrust (at the weight's, a landed V rose 3.6 cm as the estimate's disturbance
    allowed), one still above it touches down a little faster. It never stops itself: where the ground is, is
    known only to the estimate's uncertainty, and a stop below an estimate that ran low stopped the body in the
    air (the thrust cut to stop the estimate dropped the V from 0.15 m at 1.4 m/s); an estimate that ran high
    asked a landed body for the thrust that stops it. Flown as the quintic of a planned landing, at a mean of
    0.5 m/s, the estimate's uncertainty grew past its bound from 1.6 m (it grows with the time flown blind, to
    the 2.5th power), and the touchdown speed was the quintic's wherever the ground cut it (0.6-0.8 m/s)."""

    z0: float
    """Start height, world, m."""
    v0: float
    """Start vertical velocity, world (up), m/s."""
    ground_z: float
    """The ground, world, m."""
    cruise_mps: float
    touchdown_mps: float
    slow_m: float
    depth_m: float
    accel_mps2: float
    press_mps2: float
    a0: float | None = None
    """Start vertical acceleration, world (up), m/s^2 (None: the first piece's): that piece's is blended in from it over
    :data:`DESCENT_BLEND_S` (a step of it steps the attitude target of an assembly moving sideways: a blind landing
    begun in a figure-8 stepped it by 0.64 deg in a period)."""

    @cached_property
    def _segments(self) -> tuple[tuple[float, float, float, float], ...]:
        """(start s, start height m, start velocity m/s, acceleration m/s^2), world up."""
        u, a, slow = -self.v0, self.accel_mps2, self.touchdown_mps  # downwards
        # Climbing (a take-off cut short): the climb stops at twice the rate (the take-off's own quintic brakes
        # harder), then the descent starts from rest: at the rate alone, from a 1 m take-off's 1.8 m/s, it climbed
        # 1.1 m more.
        climb = [(-u / (2.0 * a), 2.0 * a)] if u < 0.0 else []
        top = self.z0 + (u * u / (4.0 * a) if climb else 0.0)
        u = max(u, 0.0)
        to_slow = top - (self.ground_z + self.slow_m)
        # Faster down to slow_m if there is room to reach the touchdown speed by then at accel; else at that speed
        # at most all the way (braking harder only where the whole way forces it: from just above slow_m at 1 m/s,
        # braking to the touchdown speed by slow_m asked 100-400 m/s^2).
        fast = _pieces(u, to_slow, self.cruise_mps, slow, a) if to_slow > abs(slow * slow - u * u) / (2.0 * a) \
            else None
        last = [(self.slow_m / slow, 0.0)] if fast else (_pieces(u, top - self.ground_z, slow, slow, a) or [])
        segments, t, z, v = [], 0.0, self.z0, self.v0
        for d, acc in climb + (fast or []) + last:
            if d <= 1e-9:
                continue
            segments.append((t, z, v, -acc))
            z, v, t = z + v * d - 0.5 * acc * d * d, v - acc * d, t + d
        segments.append((t, z, v, -self.press_mps2))  # from the ground on
        return tuple(segments)

    @cached_property
    def duration(self) -> float:
        """Until it is ``depth_m`` below the ground, s."""
        t, z, v, a = self._segments[-1]
        below = z - (self.ground_z - self.depth_m)  # to go from the last piece's start (on or below the ground)
        if below <= 0.0:
            return t
        return t + (v + math.sqrt(v * v + 2.0 * -a * below)) / -a if a < 0.0 else t + below / -v

    @property
    def end_z(self) -> float:
        """Where it is then, world, m."""
        return self(self.duration)[0]

    def __call__(self, t: float) -> tuple[float, float, float]:
        """Height (m), vertical velocity (m/s) and acceleration (m/s^2) at ``t`` s, world up."""
        t0, z, v, a = next(p for p in reversed(self._segments) if p[0] <= t) if t > 0.0 else self._segments[0]
        dt = max(0.0, t - t0)
        z, v, a = z + v * dt + 0.5 * a * dt * dt, v + a * dt, a
        if self.a0 is not None and 0.0 <= t < DESCENT_BLEND_S:
            # + (a0 - the first piece's) g(t), g = t^2 / 2 (1 - t / T)^3: g, g' and g'' are 0, 0, 1 at the start and
            # 0, 0, 0 at T (position and velocity untouched at both ends)
            da, s = self.a0 - self._segments[0][3], t / DESCENT_BLEND_S
            r = 1.0 - s
            z += da * 0.5 * t * t * r ** 3
            v += da * (t * r ** 3 - 1.5 * s * t * r * r)
            a += da * (r ** 3 - 6.0 * s * r * r + 3.0 * s * s * r)
        return z, v, a


@dataclass(frozen=True)
class Landing:
    """A landing begun wherever the assembly is and however it moves (a failsafe, the operator): the reference
    goes on from a position, velocity and acceleration, brakes horizontally to rest and descends to
    ``touchdown_z`` in ``duration``. A reference that started at rest asked the controller to stop a figure-8 at
    0.5 m/s in one period: the V's pitch target stepped by 16 deg and its rotors saturated (the fault table's
    reordering row: 21 deg of tilt)."""

    start: tuple[float, float, float]
    """World, m."""
    velocity: tuple[float, float, float]
    """At the start, world, m/s."""
    acceleration: tuple[float, float, float]
    """At the start, world, m/s^2."""
    touchdown_z: float
    """m"""
    duration: float
    """Of the descent, s; the horizontal stop takes at most this."""
    descent: Descent | None = None
    """Flown blind: the vertical profile (ending at ``touchdown_z`` after ``duration``: :meth:`blind`), not the
    quintic."""

    @classmethod
    def blind(cls, start, velocity, acceleration, descent: Descent) -> Landing:
        """A landing whose height follows ``descent`` (its start height and vertical velocity: ``start``'s and
        ``velocity``'s)."""
        return cls(start, velocity, acceleration, descent.end_z, descent.duration, descent)

    @cached_property
    def _plan(self) -> tuple[np.ndarray, ...]:
        p0, v0, a0 = (np.array(x, float) for x in (self.start, self.velocity, self.acceleration))
        v_h, a_h = v0 * (1.0, 1.0, 0.0), a0 * (1.0, 1.0, 0.0)
        # Braking at LANDING_BRAKE at most (or the start's acceleration, if larger): the quintic to the rest
        # point below decelerates by at most 1.5 speed / time, and moves on by about half speed x time.
        stop_s = min(self.duration, max(1.5 * float(np.linalg.norm(v_h)) / LANDING_BRAKE, 0.3))
        rest = p0 + v_h * (stop_s / 2.0) + a_h * (stop_s ** 2 / 12.0)
        return p0, v0 - v_h, a0 - a_h, v_h, a_h, np.array([rest[0], rest[1], self.touchdown_z]), stop_s

    @property
    def end(self) -> tuple[float, float, float]:
        """Where it touches down, world, m."""
        return tuple(float(v) for v in self._plan[5])

    def __call__(self, t: float) -> Setpoint:
        p0, v_z, a_z, v_h, a_h, p1, stop_s = self._plan
        t = max(t, 0.0)
        ph, vh, ah = _to_rest(p0, v_h, a_h, p1, stop_s, t)
        if self.descent is None:
            pz, vz, az = (x[2] for x in _to_rest(p0, v_z, a_z, p1, self.duration, t))
        else:
            pz, vz, az = self.descent(t)
        return Setpoint(np.array([ph[0], ph[1], pz]), np.array([vh[0], vh[1], vz]), np.array([ah[0], ah[1], az]),
                        np.eye(3))


@dataclass(frozen=True)
class Circle:
    """Horizontal circle of ``radius`` (m) around ``center`` (world, m), one lap per ``period`` (s), starting
    at ``center + [radius, 0, 0]``."""

    center: tuple[float, float, float]
    radius: float
    period: float
    duration: float
    attitude: Attitude = field(default_factory=Attitude)

    def __call__(self, t: float) -> Setpoint:
        w = TWO_PI / self.period
        c, s = np.cos(w * t), np.sin(w * t)
        r = self.radius
        p = np.array(self.center, float) + [r * c, r * s, 0.0]
        return Setpoint(p, np.array([-r * w * s, r * w * c, 0.0]), np.array([-r * w * w * c, -r * w * w * s, 0.0]),
                        self.attitude.matrix)

    def bounds(self) -> Bounds:
        w, r, c = TWO_PI / self.period, self.radius, np.array(self.center, float)
        return Bounds(tuple(c - [r, r, 0.0]), tuple(c + [r, r, 0.0]), r * w, r * w * w)


@dataclass(frozen=True)
class Figure8:
    """The paper's 3D figure-8 (§VI-B):
    ``p(t) = [l0 sin(wt) cos(wt), l0 sin(wt), h0 - l0/3 sin(wt)] + offset``, ``w = 2 pi / tc``."""

    l0: float
    """Size, m."""
    tc: float
    """Period, s."""
    h0: float
    """Mean height, m."""
    duration: float
    offset: tuple[float, float] = (0.0, 0.0)
    """Horizontal offset of the figure, m."""
    attitude: Attitude = field(default_factory=Attitude)

    def __call__(self, t: float) -> Setpoint:
        w = TWO_PI / self.tc
        s, c = np.sin(w * t), np.cos(w * t)
        s2, c2 = np.sin(2 * w * t), np.cos(2 * w * t)
        l0 = self.l0
        p = np.array([self.offset[0] + 0.5 * l0 * s2, self.offset[1] + l0 * s, self.h0 - l0 / 3 * s])
        v = np.array([l0 * w * c2, l0 * w * c, -l0 / 3 * w * c])
        a = np.array([-2 * l0 * w * w * s2, -l0 * w * w * s, l0 / 3 * w * w * s])
        return Setpoint(p, v, a, self.attitude.matrix)

    def bounds(self) -> Bounds:
        """Each coordinate reaches its extremes; speed and acceleration bounded per axis (|v_x| <= l0 w, ...)."""
        w, l0 = TWO_PI / self.tc, self.l0
        ext = np.array([0.5 * l0, l0, l0 / 3])
        c = np.array([self.offset[0], self.offset[1], self.h0])
        return Bounds(tuple(c - ext), tuple(c + ext), l0 * w * math.sqrt(2 + 1 / 9),
                      l0 * w * w * math.sqrt(4 + 1 + 1 / 9))


def _smoothstep(x: float) -> tuple[float, float, float]:
    """Quintic smoothstep h(x) on [0, 1], its derivative and its integral from 0."""
    x = min(max(x, 0.0), 1.0)
    return 10 * x**3 - 15 * x**4 + 6 * x**5, 30 * x**2 - 60 * x**3 + 30 * x**4, 2.5 * x**4 - 3 * x**5 + x**6


LANDING_DEPTH = 0.02
"""A landing aims this far below the ground, m: the touchdown's last thrust presses the assembly down (firm contact)."""
MAX_LANDING_MPS = 0.8
"""The fastest mean descent of a landing (its height over its time), m/s: a landing lasts at least its height over
this (:attr:`FlightPlan.landing_time`, and the flight's landings begun elsewhere). The quintic peaks at 1.875 times
that and the position loop trails it. Measured in the dry run, the toy V's 0.76 m with 18 % more mass than its model
says: in 0.86 s (0.89 m/s) touchdown at 1.64 m/s, in 1.0 s (0.76 m/s) 1.39 m/s (0.92 without the extra mass), in
1.3 s 0.99 m/s, in 1.7 s 0.71 m/s."""


@dataclass(frozen=True)
class FlightPlan:
    """Take off level from ``ground`` to the trajectory's start, track it, land level below its end point.

    Transitions are smooth: the tracking trajectory is entered and left through a time warp ``s(t)`` whose rate
    rises from 0 to 1 (and back) over ``ramp_s`` with a quintic profile, so the reference velocity and
    acceleration are continuous; the attitude target is blended from level to the trajectory's attitude during
    the settle phase and back to level during the first half of the landing.
    """

    ground: tuple[float, float, float]
    """COM position resting on the ground, world, m."""
    track: Hover | Circle | Figure8
    takeoff_s: float = 3.0
    settle_s: float = 1.5
    ramp_s: float = 2.0
    landing_s: float = 3.0
    """The landing's time, s, unless it is too short for its height: :attr:`landing_time`."""

    @cached_property
    def landing_time(self) -> float:
        """The landing's time: ``landing_s``, or its height over :data:`MAX_LANDING_MPS` if longer, s."""
        drop = self._ends[1][2] - (self.ground[2] - LANDING_DEPTH)
        return max(self.landing_s, drop / MAX_LANDING_MPS)

    @cached_property
    def phases(self) -> tuple[tuple[Phase, float, float], ...]:
        """(name, start, end) of each phase, s."""
        t1 = self.takeoff_s
        t2 = t1 + self.settle_s
        t3 = t2 + self.track.duration
        t4 = t3 + self.settle_s
        return ((Phase.TAKEOFF, 0.0, t1), (Phase.SETTLE, t1, t2), (Phase.TRACK, t2, t3), (Phase.HOLD, t3, t4),
                (Phase.LANDING, t4, t4 + self.landing_time))

    @property
    def duration(self) -> float:
        return self.phases[-1][2]

    def _warp(self, t: float) -> tuple[float, float, float]:
        """Trajectory time s(t), s'(t), s''(t) within the tracking phase."""
        d, r = self.track.duration, min(self.ramp_s, self.track.duration / 2)
        if r <= 0:
            return t, 1.0, 0.0
        if t < r:
            h, dh, ih = _smoothstep(t / r)
            return r * ih, h, dh / r
        if t > d - r:
            h, dh, ih = _smoothstep((d - t) / r)
            return (d - r) - r * ih, h, -dh / r
        return r / 2 + (t - r), 1.0, 0.0

    def _tracked(self, t: float) -> Setpoint:
        s, ds, dds = self._warp(t)
        sp = self.track(s)
        return Setpoint(sp.position, sp.velocity * ds, sp.acceleration * ds * ds + sp.velocity * dds, sp.rotation)

    def _attitude(self, weight: float) -> np.ndarray:
        att = self.track.attitude
        return euler_zyx(weight * att.roll, weight * att.pitch, att.yaw)

    @cached_property
    def _ends(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        return tuple(self._tracked(0.0).position), tuple(self._tracked(self.track.duration).position)

    def __call__(self, t: float) -> Setpoint:
        (_, _, t1), (_, _, t2), (_, _, t3), (_, _, t4), _ = self.phases
        start, end = self._ends
        if t < t1:
            sp = Ramp(self.ground, start, self.takeoff_s)(t)
            return Setpoint(sp.position, sp.velocity, sp.acceleration, self._attitude(0.0))
        if t < t2:
            blend = _smoothstep((t - t1) / self.settle_s)[0]
            return Setpoint(np.array(start), np.zeros(3), np.zeros(3), self._attitude(blend))
        if t < t3:
            return self._tracked(t - t2)
        if t < t4:
            return Setpoint(np.array(end), np.zeros(3), np.zeros(3), self._attitude(1.0))
        touchdown = (end[0], end[1], self.ground[2] - LANDING_DEPTH)
        sp = Ramp(end, touchdown, self.landing_time)(t - t4)
        level = 1.0 - _smoothstep(2.0 * (t - t4) / self.landing_time)[0]
        return Setpoint(sp.position, sp.velocity, sp.acceleration, self._attitude(level))

    def bounds(self) -> Bounds:
        """Position box, speed and acceleration of the whole plan, from each piece's closed form: the tracking
        trajectory through the time warp (speed scaled by at most 1, acceleration gains the warp's
        ``v * s''`` term), take-off and landing ramps, and the hold points."""
        start, end = self._ends
        touchdown = (end[0], end[1], self.ground[2] - LANDING_DEPTH)
        return (Ramp(self.ground, start, self.takeoff_s).bounds().union(self.tracked_bounds())
                .union(Ramp(end, touchdown, self.landing_time).bounds()))

    def tracked_bounds(self) -> Bounds:
        """The tracking phase's bounds: the trajectory's through the time warp, whose ``v * s''`` term adds to its
        acceleration (a short track enters and leaves its speed in a short ramp)."""
        r = min(self.ramp_s, self.track.duration / 2)
        tb = self.track.bounds()
        warp_accel = tb.accel + (tb.speed * QUINTIC_SPEED / r if r > 0 else 0.0)
        return Bounds(tb.lower, tb.upper, tb.speed, warp_accel)

    def phase_at(self, t: float) -> Phase:
        for name, a, b in self.phases:
            if a <= t < b:
                return name
        return Phase.DONE


def make_track(kind: str, duration: float, height: float, size: float, period: float, roll_deg: float):
    """The tracking trajectory named by ``kind`` (``hover``, ``circle``, ``figure8``) from flight parameters:
    ``size`` is the figure-8's l0 or the circle's radius (m), ``period`` its t_c or lap time (s)."""
    from groundstation.errors import UsageError

    att = Attitude(roll=np.radians(roll_deg))
    if kind == "hover":
        return Hover((0.0, 0.0, height), duration, att)
    if kind == "circle":
        return Circle((-size, 0.0, height), size, period, duration, att)
    if kind == "figure8":
        return Figure8(size, period, height, duration, attitude=att)
    raise UsageError(f"unknown trajectory {kind!r}; choose hover, circle or figure8")
