"""The README's figure-8 for Crazyflie modules, flown through the product's own commands (``sim-peer``, ``params``,
``fly``) against two real-firmware modules of each platform, twice without restarting them, and compared with the
same flight against the Python modules. Needs ``CRAZYFLIE_FIRMWARE`` (see conftest).

A flight the machine stopped (a stall or a silent link while a top-priority probe saw a CPU held off ~100 ms by
the host: ``tests.peers.stopped_by_host``) voids its attempt, and the platform is flown again from fresh firmware
processes, at most ``tests.peers.ATTEMPTS`` times; every voided attempt is printed. Any other ending fails at once."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys

import pytest

from tests.firmware_sitl.conftest import ROOT, sitl_binary
from tests.firmware_sitl.test_conformance import TOY
from tests.peers import attempted, host_freezes, peer_process, raise_if_stopped_by_host

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


def fly_to_done(cfg) -> float:
    """``fly --json`` once; its position RMSE, m. Raises :class:`HostStopped` for a flight the machine stopped."""
    with host_freezes() as seen:
        flown = groundstation("fly", str(cfg), "--json")
    summary = json.loads(flown.stdout)
    if flown.returncode != 0:
        raise_if_stopped_by_host(summary["phase"], summary["reason"], seen)
    assert flown.returncode == 0 and summary["phase"] == "done" and summary["reason"] == "", flown.stderr
    return summary["pos_rmse_m"]


def against_firmware(tmp_path, platform: str, port: int, mocap: str, cfg) -> list[float]:
    """``params --apply``, then two flights in a row against fresh firmware processes; their RMSE, m."""
    binary = sitl_binary(platform)
    with sim_peer(tmp_path, platform, port, mocap, "--firmware", str(binary), "--state-dir", str(tmp_path / "modules")):
        applied = groundstation("params", str(cfg), "--apply")
        assert applied.returncode == 0, applied.stdout + applied.stderr  # tumble detection off, stored
        # twice in a row: a normal landing disarms without latching anything
        return [fly_to_done(cfg) for _ in range(2)]


def against_model(tmp_path, platform: str, port: int, mocap: str, cfg) -> float:
    with sim_peer(tmp_path, platform, port, mocap, "--params", str(ROOT / "firmware_params/crazyflie.toml")):
        return fly_to_done(cfg)


@pytest.mark.parametrize("platform, port", [("cf2", 19640), ("bolt", 19650), ("cf21bl", 19660)])
def test_figure8_against_real_firmware_modules(platform, port, tmp_path):
    mocap = f"tcp/127.0.0.1:{7624 + port % 19640 // 10}"
    cfg = flight_config(tmp_path, platform, port, mocap)
    firmware = attempted(against_firmware, tmp_path, platform, port, mocap, cfg, label=platform)
    model = attempted(against_model, tmp_path, platform, port, mocap, cfg, label=platform)
    print(f"{platform}: position RMSE real firmware {firmware} m, Python modules {model:.4f} m")
    assert max(firmware) <= 2.0 * model
