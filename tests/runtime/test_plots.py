"""The flight figure's content, from traces made here with known answers: the dashed reference in the legend, equal
3D axes, per-axis errors, the untracked angle without a target, the rotor envelopes' time at each bound, the
titles, print-size fonts; and the trace of a flight recorded in process (``simulate``)."""

from dataclasses import replace

import matplotlib
import numpy as np
import pytest

from groundstation.control.trajectory import euler_zyx
from groundstation.runtime.closed_loop import FlightRecord
from groundstation.runtime.plots import FlightTrace, Series, flight_figure, save_flight_figure, trace_of_record

matplotlib.use("Agg")

RATE_HZ = 250.0
PHASES = (("takeoff", 1.0), ("settle", 0.5), ("track", 4.0), ("hold", 0.5), ("landing", 1.0))


def _trace(label: str, roll_deg: float, facts=(), zero_rows=0, full_rows=0, free=("pitch",)) -> FlightTrace:
    """A 7 s flight at 250 Hz: a figure-8 flown 3 mm off the reference along x and 1 mm along z, the roll target
    held; module 0's rotor 3 at 0 for ``zero_rows`` tracking periods, module 1's rotor 0 at u_max for
    ``full_rows``."""
    phase = np.concatenate([[name] * int(d * RATE_HZ) for name, d in PHASES])
    t = np.arange(phase.size) / RATE_HZ
    s = 2 * np.pi * t / 4.0
    ref = np.column_stack([0.6 * np.sin(s) * np.cos(s), 0.6 * np.sin(s), 1.0 - 0.2 * np.sin(s)])
    position = ref + np.array([0.003, 0.0, -0.001]) * np.sin(3 * s)[:, None]
    pitch = 3.0 * np.sin(s)
    rotation = np.array([euler_zyx(np.radians(roll_deg), np.radians(p), 0.0) for p in pitch])
    target = np.column_stack([np.full(t.size, roll_deg), pitch + 0.5, np.zeros(t.size)])
    motors = np.full((t.size, 2, 4), 0.45) + 0.1 * np.sin(s)[:, None, None]
    track = np.flatnonzero(phase == "track")
    motors[track[:zero_rows], 0, 3] = 0.0
    motors[track[-full_rows:] if full_rows else [], 1, 0] = 1.0
    return FlightTrace(label, facts, Series(t, position, ref, rotation, target, motors, phase), free)


FACTS = (("assembly", "toy_v2 (n = 2, 5 DOF)"), ("config", "roll0.toml"), ("date", "2026-12-02 10:00 UTC"),
         ("code", "code 0.1.0 (abc)"))


@pytest.fixture(scope="module")
def two():
    a = _trace("figure8, roll target 0 deg", 0.0, FACTS)
    b = _trace("figure8, roll target -5 deg", -5.0, FACTS[:1] + (("config", "roll-5.toml"),) + FACTS[2:],
               zero_rows=50, full_rows=25)
    fig = flight_figure([a, b])
    yield fig, (a, b)
    matplotlib.pyplot.close(fig)


def axes(fig, label: str):
    (ax,) = [ax for ax in fig.axes if ax.get_label() == label]
    return ax


def test_each_flight_has_its_dashed_reference_in_the_legend(two):
    fig, traces = two
    for c, tr in enumerate(traces):
        ax = axes(fig, f"{c}:trajectory")
        (ref,) = [line for line in ax.get_lines() if line.get_label() == "reference"]
        assert ref.get_linestyle() == "--" and matplotlib.colors.to_hex(ref.get_color()) == "#000000"
        track = tr.series.phase == "track"
        np.testing.assert_allclose(np.column_stack(ref.get_data_3d()), tr.series.position_ref[track])
        assert [t.get_text() for t in ax.get_legend().get_texts()] == ["reference", "flown", "body x, y, z"]


def test_the_3d_axes_are_equal_and_shared(two):
    fig, _ = two
    limits = []
    for c in range(2):
        ax = axes(fig, f"{c}:trajectory")
        spans = np.array([np.ptp(ax.get_xlim3d()), np.ptp(ax.get_ylim3d()), np.ptp(ax.get_zlim3d())])
        aspect = np.array(ax.get_box_aspect())
        np.testing.assert_allclose(spans / spans.max(), aspect / aspect.max(), rtol=1e-9)  # a metre is a metre
        limits.append((ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()))
    assert limits[0] == limits[1]


def test_the_body_axes_are_drawn_along_the_path(two):
    fig, traces = two
    ax = axes(fig, "1:trajectory")
    segments = [np.array(c._segments3d) for c in ax.collections]
    assert len(segments) == 3 and 8 <= len(segments[0]) <= 40  # x, y, z at a spacing, not every period
    tr = traces[1]
    for k, axis in enumerate(segments):
        rows = [int(np.flatnonzero((tr.series.position == start).all(axis=1))[0]) for start in axis[:, 0]]
        assert all(tr.series.phase[r] == "track" for r in rows)
        direction = (axis[:, 1] - axis[:, 0]) / np.linalg.norm(axis[:, 1] - axis[:, 0], axis=1)[:, None]
        np.testing.assert_allclose(direction, tr.series.rotation[rows][:, :, k], atol=1e-12)  # column k: body axis k
    assert np.ptp(axes(fig, "1:trajectory").get_ylim3d()) > 10 * np.linalg.norm(axis[0, 1] - axis[0, 0])


