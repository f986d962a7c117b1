"""Figures of a flight: 3D trajectory against the reference, errors and motor use over time."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from groundstation.control.phase import Phase
from groundstation.output import save_figure
from groundstation.rotations import rotation_angle
from groundstation.runtime.closed_loop import FlightRecord


def plot_flight(rec: FlightRecord, path: str | Path, title: str, u_max: float) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(12, 7))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax3.plot(*rec.position_ref.T, "k--", lw=1, label="reference")
    ax3.plot(*rec.position.T, "tab:blue", lw=1.2, label="flown")
    ax3.set_xlabel("x (m)")
    ax3.set_ylabel("y (m)")
    ax3.set_zlabel("z (m)")
    ax3.legend(loc="upper left")
    ax3.set_title(title)
    t = rec.t
    e = np.linalg.norm(rec.position - rec.position_ref, axis=1) * 100
    ang = np.degrees(rotation_angle(rec.rotation, rec.rotation_desired))
    roll_err = np.degrees(np.arctan2(rec.rotation[:, 2, 1], rec.rotation[:, 2, 2]) - rec.roll_target)
    axes = [fig.add_subplot(3, 2, k) for k in (2, 4, 6)]
    axes[0].plot(t, e)
    axes[0].set_ylabel("position error (cm)")
    axes[1].plot(t, ang, label="attitude error vs R_d")
    axes[1].plot(t, roll_err, label="roll error vs target")
    axes[1].set_ylabel("deg")
    axes[1].legend(fontsize=8)
    axes[2].plot(t, rec.motors.max(axis=1) / u_max, label="max rotor")
    axes[2].plot(t, rec.motors.min(axis=1) / u_max, label="min rotor")
    axes[2].set_ylabel("u / u_max")
    axes[2].set_xlabel("time (s)")
    axes[2].legend(fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
        for name in (Phase.SETTLE, Phase.TRACK, Phase.HOLD, Phase.LANDING):
            starts = t[np.argmax(rec.phase == name)] if np.any(rec.phase == name) else None
            if starts is not None:
                ax.axvline(starts, color="grey", lw=0.6, ls=":")
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
