"""The flight figure of ``simulate --plot`` and ``replay --plot``, in the style of the paper's Fig. 9: several
flights side by side, a column each, sized for print (a column is 3.5 in wide, an IEEE column; fonts 6-7 pt at
that size); one flight fills two columns, its 3D path beside its time panels.

For each flight: the 3D path of the tracking phase against its dashed reference, on equal axes, with the body's
axes drawn along it; the tracking error along x, y and z; roll, pitch and yaw against their dashed targets (an
angle the assembly does not track, the pitch of the two-module V, is drawn alone and says so: its "target" is what
the force asked for); each module's rotor commands as an envelope with the time spent at each bound. Phases are
shaded in every time panel; the title names the assembly, the config, the date and the code version (what the
flights share in the figure's title, the rest in each column's). Rows share their axis ranges across columns, so
the flights compare at a glance.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from groundstation.control.phase import Phase
from groundstation.output import save_figure
from groundstation.runtime.metrics import SATURATED

if TYPE_CHECKING:  # replay imports the Series from here, and needs none of the flight loop's modules
    from groundstation.runtime.closed_loop import FlightRecord

COLUMN_IN = 3.5
"""Width of one flight's column, in (an IEEE column: two flights fill a double-column figure)."""
HEIGHT_IN = 8.6
"""Height of a figure of several flights, in."""
SINGLE_HEIGHT_IN = 4.6
"""Height of a figure of one flight (two columns wide: the 3D path beside the time panels), in."""
DPI = 300
"""Resolution of a raster figure: print quality at the size above."""
STYLE = {"font.size": 7, "axes.titlesize": 7, "axes.labelsize": 7, "xtick.labelsize": 6, "ytick.labelsize": 6,
         "legend.fontsize": 6, "lines.linewidth": 0.8, "axes.linewidth": 0.5, "xtick.major.width": 0.5,
         "ytick.major.width": 0.5, "xtick.major.size": 2.5, "ytick.major.size": 2.5, "grid.linewidth": 0.4}
"""Matplotlib settings of the figure, sized for COLUMN_IN."""
FLOWN = "tab:blue"
AXIS_COLORS = ("tab:red", "tab:green", "0.1")
"""Body x, y and z in the 3D panel."""
MODULE_COLORS = ("tab:orange", "tab:purple", "tab:olive", "tab:brown")
MAX_MODULE_BANDS = len(MODULE_COLORS)
"""Up to this many modules get a band each; more share one band (every rotor of the assembly)."""
PHASE_SHADES = {Phase.TAKEOFF: "0.86", Phase.LANDING: "0.86", Phase.SETTLE: "0.94", Phase.HOLD: "0.94",
                Phase.EMERGENCY: "mistyrose"}
"""Background of each phase in the time panels (tracking: none)."""
ANGLES = ("roll", "pitch", "yaw")
MIN_SPAN_3D_M = 0.3
"""Smallest range of a 3D axis, m: a hover is not blown up to fill the box."""
MIN_ERROR_CM = 0.5
"""Smallest half range of an error panel, cm: sensor noise is not blown up to fill it."""
MIN_SPAN_DEG = 4.0
"""Smallest range of an attitude panel, deg."""
TRIAD_SHARE = 0.08
"""Length of a drawn body axis, share of the 3D box's largest range."""
TRIAD_SPACING = 2.6
"""Body axes are drawn at least this many axis lengths apart along the path (a second lap over the first adds
none where it retraces it)."""
ENVELOPE_S = 0.2
"""A rotor envelope spans the commands' least and largest value in windows this long, s."""


@dataclass(frozen=True, eq=False)
class Series:
    """Time series of a flight, at its control periods (or an evenly decimated share of them)."""

    t: np.ndarray
    """(k,) flight time, s."""
    position: np.ndarray
    """(k, 3) flown (the physics truth in simulation), m."""
    position_ref: np.ndarray
    """(k, 3) the reference, m."""
    rotation: np.ndarray
    """(k, 3, 3) body to world, flown."""
    rpy_target: np.ndarray
    """(k, 3) ZYX roll, pitch and yaw of the attitude the controller aimed at, deg."""
    motors: np.ndarray
    """(k, n, 4) rotor commands, fractions of u_max."""
    phase: np.ndarray
    """(k,) the phase of each row (:class:`Phase` values)."""


