import csv
import json
import os

import pytest

from groundstation.errors import PreflightError
from groundstation.replay.analysis import Decimated
from groundstation.runtime.fly import Faults, fly
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
    (d,) = json.loads(out)  # a list whatever the number of logs
    assert set(d) >= REQUIRED and d["complete"] and d["phase"] == "done"
    assert any(e["text"] == "landing -> done: landed" for e in d["events"])


def test_json_with_a_plot_is_json_alone(cli, two_logs, tmp_path):
    png = tmp_path / "fig9.png"
    code, out, err = cli("replay", two_logs[0], "--json", "--plot", str(png))
    assert code == 0 and [d["log"] for d in json.loads(out)] == two_logs[:1], err
    assert err == f"plot: {png}\n" and png.stat().st_size > 50_000


def test_two_logs_side_by_side_with_a_plot_and_csv(cli, two_logs, tmp_path):
    png = tmp_path / "fig9.png"
    out_dir = tmp_path / "csv" / "of-today"  # made, parents too
    code, out, err = cli("replay", *two_logs, "--plot", str(png), "--csv", str(out_dir), "--rerun")
    assert code == 0, err
    assert "roll0.mcap" in out and "roll-5.mcap" in out and "re-run: max rotor diff" in out
    assert png.stat().st_size > 50_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in out_dir.glob("*.csv")) == [
        f"{stem}_{part}.csv" for stem in ("roll-5", "roll0") for part in ("control", "events", "mocap")]
    code, out, _ = cli("replay", *two_logs, "--json")
    assert code == 0 and [d["log"] for d in json.loads(out)] == two_logs


def test_a_refused_flight_replays_its_events(cli, tmp_path):
    """A flight refused in preflight (mocap never saw the assembly) never armed: no control period, and still its
    events, its end and its CSV, in a window too; the plot leaves it out and says so."""
    log = tmp_path / "refused.mcap"
    with pytest.raises(PreflightError):
        fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:7491"), log_path=log, faults=Faults(mocap_paused=True))
    png, out_dir = tmp_path / "fig9.png", tmp_path / "csv"
    code, out, err = cli("replay", str(log), "--from", "0", "--to", "5", "--json", "--plot", str(png),
                         "--csv", str(out_dir))
    assert code == 0, err
    (d,) = json.loads(out)
    assert d["periods"] == 0 and d["phase"] == "aborted" and d["timeline"] == [{"t": 0.0, "phase": "aborted"}]
    assert any("preflight failed: mocap does not see" in e["text"] for e in d["events"])
    assert "refused.mcap: not plotted: it never flew" in err and not png.exists()
    with open(out_dir / "refused_events.csv") as fh:
        assert [e["text"] for e in csv.DictReader(fh)] == [e["text"] for e in d["events"]]
    code, out, err = cli("replay", str(log))
    assert code == 0 and "preflight failed: mocap does not see" in out, err


def test_bad_input_is_one_line_and_exit_2(cli, two_logs, tmp_path):
    for args, message in [((str(ROOT / "README.md"),), "README.md: not an MCAP file"),
                          ((str(tmp_path / "none.mcap"),), "none.mcap: file not found"),
                          ((two_logs[0], "--from", "5", "--to", "2"), "--to (2) must be after --from (5)"),
                          ((two_logs[0], "--csv", two_logs[1]), "roll-5.mcap: not a directory"),
                          ((two_logs[0], "--from", "900"), "no control period to analyse in the window")]:
        code, out, err = cli("replay", *args)
        assert code == 2 and out == "" and message in err and err.count("\n") == 1, (args, err)


def test_a_file_that_is_not_a_regular_one_is_one_line_saying_what_it_is(cli, tmp_path):
    """``replay`` and ``log recover`` (one check, never opening it: a FIFO would block, /dev/zero never end) of a
    device, a FIFO and an empty file: one line naming it and what it is, exit 2. Before: "file not found" for
    /dev/zero and /dev/null, which exist."""
    fifo, empty = tmp_path / "fifo.mcap", tmp_path / "empty.mcap"
    os.mkfifo(fifo)
    empty.touch()
    device = "not a regular file (a character device), not an MCAP flight log"
    for path, what in [("/dev/zero", device), ("/dev/null", device),
                       (str(fifo), "not a regular file (a FIFO), not an MCAP flight log"),
                       (str(empty), "empty file, not an MCAP flight log")]:
        for args in (("replay", path), ("log", "recover", path, str(tmp_path / "r.mcap"))):
            code, out, err = cli(*args)
            assert code == 2 and out == "" and err == f"groundstation: error: {path}: {what}\n", (args, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.mcap", "fifo.mcap"]


def test_series_stay_bounded():
    d = Decimated(cap=1000)
    for k in range(1_000_000):
        d.add(k)
    assert len(d.rows) <= 1000 and d.rows[0] == 0 and d.rows[-1] > 990_000
    assert all(b - a == d.stride for a, b in zip(d.rows, d.rows[1:], strict=False))  # evenly spaced


@pytest.mark.parametrize("stdout", ["/dev/full", "closed"])
def test_figures_that_cannot_be_printed_are_one_line_on_stderr(two_logs, tmp_path, stdout):
    """``replay LOG > /dev/full`` ended in a traceback (ENOSPC), ``>&-`` printed nothing and exited 0."""
    import subprocess
    import sys

    err = tmp_path / "err"
    for args in ([], ["--json"]):
        with err.open("w") as e, open(os.devnull if stdout == "closed" else stdout, "w") as out:
            proc = subprocess.run([sys.executable, "-m", "groundstation", "replay", str(two_logs[0]), *args],
                                  stdin=subprocess.DEVNULL, stdout=out, stderr=e, cwd=ROOT, timeout=120,
                                  preexec_fn=(lambda: os.close(1)) if stdout == "closed" else None)
        text = err.read_text()
        assert proc.returncode == 1 and "Traceback" not in text, text
        assert text.splitlines()[-1].startswith("groundstation: cannot print the replay ("), text
