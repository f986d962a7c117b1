"""The Crazyflie backend over cflib's real radio driver, with the USB dongle emulated (sim.crazyradio_emulator):
sends never wait for the radio, several dongles work in parallel, and a figure-8 flight over them flies or ends
in the link failsafe."""

import re
import threading
import time

import numpy as np

from groundstation.backends.crazyflie import CrazyflieBackend, CrazyflieSettings
from groundstation.errors import PreflightError
from groundstation.runtime.fly import fly
from sim.crazyflie_peer import SimulatedCrazyflies
from sim.crazyradio_emulator import emulated_crazyradios
from tests.peers import ASM, ROOT, U_MAX, UNTIMED_LINK, hold, peer_process, start_peer, stop_peer
from tests.runtime.test_fly import sitl_config

RADIOS = ["radio://0/80/2M/E7E7E7E700", "radio://1/80/2M/E7E7E7E701"]


def test_sends_never_wait_for_a_stalled_dongle():
    peer, th = start_peer(SimulatedCrazyflies, 19940, 7482)
    try:
        with emulated_crazyradios(19940) as radio:
            be = CrazyflieBackend(RADIOS, ASM.params, ASM.module_rotations, CrazyflieSettings(**UNTIMED_LINK))
            be.connect()
            assert be.preflight().ok  # the modules claimed: they take this backend's commands
            stalled = threading.Event()
            radio.gate = stalled  # every transaction waits: the radio is stuck
            done = threading.Event()

            def loop():
                be._armed = True  # as after arm(): the commands carry the armed flag
                for k in range(200):
                    be.send(np.full(8, (k + 1) / 200 * 0.5 * U_MAX))
                done.set()

            sender = threading.Thread(target=loop, daemon=True)
            sender.start()
            assert done.wait(10.0), "send() blocked on the radio"
            assert be.superseded >= 2 * 200 - 2 * 3  # nearly all replaced by newer ones while the radio was stuck
            stalled.set()  # the radio comes back: the newest command goes out, not a backlog
            deadline = time.monotonic() + 3.0
            while time.monotonic() < deadline and any(
                    peer.firmware(i).app.latest is None or peer.firmware(i).app.latest.sequence != be._seq
                    for i in range(ASM.n)):
                time.sleep(0.01)
            assert all(peer.firmware(i).app.latest.sequence == be._seq for i in range(ASM.n))
            be.close()
    finally:
        stop_peer(peer, th)


def test_one_module_per_dongle_at_the_control_rate():
    peer, th = start_peer(SimulatedCrazyflies, 19944, 7483)
    try:
        with emulated_crazyradios(19944) as radio:
            settings = CrazyflieSettings(**UNTIMED_LINK)
            with CrazyflieBackend(RADIOS, ASM.params, ASM.module_rotations, settings) as be:
                assert be.preflight().ok, be.preflight().issues
                be.arm()
                hold(be, np.full(8, 0.4 * U_MAX), 1.0)
                np.testing.assert_allclose(be.telemetry().motors, 0.4 * U_MAX, rtol=1e-3)
                q = be.link_quality()
                assert np.all(q.latency_s >= 0) and np.all(q.loss < 0.05)  # measured (values: benchmarks.radio)
                be.disarm()
            assert set(radio.transactions) == {0, 1}  # each module on its own dongle
    finally:
        stop_peer(peer, th)


def test_figure8_over_two_emulated_dongles(tmp_path):
    """The SITL flight through cflib's radio driver (one module per dongle at 250 Hz), parameters included, with
    the shipped link bounds: it flies its plan, or the link failsafe lands or stops it naming the link; nothing else.

    The emulated dongles are threads of this process (the simulated modules run in their own), and the round
    trip sits near the bounds (12 ms median, 14 ms to land, 20 ms to stop). Relaxing the bounds (40 / 80 ms) let
    the assembly flip under a CPU hog, which is why they are the shipped ones here. The attitude loop at 4 Hz had
    little phase left at that round trip (1 flight in 4 flipped in its landing); at the shipped config's 3 Hz it
    flies or lands on the link failsafe: 2 of 2 idle and 2 of 2 with a CPU hog (2026-12-02, the modules in a
    process of their own and landings that go on from the reference's motion); with two hogs on this 2-core
    machine, 1 of 2 flipped (so did the code before, as threads)."""
    peer = peer_process(tmp_path, str(ROOT / "configs/assemblies/toy_v2.json"), "--port", "19948", "--mocap",
                        "tcp/127.0.0.1:7484", "--params", str(ROOT / "firmware_params/crazyflie.toml"))
    try:
        cfg = sitl_config(tmp_path, "crazyflie", 19948, "tcp/127.0.0.1:7484")
        text = cfg.read_text().replace('"udp://127.0.0.1:19948", "udp://127.0.0.1:19949"',
                                       ", ".join(f'"{u}"' for u in RADIOS))
        assert RADIOS[0] in text
        cfg.write_text(text)
        with emulated_crazyradios(19948) as radio:
            try:
                res = fly(cfg, duration=3.0, log_path=tmp_path / "radio.mcap")
            except PreflightError as exc:  # the same bound, before take-off
                one = r"module \d \(radio://\S+\) link round trip \d+ ms > 14 ms"
                assert re.fullmatch(f"preflight failed: {one}(; {one})*", str(exc)), exc
                return
        assert min(radio.transactions.get(d, 0) for d in (0, 1)) > 250  # both dongles carried the flight
        assert any(text.startswith("preflight -> takeoff") for _, _, text in res.events)
        if res.nominal:
            assert res.metrics.pos_rmse_m < 0.03
        else:
            assert res.phase in ("done", "emergency") and res.reason.startswith("link degraded"), res.reason
    finally:
        peer.terminate()
        peer.wait(10)