@dataclass(frozen=True, eq=False)
class FlightTrace:
    """One flight as the figure draws it."""

    label: str
    """What the flight is, first line of its column's title (e.g. the trajectory and the roll target)."""
    facts: tuple[tuple[str, str], ...]
    """(name, value) pairs for the titles: assembly, config, date, code version, log."""
    series: Series
    free_angles: tuple[str, ...]
    """ZYX angles the assembly does not track (set by the force: the V's pitch), drawn without a target."""


def rpy_deg(rotation: np.ndarray) -> np.ndarray:
    """(k, 3) ZYX roll, pitch, yaw of (k, 3, 3) rotations, deg (the log's ``rpy_deg``)."""
    r = rotation
    return np.degrees(np.column_stack([np.arctan2(r[:, 2, 1], r[:, 2, 2]), -np.arcsin(np.clip(r[:, 2, 0], -1, 1)),
                                       np.arctan2(r[:, 1, 0], r[:, 0, 0])]))


def bound_seconds(t: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(g, 2): for each group of rotors of ``u`` (k, g, r), fractions of u_max, at rows ``t`` (k,) s: the time one
    of them spent at 0 and at u_max (at the metrics' saturation threshold), s: rows at the bound times the rows'
    median spacing (of a decimated series: an estimate)."""
    row_s = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return np.column_stack([(u <= 1.0 - SATURATED).any(axis=2).sum(axis=0),
                            (u >= SATURATED).any(axis=2).sum(axis=0)]) * row_s


def _phase_runs(s: Series) -> list[tuple[str, float, float]]:
    """(phase, start s, end s) of each stretch of one phase; a stretch ends where the next begins."""
    p, t = s.phase, s.t
    starts = np.flatnonzero(np.r_[True, p[1:] != p[:-1]])
    ends = np.r_[t[starts[1:]], t[-1]]
    return [(str(p[i]), float(t[i]), float(e)) for i, e in zip(starts, ends, strict=True)]


def _tracking(s: Series) -> np.ndarray:
    """Rows of the tracking phase (every row of a flight that never tracked)."""
    rows = s.phase == Phase.TRACK
    return rows if rows.any() else np.ones(s.t.size, bool)


def _title_parts(traces: Sequence[FlightTrace]) -> tuple[str, list[str]]:
    """The figure's title (the facts every flight shares) and each column's (its label and the rest)."""
    shared = [f for f in traces[0].facts if all(f in tr.facts for tr in traces)]
    own = [" | ".join(value for name, value in tr.facts if (name, value) not in shared) for tr in traces]
    return " | ".join(value for _, value in shared), [tr.label + ("\n" + o if o else "") for tr, o in
                                                       zip(traces, own, strict=True)]


def _envelope(t: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Window centres (s) and the least and largest of ``u`` (k, m: every rotor of a band) in each window."""
    bins = np.floor((t - t[0]) / ENVELOPE_S).astype(int)
    starts = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])
    ends = np.r_[starts[1:], t.size] - 1
    return ((t[starts] + t[ends]) / 2, np.minimum.reduceat(u.min(axis=1), starts),
            np.maximum.reduceat(u.max(axis=1), starts))


def _bands(s: Series) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, rotor commands (k, r), time at 0 and at u_max (2,) s) of each band of the rotor panel: one per module,
    or one of every rotor for an assembly of more than MAX_MODULE_BANDS modules."""
    k, n = s.motors.shape[:2]
    groups, names = ((s.motors, [f"module {i}" for i in range(n)]) if n <= MAX_MODULE_BANDS
                     else (s.motors.reshape(k, 1, -1), [f"all {n} modules"]))
    times = bound_seconds(s.t, groups)
    return [(name, groups[:, i], times[i]) for i, name in enumerate(names)]


def _limits_3d(traces: Sequence[FlightTrace]) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre and range (m) of each 3D axis, over every flight's tracking phase, and the drawn body axes' length:
    one unit is as long on every axis, and every column shows the same box."""
    pts = np.vstack([np.vstack([s.position[_tracking(s)], s.position_ref[_tracking(s)]])
                     for s in (tr.series for tr in traces)])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    axis_len = TRIAD_SHARE * max(float((hi - lo).max()), MIN_SPAN_3D_M)
    return (lo + hi) / 2, np.maximum(hi - lo, MIN_SPAN_3D_M) + 2 * axis_len, axis_len


