"""Design figures: the assembly with its downwash capsules (paper Fig. 1), costs of the feasible candidates
(Fig. 5), the cost of every candidate against the input bound ``u_max`` (why Fig. 5 shows the candidates it
shows) and the force polytope at zero torque with the task forces (Fig. 6)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.optimize import linprog

from groundstation.assembly.assembly import Assembly
from groundstation.design.selection import CostCurve
from groundstation.output import save_figure


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_assembly(assembly: Assembly, path: str | Path, title: str = "") -> Path:
    """3D view: modules as squares, connections, thrust axes (red) and capsules (purple), like Fig. 1."""
    plt = _plt()
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    p = assembly.params
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    hx, hy, _ = p.frame_half_extents
    square = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]])
    for o, r in zip(assembly.module_positions, assembly.module_rotations, strict=True):
        ax.add_collection3d(Poly3DCollection([o + square @ r.T], color="black", alpha=0.9))
        z = r[:, 2]
        ax.quiver(*o, *(0.12 * z), color="red", linewidth=1.5)
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
    ax.set_title(title or f"{assembly.n} modules: {assembly.topology.code}")
    return save_figure(fig, path, dpi=110)


def plot_costs(rows: list[dict], n: int, path: str | Path) -> Path:
    """Bar chart of the cost of every feasible candidate with n modules (Fig. 5), best first."""
    plt = _plt()
    feas = sorted((r for r in rows if r["n"] == n and r["feasible"]), key=lambda r: r["cost"])
    fig, ax = plt.subplots(figsize=(max(5, 0.5 * len(feas) + 2), 3.5))
    ax.bar(range(len(feas)), [r["cost"] for r in feas], color="tab:blue")
    ax.set_xticks(range(len(feas)), [r["code"] for r in feas], rotation=60, fontsize=7, ha="right")
    ax.set_ylabel("J_cost ((rad/s)^4)")
    ax.set_title(f"Feasible configurations with {n} modules ({len(feas)} of {sum(r['n'] == n for r in rows)})")
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
    ax.set_ylabel("least J_cost found ((rad/s)^4)")
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


def plot_polytope(assembly: Assembly, forces: np.ndarray, path: str | Path) -> Path:
    """Force polytope at zero torque with the task's forces as arrows (Fig. 6)."""
    plt = _plt()
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from scipy.spatial import ConvexHull

    pts = force_polytope(assembly)
    fig = plt.figure(figsize=(6.5, 6))
    ax = fig.add_subplot(projection="3d")
    centre = pts.mean(axis=0)
    _, sv, vt = np.linalg.svd(pts - centre)
    if sv[2] > 1e-6 * sv[0]:
        hull = ConvexHull(pts)
        ax.add_collection3d(Poly3DCollection(pts[hull.simplices], alpha=0.15, facecolor="tab:gray",
                                             edgecolor="tab:gray", linewidths=0.3))
    else:  # planar polytope (e.g. the V cannot push along its hinge axis): a polygon in its own plane
        flat = (pts - centre) @ vt[:2].T
        ring = pts[ConvexHull(flat).vertices]
        ax.add_collection3d(Poly3DCollection([ring], alpha=0.25, facecolor="tab:gray", edgecolor="k"))
    colours = ["tab:blue", "tab:red", "tab:purple", "tab:green", "tab:orange"]
    for k, f in enumerate(forces):
        ax.quiver(0, 0, 0, *f, color=colours[k % len(colours)], linewidth=2, arrow_length_ratio=0.08)
    lim = np.abs(pts).max() * 1.05
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_zlim(0, lim)
    ax.set_xlabel("F_x (N)")
    ax.set_ylabel("F_y (N)")
    ax.set_zlabel("F_z (N)")
    ax.set_title(f"Force polytope at zero torque, {assembly.n} modules")
    return save_figure(fig, path, dpi=110)
