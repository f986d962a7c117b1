"""Drawings of lattice topologies like the paper's Fig. 2 and Fig. 3.

Each module is a black square; each connector is a small rectangle on a side of it: blue for a connection,
yellow for a connector blocked by an adjacent module it is not connected to, grey for a free connector.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from groundstation.assembly.lattice import DIRECTIONS
from groundstation.assembly.topology import BLOCKED, CONNECTED, FREE, Topology
from groundstation.output import save_figure

COLOURS = {CONNECTED: "#1f5fbf", BLOCKED: "#e8b70f", FREE: "#9a9a9a"}
MAX_DRAWN = 1000


def draw_topology(ax, topo: Topology, title: str | None = None, span: float | None = None) -> None:
    """Draw one topology on a matplotlib axes, lattice units (module pitch 1).

    ``span`` fixes the visible width and height (lattice units) so several drawings share one scale.
    """
    from matplotlib.patches import Rectangle

    half, conn_len, conn_w = 0.32, 0.26, 0.1
    mat = topo.to_matrix()
    h = mat.shape[0] // 2
    for x, y in topo.cells:
        ax.add_patch(Rectangle((x - half, y - half), 2 * half, 2 * half, color="black"))
        r, c = 2 * (h - 1 - y) + 1, 2 * x + 1
        for dx, dy in DIRECTIONS.tolist():
            state = int(mat[r - dy, c + dx])
            cx, cy = x + dx * (half + conn_w / 2 + 0.02), y + dy * (half + conn_w / 2 + 0.02)
            w, hh = (conn_w, conn_len) if dx else (conn_len, conn_w)
            if state == CONNECTED:  # a connection bridges the gap to the neighbour
                cx, cy = x + dx * 0.5, y + dy * 0.5
                w, hh = (1 - 2 * half, conn_len) if dx else (conn_len, 1 - 2 * half)
            ax.add_patch(Rectangle((cx - w / 2, cy - hh / 2), w, hh, color=COLOURS[state]))
    xs = [x for x, _ in topo.cells]
    ys = [y for _, y in topo.cells]
    span = span or max(max(xs) - min(xs), max(ys) - min(ys)) + 1.4
    mid_x, mid_y = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2
    ax.set_xlim(mid_x - span / 2, mid_x + span / 2)
    ax.set_ylim(mid_y - span / 2, mid_y + span / 2)
    ax.set_aspect("equal")
    ax.axis("off")
    if title:
        ax.set_title(title, fontsize=7)


def draw_level(topologies: Sequence[Topology], path: str | Path, title: str) -> Path:
    """Draw every topology of a level in a grid and save it as an image (PNG by suffix)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    count = len(topologies)
    if count > MAX_DRAWN:
        raise ValueError(f"{count} configurations are too many to draw legibly (at most {MAX_DRAWN})")
    cols = max(1, math.ceil(math.sqrt(count * 1.5)))
    rows = math.ceil(count / cols)
    title_in = 0.6  # a band of its own for the title: tight_layout lays out the axes only, and the n = 7 sheet's
    # title sat on its first row
    height = 1.6 * rows + title_in
    fig, axes = plt.subplots(rows, cols, figsize=(1.6 * cols, height), squeeze=False)
    span = 1.4 + max(max(max(x, y) for x, y in t.cells) for t in topologies)
    for k, ax in enumerate(axes.flat):
        if k < count:
            draw_topology(ax, topologies[k], f"({k + 1}) {topologies[k].code}", span=span)
        else:
            ax.axis("off")
    # As large as reads well on a big sheet, small enough to fit a sheet of two (a character is ~0.6 em wide).
    size = min(14.0, 0.95 * 72 * 1.6 * cols / (0.6 * len(title)))
    fig.suptitle(title, fontsize=size, y=1 - 0.15 * title_in / height)
    fig.tight_layout(rect=(0, 0, 1, 1 - title_in / height))
    return save_figure(fig, path, dpi=110)