def _triad_rows(t: np.ndarray, p: np.ndarray, spacing: float) -> list[int]:
    """Rows at which to draw the body axes: every 0.1 s a candidate, kept when ``spacing`` (m) from every one
    kept before it."""
    kept: list[int] = []
    for i in np.unique(np.searchsorted(t, np.arange(t[0], t[-1], 0.1))):
        if all(np.linalg.norm(p[i] - p[j]) >= spacing for j in kept):
            kept.append(int(i))
    return kept


def _draw_path(ax, s: Series, centre: np.ndarray, span: np.ndarray, axis_len: float) -> None:
    from matplotlib.legend_handler import HandlerTuple
    from matplotlib.lines import Line2D
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    rows = _tracking(s)
    flown = ax.plot(*s.position[rows].T, color=FLOWN, lw=1.4, label="flown")[0]
    reference = ax.plot(*s.position_ref[rows].T, "k", ls=(0, (3, 3)), lw=0.6, label="reference")[0]  # on top:
    # millimetres apart, the flown line shows between its dashes
    t, p, r = s.t[rows], s.position[rows], s.rotation[rows]
    at = _triad_rows(t, p, TRIAD_SPACING * axis_len)
    for k, color in enumerate(AXIS_COLORS):
        ends = p[at] + axis_len * r[at][:, :, k]  # column k of R: body axis k in the world
        ax.add_collection3d(Line3DCollection(np.stack([p[at], ends], axis=1), colors=color, linewidths=0.9))
    for k, setter in enumerate((ax.set_xlim, ax.set_ylim, ax.set_zlim)):
        setter(centre[k] - span[k] / 2, centre[k] + span[k] / 2)
    ax.set_box_aspect(tuple(span), zoom=1.12)  # equal units: the figure-8 keeps its shape
    ax.view_init(elev=28, azim=-40)  # the figure-8 shows its two loops and its tilted plane
    ax.set_xlabel("x (m)", labelpad=-6)
    ax.set_ylabel("y (m)", labelpad=-5)
    ax.set_zlabel("z (m)", labelpad=-9)
    ax.tick_params(pad=-3)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(_locator(4))
    body = tuple(Line2D([], [], color=color, lw=0.9) for color in AXIS_COLORS)
    ax.legend([reference, flown, body], ["reference", "flown", "body x, y, z"], loc="upper center", ncol=3,
              frameon=False, handlelength=2.2, borderaxespad=0, bbox_to_anchor=(0.5, 1.0),
              handler_map={tuple: HandlerTuple(ndivide=None, pad=0.2)})


def _locator(n: int):
    from matplotlib.ticker import MaxNLocator

    return MaxNLocator(n, steps=[1, 2, 2.5, 5, 10])


def _shade(ax, runs: list[tuple[str, float, float]]) -> None:
    for name, t0, t1 in runs:
        if name in PHASE_SHADES:
            ax.axvspan(t0, t1, color=PHASE_SHADES[name], lw=0, zorder=0)


def _symmetric(axes, values: list[np.ndarray], minimum: float) -> None:
    """The same y range on ``axes``, symmetric about 0, covering ``values`` and at least +-``minimum``."""
    top = max([minimum] + [float(np.nanmax(np.abs(v))) for v in values if v.size])
    for ax in axes:
        ax.set_ylim(-1.08 * top, 1.08 * top)


def _spanning(axes, values: list[np.ndarray], minimum: float) -> None:
    """The same y range on ``axes`` covering ``values``, at least ``minimum`` wide (centred)."""
    v = np.concatenate([x[np.isfinite(x)] for x in values])
    lo, hi = (float(v.min()), float(v.max())) if v.size else (0.0, 0.0)
    if hi - lo < minimum:
        lo, hi = (lo + hi - minimum) / 2, (lo + hi + minimum) / 2
    for ax in axes:
        ax.set_ylim(lo - 0.06 * (hi - lo), hi + 0.06 * (hi - lo))


