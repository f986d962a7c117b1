"""Send time per control period and what reaches the modules, for the Crazyflie backend's links.

    python -m benchmarks.radio [--seconds 10] [--rate 250]

Two simulated modules (``sim.crazyflie_peer`` in this process's thread), driven by the fixed-rate loop at
``--rate`` with one ``send`` and one ``telemetry`` per period, over:

* UDP, direct; and UDP through ``sim.udp_relay`` delaying every packet 50 ms each way (a peer that answers late);
* cflib's real radio driver over emulated dongles (``sim.crazyradio_emulator``, 2.1 ms a transaction: ~470 a
  second), one module per dongle and both modules on one dongle, each with the backend's sender thread (ours)
  and with the send on the loop's thread (``blocking``: what ``link.send_packet`` does when called directly,
  the baseline).

Reports the time ``send`` took per period, late periods, commands superseded before the radio took them, the
commands the modules accepted per second, and the round trip the backend measured.
"""

from __future__ import annotations

import argparse
import contextlib
import subprocess
import sys
import threading
import time

import numpy as np

from benchmarks._util import print_table
from groundstation.assembly.assembly_file import load_assembly
from groundstation.backends import crazyflie
from groundstation.backends.crazyflie import CrazyflieBackend
from groundstation.runtime.loop import WallClock, run_fixed_rate
from sim.crazyflie_peer import SimulatedCrazyflies
from sim.crazyradio_emulator import emulated_crazyradios
from sim.module_peer import PeerConfig
from tests.peers import ROOT

PEER_PORT, RELAY_PORT = 19970, 19980
ASM, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")


@contextlib.contextmanager
def _blocking_sends():
    """Every link sends on the caller's thread (the baseline)."""
    saved = crazyflie._sender_for
    crazyflie._sender_for = lambda driver, name: crazyflie._DirectSender(driver)
    try:
        yield
    finally:
        crazyflie._sender_for = saved


def _run(uris: list[str], seconds: float, rate: float, peer: SimulatedCrazyflies) -> list:
    be = CrazyflieBackend(uris, ASM.params, ASM.module_rotations)
    be.connect()
    be.preflight()
    received0 = [peer.firmware(i).app.received for i in range(ASM.n)]
    sends: list[float] = []
    u = np.full(8, 0.1 * ASM.params.u_max)

    def step(k: int, t: float) -> bool:
        t0 = time.perf_counter()
        be.send(u)
        sends.append(time.perf_counter() - t0)
        be.telemetry()
        return t < seconds

    stats = run_fixed_rate(step, rate, WallClock())
    accepted = [(peer.firmware(i).app.received - received0[i]) & 0xFFFF for i in range(ASM.n)]
    rtt = be.link_quality().latency_s
    superseded = be.superseded
    be.close()
    s = np.array(sends) * 1e6
    return [f"{np.percentile(s, 50):.0f}", f"{np.percentile(s, 99):.0f}", f"{s.max():.0f}", stats.overruns,
            superseded, f"{min(accepted) / seconds:.0f}", f"{np.nanmax(rtt) * 1e3:.1f}"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=250.0)
    args = ap.parse_args(argv)
    peer = SimulatedCrazyflies(ASM, PeerConfig(port=PEER_PORT, mocap_endpoint="tcp/127.0.0.1:7495"))
    peer.open()
    th = threading.Thread(target=peer.run, daemon=True)
    th.start()
    rows = []
    try:
        udp = [f"udp://127.0.0.1:{PEER_PORT + i}" for i in range(ASM.n)]
        rows.append(["UDP", "direct"] + _run(udp, args.seconds, args.rate, peer))
        relay = subprocess.Popen([sys.executable, "-m", "sim.udp_relay", "--listen", str(RELAY_PORT), "--target",
                                  str(PEER_PORT), "--links", str(ASM.n), "--delay-ms", "50"],
                                 stdout=subprocess.DEVNULL)
        time.sleep(1.0)
        try:
            relayed = [f"udp://127.0.0.1:{RELAY_PORT + i}" for i in range(ASM.n)]
            rows.append(["UDP, answers 100 ms late", "direct"] + _run(relayed, args.seconds, args.rate, peer))
        finally:
            relay.terminate()
            relay.wait(10)
        layouts = {"radio, 1 module per dongle": [f"radio://{i}/80/2M/E7E7E7E70{i}" for i in range(ASM.n)],
                   "radio, 2 modules on 1 dongle": [f"radio://0/80/2M/E7E7E7E70{i}" for i in range(ASM.n)]}
        for name, uris in layouts.items():
            for mode in ("sender thread", "blocking"):
                with emulated_crazyradios(PEER_PORT), (_blocking_sends() if mode == "blocking"
                                                       else contextlib.nullcontext()):
                    rows.append([name, mode] + _run(uris, args.seconds, args.rate, peer))
    finally:
        peer.stop_event.set()
        th.join(5)
        peer.close()
    print_table(f"Crazyflie backend links at {args.rate:g} Hz, {args.seconds:g} s each, 2 modules",
                ["link", "send", "send p50 us", "p99 us", "max us", "late periods", "superseded",
                 "accepted/s (min module)", "round trip ms"], rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
