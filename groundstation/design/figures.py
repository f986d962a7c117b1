"""Design figures: the assembly with its downwash capsules (paper Fig. 1), costs of the candidates (Fig. 5), the
cost of every candidate against the input bound ``u_max`` (why Fig. 5 shows the candidates it shows) and the force
polytope at zero torque with the task forces (Fig. 6)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
from scipy.optimize import linprog

from groundstation.assembly import kinematics as kin
from groundstation.assembly.assembly import Assembly
from groundstation.design.selection import CostCurve
from groundstation.output import save_figure

COST_UNIT = "(rad/s)^4"
"""Unit of ``J_cost = sum_k lambda_k |u_k|^2`` with ``u`` in rad^2/s^2."""
FLAT = 1e-6
"""Singular values of the polytope's points below this fraction of the largest count as zero: the polytope lies
in a plane (or on a line) and is drawn in it."""
TASK_COLOURS = ("tab:blue", "tab:red", "tab:purple", "tab:green", "tab:orange", "tab:brown", "tab:pink")


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _deg(rad: float) -> str:
    """Degrees to two decimals, without the ``-0.00`` of a solver's ``-1e-30``."""
    return f"{round(float(np.degrees(rad)), 2) + 0.0:.2f}"


def design_angles(assembly: Assembly) -> tuple[str, ...]:
    """The design's angles, deg, each with its name, in the order the kinematics applies them: the root's yaw, x
    and y (``R_z(yaw) R_x(alpha_0) R_y(alpha_1)``: the assembly file's ``yaw_deg`` and ``angles_deg[:2]``), then
    the hinge of each connection ``parent-child`` (modules numbered as in the assembly file) with its axis in the
    parent's frame, breadth-first (``angles_deg[2:]``)."""
    alpha = np.asarray(assembly.alpha, float)
    root = (f"root yaw {_deg(assembly.yaw)}", f"root x {_deg(alpha[0])}", f"root y {_deg(alpha[1])}")
    return root + tuple(f"hinge {parent}-{child} ({kin.hinge_axis(connector)}) {_deg(a)}"
                        for (child, parent, connector), a in zip(assembly.topology.bfs_tree(), alpha[2:], strict=True))


