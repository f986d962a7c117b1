import time

import numpy as np
import pytest

from groundstation.control.state import RigidState
from groundstation.mocap.zenoh_link import PosePublisher, PoseSubscriber, SubscriberSettings, open_session
from sim.virtual_mocap import VirtualMocap


@pytest.mark.parametrize("threaded", [False, True])
def test_rate_latency_and_delivery(threaded):
    a = open_session(listen=["tcp/127.0.0.1:7479"])
    b = open_session(connect=["tcp/127.0.0.1:7479"])
    try:
        now = [0.0]
        # stamps and arrivals on one clock; the measurements timed at capture (the latency taken off)
        sub = PoseSubscriber(b, "mocap/v/pose", SubscriberSettings(latency=0.02), clock=lambda: now[0])
        pub = PosePublisher(a, "mocap/v/pose")
        time.sleep(0.3)
        vm = VirtualMocap(pub, rate_hz=100.0, latency=0.02, threaded=threaded, clock=lambda: now[0])
        measured = []
        for k in range(1, 241):  # 1 s of physics at 240 Hz, moving along x at 1 m/s, in real time
            now[0] = t = k / 240
            vm.on_step(t, RigidState(np.array([t, 0.0, 1.0]), np.zeros(3), np.eye(3), np.zeros(3)))
            time.sleep(1 / 240)
            measured += sub.measurements()
        vm.close()
        assert sub.wait_for(vm.published, timeout=2.0)
        # measured at the first physics step of every 10 ms, each sent 20 ms later: 98 are out after 1 s
        assert vm.published == 98
        assert sub.received == 98 and sub.missed == 0 and sub.rejected == 0
        # the newest pose out: measured at the first physics step after 0.97 s (233/240 s), sent 20 ms later
        assert sub.latest().position[0] == pytest.approx(233 / 240, abs=1e-12)
        measured += sub.measurements()
        assert len(measured) == 98
        # moving at 1 m/s from x = 0 at t = 0: a pose's x is its capture time. A measurement's time is its stamp
        # (the capture) plus the fastest sample's arrival delay less the latency: sent at the first physics step
        # after the latency, polled at the step after, so at most two physics steps late, never early
        assert all(0 <= m.t - m.position[0] <= 2 / 240 + 1e-9 for m in measured)
        sub.close()
        pub.close()
    finally:
        b.close()
        a.close()
