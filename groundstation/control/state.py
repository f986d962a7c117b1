"""Frozen state and setpoint types shared by control, simulation and logging."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class RigidState:
    """Pose and twist of the assembly body frame (origin at the COM)."""

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """COM position, world frame (z up), m."""
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """COM velocity, world frame, m/s."""
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    """Body-to-world rotation matrix."""
    omega: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Angular velocity, body frame, rad/s."""


@dataclass(frozen=True, eq=False)
class Setpoint:
    """Desired motion at one instant, from a trajectory."""

    position: np.ndarray
    """World frame, m."""
    velocity: np.ndarray
    """World frame, m/s."""
    acceleration: np.ndarray
    """World frame, m/s^2."""
    rotation: np.ndarray
    """Desired body-to-world rotation (attitude target before any under-actuation adaptation)."""
    omega: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Desired angular velocity, body frame, rad/s."""