def plot_assembly(assembly: Assembly, path: str | Path, cost: float) -> Path:
    """3D view like Fig. 1: modules as numbered squares, connections, rotors (by the sign of their yaw torque),
    thrust axes and downwash capsules, with a legend; the title gives the topology, the cost ``cost``
    ((rad/s)^4) and the angles (:func:`design_angles`)."""
    plt = _plt()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    p = assembly.params
    fig = plt.figure(figsize=(8, 7))
    ax = fig.add_subplot(projection="3d")
    hx, hy, _ = p.frame_half_extents
    square = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]])
    spin_colour = {1.0: "tab:orange", -1.0: "tab:green"}
    for i, (o, r) in enumerate(zip(assembly.module_positions, assembly.module_rotations, strict=True)):
        ax.add_collection3d(Poly3DCollection([o + square @ r.T], color="black", alpha=0.85))
        z = r[:, 2]
        ax.quiver(*o, *(0.12 * z), color="red", linewidth=1.5)
        # Its number, which the angles in the title name connections by: beside it, away from the centroid (the
        # origin) so that neighbours' numbers do not collide (a module at the centroid: above it); above every
        # depth-sorted square in zorder, or a module hides its own number.
        away = np.array([o[0], o[1], 0.0])
        away = away / np.linalg.norm(away) if np.linalg.norm(away) > hx else np.zeros(3)
        ax.text(*(o + 1.6 * hx * away + [0, 0, hx]), str(i), color="black", fontsize=8, fontweight="bold",
                ha="center", zorder=1000,
                bbox={"boxstyle": "round,pad=0.15", "facecolor": "white", "edgecolor": "none", "alpha": 0.8})
        a, b = o - p.capsule_a * z, o - p.capsule_b * z
        ax.plot(*np.array([a, b]).T, color="purple", lw=1)
        # a few rings to show the capsule radius
        u = np.cross(z, [1, 0, 0] if abs(z[0]) < 0.9 else [0, 1, 0])
        u /= np.linalg.norm(u)
        v = np.cross(z, u)
        ang = np.linspace(0, 2 * np.pi, 24)
        for c in np.linspace(0, 1, 4):
            ring = (a + c * (b - a)) + p.r * (np.outer(np.cos(ang), u) + np.outer(np.sin(ang), v))
            ax.plot(*ring.T, color="purple", alpha=0.25, lw=0.8)
    for s, colour in spin_colour.items():
        ax.scatter(*assembly.rotor_positions[assembly.rotor_spin == s].T, color=colour, s=14, depthshade=False)
    for i, j in assembly.topology.edges:
        ax.plot(*np.array([assembly.module_positions[i], assembly.module_positions[j]]).T, color="tab:blue", lw=3)
    pts = np.vstack([assembly.module_positions, assembly.module_positions - p.capsule_b *
                     assembly.module_rotations[:, :, 2]])
    c, half = pts.mean(axis=0), (pts.max(axis=0) - pts.min(axis=0)).max() / 2 + 0.1
    ax.set_xlim(c[0] - half, c[0] + half)
    ax.set_ylim(c[1] - half, c[1] + half)
    ax.set_zlim(c[2] - half, c[2] + half)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    handles = [Patch(color="black", label="module (number)"),
               Line2D([], [], color="tab:blue", lw=3, label="connection (hinge)"),
               *(Line2D([], [], color=colour, marker="o", ls="", label=f"rotor, yaw torque {'+' if s > 0 else '-'}")
                 for s, colour in spin_colour.items()),
               Line2D([], [], color="red", lw=1.5, label="thrust axis"),
               Line2D([], [], color="purple", lw=1, label=f"downwash capsule (radius {p.r:g} m)")]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=8, frameon=False)
    head = f"{assembly.topology.code}: {assembly.n} modules, J_cost = {cost:.5g} {COST_UNIT}"
    # no-break spaces inside each angle: a line breaks between angles, never between a name and its value
    angles = textwrap.fill("angles (deg): " + ", ".join(a.replace(" ", "\N{NO-BREAK SPACE}")
                                                        for a in design_angles(assembly)), 90)
    fig.suptitle(f"{head}\n{angles}", fontsize=9)
    title_in = 0.25 + 0.16 * (angles.count("\n") + 2)  # (a 12-module design's angles take four lines)
    fig.subplots_adjust(left=0.0, right=0.95, bottom=0.06, top=1 - title_in / fig.get_figheight())
    return save_figure(fig, path, dpi=110)


def _why_no_cost(row: dict) -> str:
    """Why a candidate has no bar: proven infeasible, or no start of the multi-start met the wrenches (which
    proves nothing), with the least input bound that makes it feasible when it was searched for."""
    if row["certificate"]:
        text = "certified infeasible (the proof is in design's output)"
    else:
        text = f"not found feasible (least residual {row['max_wrench_residual']:.3g}, {row['starts']} starts)"
    if row["never_feasible"]:
        text += "; no u_max makes it feasible"
    elif row["least_searched"] and np.isfinite(row["least_u_max"]):
        text += f"; feasible from u_max = {row['least_u_max']:.5g} rad^2/s^2"
    return text


