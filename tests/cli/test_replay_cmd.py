import json

import pytest

from groundstation.replay.analysis import Decimated
from groundstation.runtime.fly import fly
from tests.peers import ROOT
from tests.runtime.test_fly import config_with

REQUIRED = {"pos_rmse_m", "max_pos_error_m", "max_orientation_error_deg", "max_roll_error_deg",
            "loop_period_error_p99_ms", "overruns", "mocap_age_p99_ms", "saturation_fraction", "events"}


@pytest.fixture(scope="module")
def two_logs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("replay-cli")
    logs = []
    for roll in (0.0, -5.0):  # hovering: short, and within the V's authority at either roll
        cfg = config_with(tmp, endpoint="tcp/127.0.0.1:7489", **{"roll_deg = 0.0": f"roll_deg = {roll}",
                                                                 'kind = "figure8"': 'kind = "hover"'})
        log = tmp / f"roll{roll:g}.mcap"
        assert fly(cfg, duration=1.0, log_path=log).phase == "done"
        logs.append(str(log))
    return logs


def test_json_of_one_log(cli, two_logs):
    code, out, err = cli("replay", two_logs[0], "--json")
    assert code == 0, err
    d = json.loads(out)
    assert set(d) >= REQUIRED and d["complete"] and d["phase"] == "done"
    assert any(e["text"] == "landing -> done: landed" for e in d["events"])


def test_two_logs_side_by_side_with_a_plot_and_csv(cli, two_logs, tmp_path):
    png = tmp_path / "fig9.png"
    code, out, err = cli("replay", *two_logs, "--plot", str(png), "--csv", str(tmp_path), "--rerun")
    assert code == 0, err
    assert "roll0.mcap" in out and "roll-5.mcap" in out and "re-run: max rotor diff" in out
    assert png.stat().st_size > 50_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.glob("*.csv")) == ["roll-5_control.csv", "roll-5_events.csv",
                                                              "roll0_control.csv", "roll0_events.csv"]
    code, out, _ = cli("replay", *two_logs, "--json")
    assert code == 0 and [d["log"] for d in json.loads(out)] == two_logs


def test_bad_input_is_one_line_and_exit_2(cli, two_logs, tmp_path):
    for args, message in [((str(ROOT / "README.md"),), "README.md: not an MCAP file"),
                          ((str(tmp_path / "none.mcap"),), "none.mcap: file not found"),
                          ((two_logs[0], "--from", "5", "--to", "2"), "--to (2) must be after --from (5)"),
                          ((two_logs[0], "--csv", str(tmp_path / "nodir")), "nodir: not a directory"),
                          ((two_logs[0], "--from", "900"), "no control period to analyse in the window")]:
        code, out, err = cli("replay", *args)
        assert code == 2 and out == "" and message in err and err.count("\n") == 1, (args, err)


def test_series_stay_bounded():
    d = Decimated(cap=1000)
    for k in range(1_000_000):
        d.add(k)
    assert len(d.rows) <= 1000 and d.rows[0] == 0 and d.rows[-1] > 990_000
    assert all(b - a == d.stride for a, b in zip(d.rows, d.rows[1:], strict=False))  # evenly spaced
