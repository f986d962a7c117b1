"""The README's figure-8 for Crazyflie modules, flown through the product's own commands (``sim-peer``, ``params``,
``fly``) against two real-firmware modules of each platform, twice without restarting them, and compared with the
same flight against the Python modules. Needs ``CRAZYFLIE_FIRMWARE`` (see conftest)."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys

import pytest

from tests.firmware_sitl.conftest import ROOT, sitl_binary
from tests.firmware_sitl.test_conformance import TOY
from tests.peers import peer_process

SHIPPED_PORT, MOCAP = 19850, "tcp/127.0.0.1:7448"


def flight_config(tmp_path, platform: str, port: int, mocap: str):
    """The shipped Crazyflie SITL flight config, flying ``platform``'s two-module V on ``port`` and ``mocap``."""
    text = (ROOT / "configs/flights/toy_figure8_crazyflie_sitl.toml").read_text()
    text = text.replace('assembly = "../assemblies/toy_v2.json"',
                        f'assembly = "{ROOT / "configs/assemblies" / TOY[platform]}"')
    text = text.replace('firmware_params = "../../', f'firmware_params = "{ROOT}/')
    text = text.replace(str(SHIPPED_PORT), str(port)).replace(str(SHIPPED_PORT + 1), str(port + 1))
    text = text.replace(MOCAP, mocap).replace('log_dir = "../../out/flights"', f'log_dir = "{tmp_path}"')
    cfg = tmp_path / f"{platform}.toml"
    cfg.write_text(text)
    return cfg


@contextlib.contextmanager
def sim_peer(tmp_path, platform: str, port: int, mocap: str, *extra: str):
    """``groundstation sim-peer`` for ``platform``'s V, started as the other flight tests start theirs (at the world's
    priority, ready when it says so); it must end cleanly."""
    peer = peer_process(tmp_path, str(ROOT / "configs/assemblies" / TOY[platform]), "--platform", platform,
                        "--port", str(port), "--mocap", mocap, *extra)
    try:
        yield peer
    finally:
        peer.terminate()
        peer.wait(timeout=20)
        assert peer.returncode == 0, f"sim-peer exited with {peer.returncode}"


def groundstation(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "groundstation", *args], capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=180)


@pytest.mark.parametrize("platform, port", [("cf2", 19640), ("bolt", 19650), ("cf21bl", 19660)])
def test_figure8_against_real_firmware_modules(platform, port, tmp_path):
    binary = sitl_binary(platform)
    mocap = f"tcp/127.0.0.1:{7624 + port % 19640 // 10}"
    cfg = flight_config(tmp_path, platform, port, mocap)
    firmware = []
    with sim_peer(tmp_path, platform, port, mocap, "--firmware", str(binary), "--state-dir", str(tmp_path / "modules")):
        applied = groundstation("params", str(cfg), "--apply")
        assert applied.returncode == 0, applied.stdout + applied.stderr  # tumble detection off, stored
        for _ in range(2):  # twice in a row: a normal landing disarms without latching anything
            flown = groundstation("fly", str(cfg), "--json")
            summary = json.loads(flown.stdout)
            assert flown.returncode == 0 and summary["phase"] == "done" and summary["reason"] == "", flown.stderr
            firmware.append(summary["pos_rmse_m"])
    params = str(ROOT / "firmware_params/crazyflie.toml")
    with sim_peer(tmp_path, platform, port, mocap, "--params", params):
        flown = groundstation("fly", str(cfg), "--json")
        model = json.loads(flown.stdout)
        assert flown.returncode == 0 and model["phase"] == "done", flown.stderr
    print(f"{platform}: position RMSE real firmware {firmware} m, Python modules {model['pos_rmse_m']:.4f} m")
    assert max(firmware) <= 2.0 * model["pos_rmse_m"]