def plot_costs(rows: list[dict], n: int, path: str | Path) -> Path:
    """The candidates with ``n`` modules (rows of :func:`results_table`, at least one feasible): the cost of each
    feasible one as percent above the best, least first (Fig. 5; bars from zero would hide the few percent that
    decide the design), the runner-up's gap annotated; below them the others, with why they have no cost."""
    plt = _plt()
    level = [r for r in rows if r["n"] == n]
    feas = sorted((r for r in level if r["feasible"]), key=lambda r: (r["cost"], r["code"]))
    others = sorted((r for r in level if not r["feasible"]), key=lambda r: (not r["certificate"], r["code"]))
    best = feas[0]["cost"]
    gaps = [100 * (r["cost"] / best - 1) for r in feas]
    fig, ax = plt.subplots(figsize=(8, max(3.0, 1.6 + 0.32 * len(level))))
    y = np.arange(len(level))
    ax.barh(y[:len(feas)], gaps, height=0.6, color="tab:blue")
    # the best's bar has no length: a marker shows where it is (unclipped: it sits on the axis)
    ax.plot([0], [0], "D", color="tab:green", ms=6, clip_on=False)
    span = max(max(gaps), 1.0)  # (1 % when the best is alone: an axis of zero width)
    for k, (r, gap) in enumerate(zip(feas, gaps, strict=True)):
        label = f"best, J_cost = {r['cost']:.5g} {COST_UNIT}" if k == 0 else \
            f"runner-up, +{gap:.2f} %" if k == 1 else f"+{gap:.2f} %"
        ax.annotate(label, (gap, k), xytext=(6, 0), textcoords="offset points", va="center", fontsize=8,
                    fontweight="bold" if k < 2 else "normal")
    for k, r in enumerate(others, len(feas)):
        ax.plot([0], [k], "x", color="tab:gray", ms=6, clip_on=False)
        ax.annotate(_why_no_cost(r), (0, k), xytext=(8, 0), textcoords="offset points", va="center", fontsize=8,
                    color="dimgray", style="italic")
    if others:
        ax.axhline(len(feas) - 0.5, color="tab:gray", lw=0.8, ls="--")
    ax.set_yticks(y, [r["code"] for r in feas + others], fontfamily="monospace", fontsize=8)
    ax.set_ylim(len(level) - 0.5, -0.5)  # least cost on top
    ax.set_xlim(0, 1.45 * span)  # room for the labels right of the longest bar
    ax.set_xlabel("cost above the best (%)")
    ax.grid(axis="x", alpha=0.3)
    ax.set_title(f"Candidates with {n} modules: {len(feas)} of {len(level)} feasible", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def plot_cost_against_bound(curves: list[CostCurve], nominal: float, n: int, path: str | Path) -> Path:
    """Least cost found against the input bound ``u_max``, one line per candidate from its least bound (a large
    dot), the nominal bound dotted; candidates no bound makes feasible are named in the legend."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9.5, 4.5))
    scale = 1e6
    for c in sorted(curves, key=lambda c: c.least_u_max):
        if not c.u_max:
            ax.plot([], [], " ", label=f"{c.code}: {'never feasible' if c.never_feasible else 'none found'}")
            continue
        (line,) = ax.plot(np.divide(c.u_max, scale), c.cost, marker=".", lw=1.2,
                          label=f"{c.code}: from {c.least_u_max / scale:.4f}e6")
        ax.plot(c.least_u_max / scale, c.cost[0], "o", color=line.get_color(), ms=7)
    ax.axvline(nominal / scale, color="k", ls=":", lw=1, label=f"module u_max {nominal / scale:g}e6")
    ax.set_xlabel("input bound u_max (1e6 rad^2/s^2)")
    ax.set_ylabel(f"least J_cost found ({COST_UNIT})")
    ax.set_title(f"Cost against the input bound, {n} modules")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def force_polytope(assembly: Assembly, directions: int = 300) -> np.ndarray:
    """Support points of the set of forces producible at zero torque within input bounds, N (body frame).

    For each of ``directions`` unit vectors d (Fibonacci sphere) solve the LP ``max d . A_F u`` s.t.
    ``A_tau u = 0, 0 <= u <= u_max``; the points span the polytope's convex hull.
    """
    a = assembly.allocation
    u_max = assembly.params.u_max
    k = np.arange(directions) + 0.5
    phi = np.arccos(1 - 2 * k / directions)
    theta = np.pi * (1 + 5**0.5) * k
    dirs = np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)])
    pts = []
    for d in dirs:
        res = linprog(-(d @ a[:3]) / (a[:3].max() + 1e-30), A_eq=a[3:] / (np.abs(a[3:]).max() + 1e-30),
                      b_eq=np.zeros(3), bounds=[(0, u_max)] * a.shape[1], method="highs")
        if res.status == 0:
            pts.append(a[:3] @ res.x)
    return np.array(pts)


def _task_colour(k: int) -> str:
    """The colour of task wrench ``k`` (0-based) in the polytope figure."""
    return TASK_COLOURS[k % len(TASK_COLOURS)]


def _axis_label(direction: np.ndarray) -> str:
    """An axis along the unit ``direction`` (body frame): ``F_x (N)`` when it is a coordinate axis, else the
    component of F along it."""
    k = int(np.argmax(np.abs(direction)))
    if abs(direction[k]) > 1 - FLAT:
        return f"F_{'xyz'[k]} (N)"
    return f"F along ({', '.join(f'{c:.2f}' for c in direction)}) (N)"


def _polytope_planes(pts: np.ndarray) -> list[np.ndarray]:
    """(2, 3) row bases of the planes to draw the polytope in: the coordinate planes x-z, y-z and x-y when it has
    volume; its own plane when it is flat (the vertical plane through it when it is a segment), with the vertical
    axis the in-plane direction nearest body z (up stays up) and the horizontal one made positive along its largest
    component."""
    _, sv, vt = np.linalg.svd(pts - pts.mean(axis=0))
    if sv[2] > FLAT * sv[0]:
        return [np.eye(3)[[0, 2]], np.eye(3)[[1, 2]], np.eye(3)[[0, 1]]]
    normal = vt[2]
    if sv[1] <= FLAT * sv[0]:  # a segment (one module's thrust axis): any plane holds it, the vertical one reads
        across = np.cross(vt[0], kin.E3)
        normal = across / np.linalg.norm(across) if np.linalg.norm(across) > FLAT else np.eye(3)[0]
    up = kin.E3 - (kin.E3 @ normal) * normal
    # (a polytope in a horizontal plane, which no thrust-making assembly has: its principal axes instead)
    up = up / np.linalg.norm(up) if np.linalg.norm(up) > FLAT else vt[1]
    side = np.cross(up, normal)
    side = side * np.sign(side[np.argmax(np.abs(side))])
    return [np.array([side, up])]


def _outline(points: np.ndarray) -> np.ndarray:
    """The closed boundary of the convex hull of 2D ``points``, or the segment between the extremes when they lie
    on a line (a single module makes forces along its thrust axis only)."""
    from scipy.spatial import ConvexHull

    centre = points.mean(axis=0)
    _, sv, vt = np.linalg.svd(points - centre)
    if sv[1] <= FLAT * sv[0]:
        t = (points - centre) @ vt[0]
        return points[[np.argmin(t), np.argmax(t)]]
    ring = points[ConvexHull(points).vertices]
    return np.vstack([ring, ring[:1]])


def plot_polytope(assembly: Assembly, forces: np.ndarray, path: str | Path) -> Path:
    """The force polytope at zero torque (:func:`force_polytope`) with the task's ``forces`` ((K, 3), N, body
    frame) as arrows named in the legend (Fig. 6), drawn as 2D projections a reader can measure: in the polytope's
    own plane when it is flat (a straight chain's, a V's), else onto the coordinate planes x-z, y-z and x-y. Each
    panel is scaled to its contents, so a narrow polytope stays readable (the axes are not to the same scale)."""
    plt = _plt()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    pts = force_polytope(assembly)
    planes = _polytope_planes(pts)
    forces = np.atleast_2d(forces)
    legend_in = 0.3 + 0.2 * ((len(forces) + 2) // 2)  # the polytope and K forces, two a row below the panels
    fig, axes = plt.subplots(1, len(planes), figsize=(max(4.6 * len(planes), 7), 4.8 + legend_in), squeeze=False)
    for ax, basis in zip(axes[0], planes, strict=True):
        ring = _outline(pts @ basis.T)
        ax.fill(*ring.T, color="tab:gray", alpha=0.25, lw=0)
        ax.plot(*ring.T, color="dimgray", lw=1)
        for k, f in enumerate(forces @ basis.T):
            arrow = {"arrowstyle": "-|>", "lw": 2, "shrinkA": 0, "shrinkB": 0, "color": _task_colour(k)}
            ax.annotate("", xy=f, xytext=(0, 0), arrowprops=arrow)
        ax.plot(0, 0, "k.", ms=5)
        ax.update_datalim(np.vstack([ring, forces @ basis.T, [[0, 0]]]))
        ax.autoscale_view()
        ax.margins(0.08)
        ax.set_xlabel(_axis_label(basis[0]))
        ax.set_ylabel(_axis_label(basis[1]))
        ax.grid(alpha=0.3)
    handles = [Patch(facecolor="tab:gray", alpha=0.4, edgecolor="dimgray", label="forces at zero torque"),
               *(Line2D([], [], color=_task_colour(k), lw=2,
                        label=f"wrench {k + 1}: F = ({', '.join(f'{c:.2f}' for c in f)}) N")
                 for k, f in enumerate(forces))]
    fig.legend(handles=handles, loc="lower center", ncol=2, fontsize=8, frameon=False)
    shape = "in its plane (it is flat)" if len(planes) == 1 else "projected onto the coordinate planes"
    fig.suptitle(f"Force polytope at zero torque, {shape}: {assembly.topology.code}, {assembly.n} modules\n"
                 "(each axis to its own scale)", fontsize=10)
    fig.tight_layout(rect=(0, legend_in / fig.get_figheight(), 1, 1))
    return save_figure(fig, path, dpi=110)