TIME_ROWS = ("error x", "error y", "error z", *ANGLES, "rotors")
"""The time panels of a flight, by name (each Axes' label is ``"<column>:<name>"``, with ``"trajectory"``)."""


def _layout(fig, cols: int) -> list[dict]:
    """The axes of each flight by name. One flight: the 3D path above the rotors on the left, errors and angles on
    the right (a landscape figure). Several: a column each, the 3D path above its time panels."""
    if cols == 1:
        outer = fig.add_gridspec(1, 2, width_ratios=[1.0, 1.05], wspace=0.3, left=0.06, right=0.985, top=0.9,
                                 bottom=0.13)
        left = outer[0].subgridspec(2, 1, height_ratios=[2.6, 1.15], hspace=0.12)
        slots = [{"trajectory": left[0], "rotors": left[1],
                  **dict(zip(TIME_ROWS[:-1], outer[1].subgridspec(6, 1, hspace=0.16), strict=True))}]
    else:
        outer = fig.add_gridspec(2, cols, height_ratios=[2.3, 5.0], hspace=0.05, wspace=0.3, left=0.13 / cols,
                                 right=1 - 0.07 / cols, top=0.925, bottom=0.075)
        slots = [{"trajectory": outer[0, c], **dict(zip(TIME_ROWS, outer[1, c].subgridspec(
            len(TIME_ROWS), 1, hspace=0.18, height_ratios=[1] * 6 + [1.5]), strict=True))} for c in range(cols)]
    out = []
    for c, slot in enumerate(slots):
        axes = {"trajectory": fig.add_subplot(slot["trajectory"], projection="3d", label=f"{c}:trajectory")}
        first = None
        for name in TIME_ROWS:
            axes[name] = fig.add_subplot(slot[name], sharex=first, label=f"{c}:{name}")
            first = first or axes[name]
        out.append(axes)
    return out