def test_per_axis_tracking_error(two):
    fig, traces = two
    for c, tr in enumerate(traces):
        expected = (tr.series.position - tr.series.position_ref) * 100  # cm
        for k, name in enumerate("xyz"):
            ax = axes(fig, f"{c}:error {name}")
            (line,) = [li for li in ax.get_lines() if len(li.get_xdata()) == tr.series.t.size]
            np.testing.assert_allclose(line.get_ydata(), expected[:, k])
            assert ax.get_ylabel() == f"$e_{name}$ (cm)"
    assert axes(fig, "0:error x").get_ylim() == axes(fig, "1:error x").get_ylim()  # rows compare across flights


def test_an_untracked_angle_has_no_target(two):
    fig, traces = two
    tr = traces[1]
    pitch = axes(fig, "1:pitch")
    assert [li.get_label() for li in pitch.get_lines() if li.get_label() == "target"] == []
    assert any(t.get_text() == "not tracked" for t in pitch.texts)
    roll = axes(fig, "1:roll")
    (target,) = [li for li in roll.get_lines() if li.get_label() == "target"]
    assert target.get_linestyle() == "--"
    np.testing.assert_allclose(target.get_ydata(), tr.series.rpy_target[:, 0])
    flown = [li for li in roll.get_lines() if li.get_label() != "target" and len(li.get_xdata()) == tr.series.t.size]
    np.testing.assert_allclose(flown[0].get_ydata(), -5.0, atol=1e-9)
    tracked = flight_figure([_trace("6 DOF", 0.0, free=())])
    try:
        assert [li.get_label() for li in axes(tracked, "0:pitch").get_lines()].count("target") == 1
    finally:
        matplotlib.pyplot.close(tracked)


def test_the_rotor_envelopes_say_the_time_at_each_bound(two):
    fig, traces = two
    texts = [t.get_text() for t in axes(fig, "1:rotors").get_legend().get_texts()]
    # an independent count: 50 periods at 0 (module 0), 25 at u_max (module 1), 4 ms each
    assert texts == [f"module 0: {50 / RATE_HZ:.2f} s at 0, 0.00 s at u_max",
                     f"module 1: 0.00 s at 0, {25 / RATE_HZ:.2f} s at u_max"]
    assert [t.get_text() for t in axes(fig, "0:rotors").get_legend().get_texts()] == [
        "module 0: 0.00 s at 0, 0.00 s at u_max", "module 1: 0.00 s at 0, 0.00 s at u_max"]
    bands = axes(fig, "1:rotors").collections
    assert len(bands) == 2  # a band per module, not a line per rotor
    top = bands[1].get_paths()[0].vertices[:, 1].max()
    assert top == pytest.approx(1.0)  # the envelope reaches the bound the rotor sat at


def test_titles_ticks_and_phases(two):
    fig, traces = two
    assert fig._suptitle.get_text() == "toy_v2 (n = 2, 5 DOF) | 2026-12-02 10:00 UTC | code 0.1.0 (abc)"
    assert axes(fig, "0:trajectory").get_title() == "figure8, roll target 0 deg\nroll0.toml"
    assert axes(fig, "1:trajectory").get_title() == "figure8, roll target -5 deg\nroll-5.toml"
    assert tuple(fig.get_size_inches()) == (7.0, pytest.approx(8.6))  # two IEEE columns
    for ax in fig.axes:
        for label in ax.get_yticklabels() + ax.get_xticklabels():
            assert label.get_fontsize() >= 6  # readable at print size
    shades = [p for p in axes(fig, "0:yaw").patches]
    assert len(shades) == 4  # take-off, settle, hold, landing shaded; tracking not


def test_one_flight_fills_two_columns(tmp_path):
    out = save_flight_figure([_trace("hover", 0.0)], tmp_path / "one.png")
    img = matplotlib.image.imread(out)
    assert img.shape[1] == 7 * 300 and img.shape[0] < img.shape[1]  # landscape, 300 dpi


def test_the_trace_of_a_recorded_flight():
    s = _trace("x", -5.0).series
    k = s.t.size
    desired = np.array([euler_zyx(np.radians(-5.0), np.radians(p), 0.0) for p in s.rpy_target[:, 1]])
    rec = FlightRecord(s.t, s.position, s.rotation, s.position_ref, desired, np.full(k, np.radians(-5.0)),
                       s.motors.reshape(k, -1) * 0.2, s.phase, 1.0, False, "", None)
    out = trace_of_record(rec, "x", FACTS, ("pitch",), u_max=0.2).series
    np.testing.assert_allclose(out.motors, s.motors)  # fractions of u_max, per module
    np.testing.assert_allclose(out.rpy_target, s.rpy_target, atol=1e-9)  # of the attitude aimed at


def test_a_large_assembly_shares_one_band():
    tr = _trace("n = 6", 0.0, free=())
    motors = np.concatenate([tr.series.motors] * 3, axis=1)  # (k, 6, 4)
    motors[100:110, 5, 2] = 0.0  # ten periods with one rotor of one module at 0 ...
    motors[105:120, 2, 1] = 1.0  # ... overlapping fifteen with another at u_max: 10 and 15 periods in all
    fig = flight_figure([FlightTrace(tr.label, (), replace(tr.series, motors=motors), ())])
    try:
        ax = axes(fig, "0:rotors")
        assert len(ax.collections) == 1
        assert [t.get_text() for t in ax.get_legend().get_texts()] == [
            f"all 6 modules: {10 / RATE_HZ:.2f} s at 0, {15 / RATE_HZ:.2f} s at u_max"]
    finally:
        matplotlib.pyplot.close(fig)
