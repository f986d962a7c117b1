import json
import socket
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ASSEMBLY = str(ROOT / "configs/assemblies/toy_v2.json")


@pytest.mark.parametrize("protocol, links", [("crtp", "udp://127.0.0.1:19884, udp://127.0.0.1:19885"),
                                             ("mavlink", "udpout:127.0.0.1:19884, udpout:127.0.0.1:19885")])
def test_sim_peer_runs_and_reports(cli, protocol, links):
    code, out, err = cli("sim-peer", ASSEMBLY, "--protocol", protocol, "--port", "19884",
                         "--mocap", "tcp/127.0.0.1:7477", "--duration", "0.5")
    assert code == 0, err
    assert f"({protocol}) on {links}" in err
    report = json.loads(out)
    assert report["packets"] == 0 and abs(report["simulated_s"] - 0.5) < 0.01


def test_sim_peer_port_in_use(cli):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 19887))
        code, out, err = cli("sim-peer", ASSEMBLY, "--port", "19886", "--mocap", "tcp/127.0.0.1:7478")
    assert code == 2 and err.startswith("groundstation: error: cannot listen on udp 127.0.0.1:19886..19887")


def test_sim_peer_bad_assembly(cli, tmp_path):
    bad = tmp_path / "a.json"
    bad.write_text("{}")
    code, out, err = cli("sim-peer", str(bad))
    assert code == 2 and str(bad) in err and out == ""
    code, out, err = cli("sim-peer", ASSEMBLY, "--protocol", "ardupilot")
    assert code == 2 and "'ardupilot' is not one of 'crtp', 'mavlink'" in err


def test_status_line_fits_the_terminal():
    from rich.text import Text

    from groundstation.cli.fly_cmd import KEYS_HINT, status_text
    from groundstation.runtime.flight import Status

    s = Status(t=12.345, phase="track", mocap_age=0.0041, worst_motor=0.456, battery_v=3.95, overruns=2,
               rate_hz=499.0)
    for width, hint in ((80, False), (130, True)):
        plain = Text.from_markup(status_text(s, width, KEYS_HINT)).plain
        assert len(plain) <= width and (KEYS_HINT in plain) is hint
        assert "track t=  12.3 s  499 Hz  mocap  4.1 ms  motor  46%  battery 3.95 V  late 2" in plain
    assert " --- Hz " in Text.from_markup(status_text(Status(0.5, "takeoff", 0.004, 0.4, None, 0), 80)).plain
    # a very narrow terminal: cut, never wrapped
    assert len(Text.from_markup(status_text(s, 40, KEYS_HINT)).plain) == 40


def _closed(*fds: int):
    """A child's preexec: the standard streams ``fds`` closed (``>&-``, ``2>&-``)."""
    import os

    def close():
        for fd in fds:
            os.close(fd)
    return close


def _run_closed(args: list[str], fds: tuple[int, ...], tmp_path: Path, timeout: float = 300):
    """``groundstation ARGS`` with ``fds`` closed; what it wrote on the others (files), and its exit status."""
    import subprocess
    import sys

    out, err = tmp_path / "out", tmp_path / "err"
    with out.open("w") as o, err.open("w") as e:
        proc = subprocess.run([sys.executable, "-m", "groundstation", *args], stdin=subprocess.DEVNULL, stdout=o,
                              stderr=e, cwd=ROOT, timeout=timeout, preexec_fn=_closed(*fds))
    return proc.returncode, out.read_text(), err.read_text()


def test_fly_with_stdout_closed_says_so_on_stderr(tmp_path):
    """``fly >&-``: the flight flies; one line on stderr says its summary could not be printed and where the log is
    (before: exit 0 and the summary lost without a word); the exit status is the flight's."""
    from tests.runtime.test_fly import config_with

    log = tmp_path / "f.mcap"
    code, _, err = _run_closed(["fly", str(config_with(tmp_path, endpoint="tcp/127.0.0.1:7791")), "--log", str(log),
                                "--json", "--duration", "1"], (1,), tmp_path)
    assert code == 0 and "Traceback" not in err, err
    assert f"groundstation: cannot print the flight's summary (stdout is closed); it is in the log {log}\n" in err
    # Descriptor 1 held on /dev/null: neither the log nor another file the process opens is given it (and what is
    # written to it lands there)
    with log.open("rb") as fh:
        assert fh.read(8) == b"\x89MCAP0\r\n"
    code, out, _ = _run_closed(["replay", str(log), "--json"], (), tmp_path)
    assert code == 0 and json.loads(out)[0]["phase"] == "done", out  # one entry per log


def test_fly_simulate_and_sim_peer_run_with_stderr_closed(tmp_path):
    """``2>&-`` (Python's sys.stderr is None): they ran into an AttributeError silencing pybullet's banner
    (sim/quiet.py) and exited 1 with nothing said and no log."""
    from tests.runtime.test_fly import config_with

    log = tmp_path / "f.mcap"
    code, out, _ = _run_closed(["fly", str(config_with(tmp_path, endpoint="tcp/127.0.0.1:7792")), "--log", str(log),
                                "--json", "--duration", "1"], (2,), tmp_path)
    assert code == 0 and json.loads(out)["phase"] == "done" and log.stat().st_size > 0, out
    code, out, _ = _run_closed(["simulate", ASSEMBLY, "--duration", "0.5", "--trajectory", "hover"], (2,), tmp_path)
    assert code == 0 and "Simulated hover" in out, out
    code, out, _ = _run_closed(["sim-peer", ASSEMBLY, "--port", "19894", "--mocap", "tcp/127.0.0.1:7793",
                                "--duration", "0.5"], (2,), tmp_path)
    assert code == 0 and json.loads(out)["simulated_s"] > 0.4, out
    # both closed: nobody to tell, the status says the figures were not printed
    code, out, _ = _run_closed(["simulate", ASSEMBLY, "--duration", "0.5", "--trajectory", "hover"], (1, 2), tmp_path)
    assert code == 1 and out == ""


def test_a_usage_error_of_a_subcommand_points_at_its_own_help(cli, tmp_path):
    """``log recover DIR``: the hint named ``groundstation recover --help``, a command that does not exist."""
    code, _, err = cli("log", "recover", str(tmp_path), str(tmp_path / "out.mcap"))
    assert code == 2 and err.endswith("(see 'groundstation log recover --help')\n"), err
