import json

from sim.crazyflie_peer import SimulatedCrazyflies
from tests.peers import ROOT, start_peer, stop_peer
from tests.runtime.test_fly import sitl_config


def test_params_check_then_apply(cli, tmp_path):
    peer, th = start_peer(SimulatedCrazyflies, 19740, 7606)
    try:
        cfg = str(sitl_config(tmp_path, "crazyflie", 19740, "tcp/127.0.0.1:7606"))
        code, out, err = cli("params", cfg)
        assert code == 1 and out.count("WRONG") == 2 and out.count(" ok ") == 6
        assert "groundstation: module 1 (udp://127.0.0.1:19741): supervisor.tmblChckEn is 1, must be 0" in err
        code, out, err = cli("params", cfg, "--apply")
        assert code == 0, err
        assert out.count("ok (written, stored)") == 2
        code, out, err = cli("params", cfg, "--json")
        rows = json.loads(out)
        assert code == 0 and len(rows) == 8 and all(r["ok"] and not r["written"] for r in rows)
        assert [peer.firmware(i).services.stored for i in range(2)] == [{"supervisor.tmblChckEn": 0}] * 2
    finally:
        stop_peer(peer, th)


def test_params_of_modules_that_do_not_answer(cli, tmp_path):
    cfg = str(sitl_config(tmp_path, "crazyflie", 19746, "tcp/127.0.0.1:7608"))
    code, out, err = cli("params", cfg)
    assert code == 1
    assert err.count("does not answer") == 2 and err.count("groundstation:") == 2  # once per module


def test_params_bad_input(cli, tmp_path):
    code, out, err = cli("params", str(ROOT / "configs/flights/toy_figure8_sim.toml"))
    assert code == 2 and "backend.kind: the sim backend has no module firmware" in err and out == ""
    cfg = str(sitl_config(tmp_path, "crazyflie", 19744, "tcp/127.0.0.1:7607"))
    code, out, err = cli("params", cfg, "--file", str(tmp_path / "none.toml"))
    assert code == 2 and "none.toml: file not found" in err
