import fcntl
import json
import os
import pty
import re
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest
from matplotlib.image import imread

ROOT = Path(__file__).resolve().parents[2]
TOY = str(ROOT / "configs/assemblies/toy_v2.json")



def test_json_metrics_and_plot(cli, tmp_path):
    png = tmp_path / "f.png"
    code, out, err = cli("simulate", TOY, "--trajectory", "hover", "--duration", "2", "--json",
                         "--plot", str(png))
    m = json.loads(out)
    assert code == 0
    for key in ("pos_rmse_m", "max_pos_error_m", "max_orientation_error_deg", "realtime_factor", "crashed"):
        assert key in m
    assert not m["crashed"] and m["pos_rmse_m"] < 0.01 and m["realtime_factor"] > 0
    assert imread(png).shape[1] > 800 and f"plot: {png}" in err


@pytest.mark.parametrize("args, fragment", [
    (["simulate", "nope.json"], "nope.json: file not found"),
    (["simulate", TOY, "--trajectory", "spiral"], "--trajectory: Input should be 'hover', 'circle' or 'figure8'"),
    (["simulate", TOY, "--duration", "-1"], "--duration: Input should be greater than or equal to 0.1"),
    (["simulate", TOY, "--height", "9"], "flight volume"),
    (["simulate", TOY, "--allocation", "magic"], "--allocation: Input should be 'clip' or 'bounded'"),
    # absurd but valid by type: the bounds of a flight config
    (["simulate", TOY, "--roll", "nan"], "Invalid value for '--roll': 'nan' is not a finite number"),
    (["simulate", TOY, "--period", "inf"], "Invalid value for '--period': 'inf' is not a finite number"),
    (["simulate", TOY, "--duration", "1e7"], "--duration: Input should be less than or equal to 3600"),
    (["simulate", TOY, "--roll", "80"], "--roll: 80 deg is not below failsafe.max_tilt_deg"),
    (["simulate", TOY, "--control-hz", "60"], "--control-hz: 4 Hz at attitude_zeta = 0.9"),
    (["simulate", TOY, "--control-hz", "1e5"], "--control-hz: Input should be less than or equal to 1000"),
    (["simulate", TOY, "--physics-hz", "1e9"], "--physics-hz: 1e+09 Hz is above 2000 Hz"),
    (["simulate", TOY, "--physics-hz", "30"], "--physics-hz: 4 Hz at attitude_zeta = 0.9"),
    (["simulate", "/dev/zero"], "/dev/zero: not a text file"),
    # the trajectory the options ask is beyond the assembly: the options named (before: the trajectory alone)
    (["simulate", TOY, "--duration", "1e-300"], "--duration: Input should be greater than or equal to 0.1"),
    (["simulate", TOY, "--duration", "5e-324"], "--duration: Input should be greater than or equal to 0.1"),
    (["simulate", TOY, "--period", "0.3"], "asks for 89 deg of tilt, above 0.75 x gains.max_tilt_deg = 22.5 deg "
                                           "(--trajectory figure8 --duration 16 --height 1 --size 0.6 --period 0.3"),
    # the 8 s figure-8 cut to 0.4 s: its speed entered and left in 0.2 s ramps (v s'' = 0.7 m/s x 1.875 / 0.2 s),
    # which the tilt check left out: it flew to 56 deg of attitude error, exit 0 (hostile campaign 34)
    (["simulate", TOY, "--duration", "0.4"], "its 7.26 m/s^2 asks for 36 deg of tilt, above 0.75 x "
                                             "gains.max_tilt_deg = 22.5 deg (--trajectory figure8 --duration 0.4"),
])
def test_bad_input(cli, args, fragment):
    code, out, err = cli(*args)
    assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("key, value", [("n", 3), ("mass_kg", 4.8), ("feasible", False)])
def test_invalid_assembly_file(cli, tmp_path, key, value):
    """A file whose stored values disagree with its geometry or its design is refused before anything flies."""
    rec = json.loads(Path(TOY).read_text())
    rec["modules"][0]["position"] = [1, 2, 3]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(rec))
    code, out, err = cli("simulate", str(bad))
    assert code == 2 and "modules[0].position" in err
    rec = json.loads(Path(TOY).read_text()) | {key: value}
    bad.write_text(json.dumps(rec))
    code, out, err = cli("simulate", str(bad))
    assert code == 2 and err.startswith(f"groundstation: error: {bad}: {key}: says {value}")
    assert len(err.strip().splitlines()) == 1, err


def test_the_table_has_replays_labels(cli):
    code, out, err = cli("simulate", TOY, "--trajectory", "hover", "--duration", "1")
    assert code == 0, err
    assert "Simulated hover" in out and "(n = 2, 5 DOF)" in out
    for label in ("position RMSE, tracking (m)", "position RMSE x, y, z, tracking (m)",
                  "max attitude error, airborne (deg)", "saturated (airborne, per module)", "end"):
        assert label in out
    assert "pos_rmse_m" not in out and "{" not in out and "(0." not in out  # no raw keys, dicts or tuples
    numbers = re.findall(r"\d+\.\d+", out)
    assert numbers and all(len(n.replace(".", "").lstrip("0")) <= 4 for n in numbers), out  # 4 significant digits


def test_a_status_line_on_a_terminal():
    """On a terminal, ``simulate`` shows fly's status line (flight time out of the plan's, the tracking error)
    while it flies, then clears it: the table starts on a line of its own."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 150, 0, 0))
    proc = subprocess.Popen([sys.executable, "-m", "groundstation", "simulate", TOY, "--trajectory", "hover",
                             "--duration", "1"], stdin=slave, stdout=slave, stderr=slave, cwd=ROOT,
                            env=os.environ | {"TERM": "xterm", "COLUMNS": "150"})
    os.close(slave)
    chunks = []
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        chunks.append(chunk)
    os.close(master)
    assert proc.wait(timeout=60) == 0
    raw = b"".join(chunks).decode()
    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", raw)  # without colours and cursor moves
    assert text.startswith("preflight\r")
    statuses = re.findall(r"(\w+) t=\s*([\d.]+) / ([\d.]+) s  error\s+([\d.]+) mm", text)
    assert len(statuses) >= 3 and {s[0] for s in statuses} >= {"takeoff"}
    assert all(float(s[2]) == float(statuses[0][2]) >= float(s[1]) for s in statuses)  # t out of the plan's total
    # the status line is erased (ESC[2K) before the table: nothing is left on the line the table starts on
    assert re.search(r"\x1b\[2K(\x1b\[3m)? *Simulated hover", raw)
