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
