import json

from sim.crazyflie_peer import SimulatedCrazyflies
from tests.peers import ROOT, start_peer, stop_peer
from tests.runtime.test_fly import sitl_config


def test_params_check_then_apply(cli, tmp_path):
    peer, th = start_peer(SimulatedCrazyflies, 19740, 7606)
    try:
        cfg = str(sitl_config(tmp_path, "crazyflie", 19740, "tcp/127.0.0.1:7606"))
        code, out, err = cli("params", cfg)
        assert code == 1 and out.count("WRONG") == 4 and out.count(" ok ") == 2
        assert "groundstation: module 1 (udp://127.0.0.1:19741): stabilizer.controller is 0, must be 6" in err
        code, out, err = cli("params", cfg, "--apply")
        assert code == 0, err
        assert out.count("ok (written)") == 4
        code, out, err = cli("params", cfg, "--json")
        rows = json.loads(out)
        assert code == 0 and len(rows) == 6 and all(r["ok"] and not r["written"] for r in rows)
        assert [peer.firmware(i).value("supervisor.tmblChckEn") for i in range(2)] == [0, 0]
    finally:
        stop_peer(peer, th)


def test_params_bad_input(cli, tmp_path):
    code, out, err = cli("params", str(ROOT / "configs/flights/toy_figure8_sim.toml"))
    assert code == 2 and "backend.kind: the sim backend has no module firmware" in err and out == ""
    cfg = str(sitl_config(tmp_path, "crazyflie", 19744, "tcp/127.0.0.1:7607"))
    code, out, err = cli("params", cfg, "--file", str(tmp_path / "none.toml"))
    assert code == 2 and "none.toml: file not found" in err
