"""``replay --plot``'s figure of real logs (the package's 5 s figure-8 at roll -5 deg, and the 1 s hover of
``tests/flightlog``), checked against what the logs hold, read here with the ``mcap`` package's own reader."""

import datetime as dt
import json

import matplotlib
import numpy as np
import pytest
from mcap.reader import make_reader

from groundstation.replay.analysis import analyse
from groundstation.replay.plots import plot_replays, trace_of
from groundstation.runtime.plots import flight_figure
from tests.flightlog.damage import flight_log

matplotlib.use("Agg")


def control_records(log) -> tuple[list[dict], float, dict]:
    """The /control records of the periods flown, the epoch of flight time 0 (s) and the log's metadata."""
    with open(log, "rb") as fh:
        reader = make_reader(fh)
        meta = {m.name: m.metadata["value"] for m in reader.iter_metadata()}
    with open(log, "rb") as fh:
        msgs = [(m.log_time * 1e-9, json.loads(m.data)) for _, _, m in make_reader(fh).iter_messages(["/control"])]
    return [d for _, d in msgs if "state" in d], msgs[0][0] - msgs[0][1]["t_s"], meta


@pytest.fixture(scope="module")
def figure(sim_flight):
    _, log = sim_flight
    hover = flight_log()
    fig = flight_figure([trace_of(analyse(hover)), trace_of(analyse(log))])
    yield fig, hover, log
    matplotlib.pyplot.close(fig)


def axes(fig, label: str):
    (ax,) = [ax for ax in fig.axes if ax.get_label() == label]
    return ax


def test_the_error_panels_are_the_logged_errors_per_axis(figure):
    fig, _, log = figure
    recs, _, _ = control_records(log)
    flown = np.array([d.get("truth", d["state"])["position_m"] for d in recs])
    ref = np.array([d["setpoint"]["position_m"] for d in recs])
    for k, name in enumerate("xyz"):
        (line,) = [li for li in axes(fig, f"1:error {name}").get_lines() if len(li.get_xdata()) == len(recs)]
        np.testing.assert_allclose(line.get_ydata(), (flown - ref)[:, k] * 100, atol=1e-9)
    tracking = [d["phase"] == "track" for d in recs]
    (path,) = [li for li in axes(fig, "1:trajectory").get_lines() if li.get_label() == "reference"]
    np.testing.assert_allclose(np.column_stack(path.get_data_3d()), ref[tracking])
    assert path.get_linestyle() == "--"


def test_the_bound_times_are_counted_from_the_rotor_commands(figure):
    fig, hover, log = figure
    for c, path in enumerate((hover, log)):
        recs, _, _ = control_records(path)
        u = np.array([[m["command_frac_umax"] for m in d["modules"]] for d in recs])  # (k, n, 4)
        period = np.median(np.diff([d["t_s"] for d in recs]))
        expected = [f"module {i}: {np.sum((u[:, i] <= 0.001).any(axis=1)) * period:.2f} s at 0, "
                    f"{np.sum((u[:, i] >= 0.999).any(axis=1)) * period:.2f} s at u_max" for i in range(u.shape[1])]
        assert [t.get_text() for t in axes(fig, f"{c}:rotors").get_legend().get_texts()] == expected


def test_the_titles_come_from_the_logs_metadata(figure):
    fig, hover, log = figure
    suptitle = fig._suptitle.get_text()
    assert suptitle.startswith("toy_v2 (n = 2, 5 DOF) | flight.toml")  # what both share: the figure's title
    assert axes(fig, "0:trajectory").get_title().startswith("hover, roll target 0 deg\n")
    assert axes(fig, "1:trajectory").get_title().startswith("figure8, roll target -5 deg\n")
    for c, path in enumerate((hover, log)):
        _, epoch, meta = control_records(path)
        date = dt.datetime.fromtimestamp(epoch, dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
        own = axes(fig, f"{c}:trajectory").get_title()
        assert path.name in own  # the logs differ: each column names its own
        for fact in (date, f"code {meta['code_version']}"):  # shared, in the figure's title; else the column's
            assert fact in own or fact in suptitle and fact not in own


def test_the_vs_pitch_is_not_tracked_and_its_roll_is(figure):
    fig, _, log = figure
    recs, _, _ = control_records(log)
    assert [li.get_label() for li in axes(fig, "1:pitch").get_lines()].count("target") == 0
    (target,) = [li for li in axes(fig, "1:roll").get_lines() if li.get_label() == "target"]
    np.testing.assert_allclose(target.get_ydata(), [d["attitude_target"]["rpy_deg"][0] for d in recs])
    assert min(target.get_ydata()) == pytest.approx(-5.0)


def test_plot_replays_writes_the_figure(sim_flight, tmp_path):
    _, log = sim_flight
    out = plot_replays([analyse(log)], tmp_path / "fig9.png")
    assert matplotlib.image.imread(out).shape[1] == 7 * 300
