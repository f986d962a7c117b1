"""Figures of replayed flights, like the paper's Fig. 9: one or several logs overlaid.

Top left, the 3D trajectory of the tracking phase against the dashed reference (equal axes); top right, x, y and z
over time against the setpoint; middle, roll, pitch and yaw against the attitude target; bottom, the rotor commands
of each module as fractions of u_max with the bounds. Axis ranges never shrink below a readable span, so sensor
noise is not blown up to fill the plot.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from groundstation.control.phase import Phase
from groundstation.output import save_figure
from groundstation.replay.analysis import PHASES, Replay

COLORS = ("tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange", "tab:brown")
ROTOR_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red")
MIN_SPAN_M = 0.2
MIN_SPAN_DEG = 4.0
MAX_MODULE_PANELS = 4
"""Up to this many modules get a panel each (four rotors); more share one panel of per-module maxima."""


def _span(ax, values: np.ndarray, minimum: float) -> None:
    """Y range covering ``values``, at least ``minimum`` wide (centred)."""
    v = values[np.isfinite(values)]
    if v.size == 0:
        return
    lo, hi = float(v.min()), float(v.max())
    if hi - lo < minimum:
        mid = (hi + lo) / 2
        lo, hi = mid - minimum / 2, mid + minimum / 2
    pad = 0.05 * (hi - lo)
    ax.set_ylim(lo - pad, hi + pad)


def _label(r: Replay) -> str:
    roll = r.metadata["config"].get("trajectory", {}).get("roll_deg")
    return f"{r.path.stem}" + (f" (roll {roll:g} deg)" if roll is not None else "")


def plot_replays(replays: list[Replay], path: str | Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_mod = max(r.series.motors.shape[1] for r in replays)
    motor_panels = n_mod if n_mod <= MAX_MODULE_PANELS else 1
    fig = plt.figure(figsize=(15, 10.5))
    grid = fig.add_gridspec(4, 6, height_ratios=[1.2, 1, 1, 0.9], hspace=0.45, wspace=0.5)
    ax3 = fig.add_subplot(grid[0:2, 0:3], projection="3d")
    pos_axes = [fig.add_subplot(grid[0, 3 + k]) for k in range(3)]
    att_axes = [fig.add_subplot(grid[1, 3 + k]) for k in range(3)]
    big = [fig.add_subplot(grid[2, 2 * k:2 * k + 2]) for k in range(3)]
    motor_axes = [fig.add_subplot(grid[3, k * 6 // motor_panels:(k + 1) * 6 // motor_panels])
                  for k in range(motor_panels)]
    track = PHASES.index(Phase.TRACK)
    all_pts = []
    for c, r in zip(COLORS * 4, replays, strict=False):
        s = r.series
        tracking = s.phase == track
        ref = s.position_ref[tracking] if tracking.any() else s.position_ref
        flown = s.position[tracking] if tracking.any() else s.position
        ax3.plot(*ref.T, "k--", lw=0.9)
        ax3.plot(*flown.T, color=c, lw=1.3, label=_label(r))
        all_pts += [ref, flown]
        for k, name in enumerate("xyz"):
            ax = pos_axes[k]
            ax.plot(s.t, s.position_ref[:, k], "k--", lw=0.8)
            ax.plot(s.t, s.position[:, k], color=c, lw=1.0)
            ax.set_title(f"{name} (m)", fontsize=9)
        for k, name in enumerate(("roll", "pitch", "yaw")):
            ax = att_axes[k]
            ax.plot(s.t, s.rpy_target[:, k], "k--", lw=0.6, alpha=0.7)
            ax.plot(s.t, s.rpy[:, k], color=c, lw=1.0)
            ax.set_title(f"{name} (deg)", fontsize=9)
        err = np.linalg.norm(s.position - s.position_ref, axis=1) * 100
        big[0].plot(s.t, err, color=c, lw=1.0, label=_label(r))
        roll_err = s.rpy[:, 0] - s.rpy_target[:, 0]
        big[1].plot(s.t, roll_err, color=c, lw=1.0)
        big[2].plot(s.t, s.motors.reshape(len(s.t), -1).max(axis=1), color=c, lw=1.0)
        big[2].plot(s.t, s.motors.reshape(len(s.t), -1).min(axis=1), color=c, lw=0.8, ls=":")
        for i in range(s.motors.shape[1]):
            if motor_panels == 1:
                motor_axes[0].plot(s.t, s.motors[:, i].max(axis=1), lw=0.7, color=c)
            else:
                for q in range(4):  # one log: a colour per rotor; several: a colour per log
                    motor_axes[i].plot(s.t, s.motors[:, i, q], lw=0.7, color=ROTOR_COLORS[q] if len(replays) == 1
                                       else c, label=f"rotor {q + 1}" if len(replays) == 1 else None)
    pts = np.vstack(all_pts)
    centre, half = (pts.max(0) + pts.min(0)) / 2, max(float((pts.max(0) - pts.min(0)).max()) / 2, MIN_SPAN_M)
    for k, setter in enumerate((ax3.set_xlim, ax3.set_ylim, ax3.set_zlim)):
        setter(centre[k] - half, centre[k] + half)  # equal axes: the figure-8 keeps its shape
    ax3.set_box_aspect((1, 1, 1))
    ax3.set_xlabel("x (m)")
    ax3.set_ylabel("y (m)")
    ax3.set_zlabel("z (m)")
    ax3.set_title("tracking phase: flown vs reference (dashed)", fontsize=10)
    ax3.legend(loc="upper left", fontsize=8)
    for k, ax in enumerate(pos_axes):
        _span(ax, np.concatenate([r.series.position[:, k] for r in replays]), MIN_SPAN_M)
    for k, ax in enumerate(att_axes):
        _span(ax, np.concatenate([np.concatenate([r.series.rpy[:, k], r.series.rpy_target[:, k]])
                                  for r in replays]), MIN_SPAN_DEG)
    big[0].set_title("position error (cm)", fontsize=9)
    _span(big[0], np.concatenate([np.linalg.norm(r.series.position - r.series.position_ref, axis=1) * 100
                                  for r in replays]), 1.0)
    big[1].set_title("roll error vs target (deg)", fontsize=9)
    _span(big[1], np.concatenate([r.series.rpy[:, 0] - r.series.rpy_target[:, 0] for r in replays]), 1.0)
    big[2].set_title("max / min rotor command (u / u_max)", fontsize=9)
    big[0].legend(fontsize=7)
    for k, ax in enumerate(motor_axes):
        ax.axhline(1.0, color="grey", lw=0.8, ls="--")
        ax.axhline(0.0, color="grey", lw=0.8, ls="--")
        ax.set_ylim(-0.05, 1.05)
        ax.set_title("per-module max rotor (u / u_max)" if motor_panels == 1 else
                     f"module {k}: rotors 1-4 (u / u_max)", fontsize=9)
        if len(replays) == 1 and motor_panels > 1 and k == 0:
            ax.legend(fontsize=6, ncol=4, loc="lower right")
    big[2].axhline(1.0, color="grey", lw=0.8, ls="--")
    big[2].set_ylim(-0.05, 1.05)
    for ax in pos_axes + att_axes + big + motor_axes:
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("flight time (s)", fontsize=7)
    return save_figure(fig, path, dpi=100, bbox_inches="tight")