def _draw(plt, traces: Sequence[FlightTrace]):
    import textwrap

    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    cols = len(traces)
    width = COLUMN_IN * max(cols, 2)
    fig = plt.figure(figsize=(width, HEIGHT_IN if cols > 1 else SINGLE_HEIGHT_IN))
    title, column_titles = _title_parts(traces)
    fig.suptitle(textwrap.fill(title, int(width * 18)), fontsize=7, y=0.99)
    centre, span, axis_len = _limits_3d(traces)
    panels = _layout(fig, cols)
    errors = [(tr.series.position - tr.series.position_ref) * 100 for tr in traces]  # cm
    angles = [rpy_deg(tr.series.rotation) for tr in traces]
    for tr, axes, column_title, error, rpy in zip(traces, panels, column_titles, errors, angles, strict=True):
        s = tr.series
        _draw_path(axes["trajectory"], s, centre, span, axis_len)
        axes["trajectory"].set_title(column_title, fontsize=7, pad=0)
        runs = _phase_runs(s)
        for name in TIME_ROWS:
            ax = axes[name]
            _shade(ax, runs)
            ax.grid(alpha=0.35)
            ax.yaxis.set_major_locator(_locator(3))
            ax.set_xlim(s.t[0], s.t[-1])
        for k in range(3):
            ax = axes[TIME_ROWS[k]]
            ax.axhline(0.0, color="k", lw=0.4)
            ax.plot(s.t, error[:, k], color=FLOWN, lw=0.7)
            ax.set_ylabel(f"$e_{'xyz'[k]}$ (cm)")
        for a, name in enumerate(ANGLES):
            ax = axes[name]
            ax.plot(s.t, rpy[:, a], color=FLOWN, lw=0.7)
            ax.set_ylabel(f"{name} (deg)")
            if name in tr.free_angles:
                # top left: over the take-off, where the angle is level (placed over tracking, it hid peaks)
                ax.text(0.01, 0.93, "not tracked", transform=ax.transAxes, ha="left", va="top", fontsize=5.5,
                        fontstyle="italic", bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 0.8})
            else:
                ax.plot(s.t, s.rpy_target[:, a], "k--", lw=0.7, label="target")
        ax = axes["rotors"]
        for (band, u, times), color in zip(_bands(s), MODULE_COLORS, strict=False):
            x, lo, hi = _envelope(s.t, u)
            ax.fill_between(x, lo, hi, color=color, alpha=0.45, lw=0,
                            label=f"{band}: {times[0]:.2f} s at 0, {times[1]:.2f} s at u_max")
        for bound in (0.0, 1.0):
            ax.axhline(bound, color="0.3", lw=0.5, ls=":")
        ax.set_ylim(-0.05, 1.5)  # the legend above the upper bound
        ax.set_yticks([0, 0.5, 1])
        ax.set_ylabel("$u/u_{max}$")
        ax.legend(loc="upper center", ncol=1, frameon=False, borderaxespad=0.1, handlelength=1.2,
                  labelspacing=0.15)
        for name in TIME_ROWS:  # the time axis is labelled under the lowest panel of each stack only
            below = axes[name].get_subplotspec().rowspan.stop < axes[name].get_subplotspec().get_gridspec().nrows
            axes[name].tick_params(labelbottom=not below)
            axes[name].set_xlabel("" if below else "flight time (s)")
    for k in range(3):
        _symmetric([axes[TIME_ROWS[k]] for axes in panels], [e[:, k] for e in errors], MIN_ERROR_CM)
    for a, name in enumerate(ANGLES):
        _spanning([axes[name] for axes in panels], [rpy[:, a] for rpy in angles] +
                  [tr.series.rpy_target[:, a] for tr in traces if name not in tr.free_angles], MIN_SPAN_DEG)
    fig.align_ylabels([panels[0][name] for name in TIME_ROWS[:6 if cols == 1 else None]])  # one stack
    handles = [Line2D([], [], color=FLOWN, lw=0.9, label="flown"),
               Line2D([], [], color="k", ls="--", lw=0.8, label="target / reference"),
               Patch(color=PHASE_SHADES[Phase.TAKEOFF], label="take-off, landing"),
               Patch(color=PHASE_SHADES[Phase.SETTLE], label="settle, hold"),
               Patch(facecolor="white", edgecolor="0.6", lw=0.4, label="tracking")]
    if any((tr.series.phase == Phase.EMERGENCY).any() for tr in traces):
        handles.append(Patch(color=PHASE_SHADES[Phase.EMERGENCY], label="emergency"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False, bbox_to_anchor=(0.5, 0.0),
               handlelength=1.6, columnspacing=1.2)
    return fig


def flight_figure(traces: Sequence[FlightTrace]):
    """The figure of ``traces``, one column each, as a matplotlib Figure (closed by :func:`save_flight_figure`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with matplotlib.rc_context(STYLE):
        return _draw(plt, traces)


def save_flight_figure(traces: Sequence[FlightTrace], path: str | Path) -> Path:
    """Draw ``traces`` (:func:`flight_figure`) into ``path`` (PNG, SVG or PDF)."""
    return save_figure(flight_figure(traces), path, dpi=DPI)


def assembly_fact(name: str, n: int, dof: int | None) -> tuple[str, str]:
    """The title's assembly entry: its file's name, its module count and controllable DOF."""
    return "assembly", f"{name} (n = {n}" + (f", {dof} DOF)" if dof is not None else ")")


def date_fact(epoch_s: float) -> tuple[str, str]:
    """The title's date entry, UTC to the minute."""
    return "date", dt.datetime.fromtimestamp(epoch_s, dt.UTC).strftime("%Y-%m-%d %H:%M UTC")


def trace_of_record(rec: FlightRecord, label: str, facts: tuple[tuple[str, str], ...],
                    free_angles: tuple[str, ...], u_max: float) -> FlightTrace:
    """The trace of a flight recorded in this process (``simulate``); ``u_max`` scales its rotor commands."""
    return FlightTrace(label, facts, Series(rec.t, rec.position, rec.position_ref, rec.rotation,
                                            rpy_deg(rec.rotation_desired),
                                            rec.motors.reshape(rec.t.size, -1, 4) / u_max, rec.phase), free_angles)
