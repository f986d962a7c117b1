"""What the design figures draw, read back from the matplotlib figure before it is saved: the costs as percent above
the best, the force polytope in readable projections with the task forces named, the assembly with a legend and its
angles and cost in the title."""

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from groundstation.assembly.assembly_file import checked_record
from groundstation.design import figures
from groundstation.design.selection import CandidateResult, results_table

ROOT = Path(__file__).resolve().parents[2]
TOY_V2 = ROOT / "configs/assemblies/toy_v2.json"  # the toy V design: its polytope is flat
FIG1_N12 = ROOT / "configs/assemblies/paper_fig1_n12.json"  # a 12-module design: its polytope has volume


@pytest.fixture
def drawn(monkeypatch):
    """The figures the plotting functions would save, kept open for inspection (closed at the end)."""
    import matplotlib.pyplot as plt

    kept = []

    def keep(fig, path, **_kwargs):
        kept.append(fig)
        return Path(path)

    monkeypatch.setattr(figures, "save_figure", keep)
    yield kept
    for fig in kept:
        plt.close(fig)


def _design(path: Path):
    record = json.loads(path.read_text())
    assembly, design = checked_record(record, str(path))
    return record, assembly, design


def _row(code: str, cost: float = math.inf, residual: float = 0.0, **fields) -> CandidateResult:
    return CandidateResult(4, code, "ok", math.isfinite(cost), cost, 0, 1.0, 0.1, residual, code, starts=24, **fields)


# The paper's §IV-C level at u_max = 4e6 (README's table): four feasible, the straight chain certified infeasible,
# the T and the O not found feasible (the T with its least bound searched).
IV_C = [_row("oSWS", 4.0988e14), _row("oSEE", 3.7251e14), _row("oSSE", 3.8627e14), _row("o(SW)E", 3.7909e14),
        _row("oEEE", certificate="every force of every design lies in one plane"),
        replace(_row("oS(W)E", residual=0.0581), least_searched=True, least_u_max=4.0568e6),
        _row("oSEN", residual=0.298)]


def test_costs_are_percent_above_the_best_least_first(drawn, tmp_path):
    rows = results_table(IV_C)
    figures.plot_costs(rows, 4, tmp_path / "fig5.png")
    ax = drawn[0].axes[0]
    feasible = sorted((r for r in rows if r["feasible"]), key=lambda r: r["cost"])
    best = feasible[0]["cost"]
    assert [p.get_width() for p in ax.patches] == pytest.approx([100 * (r["cost"] / best - 1) for r in feasible])
    assert [t.get_text() for t in ax.get_yticklabels()] == \
        ["oSEE", "o(SW)E", "oSSE", "oSWS", "oEEE", "oS(W)E", "oSEN"]  # the others listed below, none dropped
    notes = {t.get_text() for t in ax.texts}
    assert "runner-up, +1.77 %" in notes and "+10.03 %" in notes
    assert any(t.startswith("best, J_cost = 3.7251e+14") for t in notes)
    # a certificate proves infeasibility; a multi-start that met nothing does not
    assert sum(t.startswith("certified infeasible") for t in notes) == 1
    assert sum(t.startswith("not found feasible") for t in notes) == 2
    assert any("least residual 0.0581" in t and "feasible from u_max = 4.0568e+06" in t for t in notes)


def test_a_flat_polytope_is_drawn_in_its_plane_with_the_task_forces_named(drawn, tmp_path, monkeypatch):
    _, assembly, design = _design(TOY_V2)
    solved, solve = [], figures.force_polytope
    monkeypatch.setattr(figures, "force_polytope", lambda a: solved.append(solve(a)) or solved[0])
    figures.plot_polytope(assembly, design.wrenches[:, :3], tmp_path / "fig6.png")
    (ax,) = drawn[0].axes  # one 2D panel, no 3D view
    assert not hasattr(ax, "get_zlim")
    # the V hinges about x: every force lies in the y-z plane, drawn on its own axes in N
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("F_y (N)", "F_z (N)")
    (pts,) = solved
    outline = ax.lines[0].get_xydata()
    assert outline.min(axis=0) == pytest.approx(pts[:, 1:].min(axis=0), abs=1e-9)
    assert outline.max(axis=0) == pytest.approx(pts[:, 1:].max(axis=0), abs=1e-9)
    labels = [t.get_text() for t in drawn[0].legends[0].get_texts()]
    assert labels[1:] == ["wrench 1: F = (0.00, 0.36, 4.71) N", "wrench 2: F = (0.00, -0.36, 4.71) N",
                          "wrench 3: F = (0.00, 0.00, 4.71) N"]
    tips = [a.xy for a in ax.texts]  # the arrows end at the task forces, in the plane's coordinates
    assert np.array(tips) == pytest.approx(design.wrenches[:, 1:3])


def test_a_flat_polytope_off_the_coordinate_planes_uses_its_own_axes():
    yaw = np.radians(30.0)
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    pts = np.array([[0, y, z] for y in (-0.7, 0.7) for z in (0.0, 11.0)] + [[0, 0, 11.4]]) @ rz.T
    (basis,) = figures._polytope_planes(pts)
    assert basis @ basis.T == pytest.approx(np.eye(2))
    assert basis[1] == pytest.approx([0, 0, 1])  # up stays up
    assert basis[0] == pytest.approx(rz[:, 1])  # the V's y axis turned by the yaw
    assert figures._axis_label(basis[0]) == "F along (-0.50, 0.87, 0.00) (N)"


def test_a_polytope_with_volume_is_drawn_on_three_coordinate_planes(drawn, tmp_path):
    _, assembly, design = _design(FIG1_N12)
    figures.plot_polytope(assembly, design.wrenches[:, :3], tmp_path / "fig6.png")
    assert [(ax.get_xlabel(), ax.get_ylabel()) for ax in drawn[0].axes] == \
        [("F_x (N)", "F_z (N)"), ("F_y (N)", "F_z (N)"), ("F_x (N)", "F_y (N)")]
    for ax in drawn[0].axes:  # each panel scaled to its contents: the narrow sides are not squeezed flat
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        outline = ax.lines[0].get_xydata()
        assert np.ptp(outline[:, 0]) > 0.8 * (x1 - x0) and np.ptp(outline[:, 1]) > 0.8 * (y1 - y0)


def test_the_assembly_figure_names_what_it_draws_and_gives_the_angles_and_cost(drawn, tmp_path):
    record, assembly, design = _design(TOY_V2)
    figures.plot_assembly(assembly, tmp_path / "fig1.png", design.cost)
    fig = drawn[0]
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == ["module (number)", "connection (hinge)", "rotor, yaw torque +", "rotor, yaw torque -",
                      "thrust axis", "downwash capsule (radius 0.095 m)"]
    title = fig._suptitle.get_text().replace("\N{NO-BREAK SPACE}", " ")
    assert title.startswith(f"oS: 2 modules, J_cost = {design.cost:.5g} (rad/s)^4\nangles (deg): ")
    angles = figures.design_angles(assembly)
    assert all(a in title for a in angles)
    # the angles are the assembly file's, in degrees, named in the order the kinematics applies them
    deg = record["angles_deg"]
    assert angles == (f"root yaw {record['yaw_deg']:.2f}", f"root x {deg[0]:.2f}", f"root y {deg[1]:.2f}",
                      f"hinge 0-1 (x) {deg[2]:.2f}")
    assert sorted(t.get_text() for t in fig.axes[0].texts) == ["0", "1"]  # the modules the hinges name
