"""The simulated modules' real-time loop: what its motion capture says when the machine starves it."""

import time

import numpy as np
import pytest

from groundstation.mocap.zenoh_link import PoseSubscriber, open_session
from sim.crazyflie_peer import SimulatedCrazyflies
from sim.module_peer import MAX_LAG_S, PeerConfig
from tests.peers import ASM


@pytest.mark.parametrize("stall_s, pauses", [(0.02, 0), (0.06, 1)])
def test_a_starved_peer_stamps_its_poses_when_the_schedule_put_them(stall_s, pauses):
    """A peer held up for 20 ms catches up by stepping fast; the poses it captures meanwhile are stamped at the
    moments its real-time schedule gives them (100 Hz mocap on 240 Hz physics: 2 or 3 steps apart), not when
    they are caught up with: stamped at the catch-up, a state 30 ms old looked current and pulled the ground
    station's estimator off by its speed x 30 ms per pose (a V flipped in a Crazyflie dry run). Held up for 60 ms,
    beyond ``MAX_LAG_S``, its world pauses instead: one gap in the stamps, as long as the stall, and counted."""
    peer = SimulatedCrazyflies(ASM, PeerConfig(port=19960, mocap_endpoint="tcp/127.0.0.1:7490"))
    serve, stalled = peer._serve, []

    def slow_once(now):
        if peer.sim.time > 0.3 and not stalled:
            stalled.append(now)
            time.sleep(stall_s)
        serve(now)

    peer._serve = slow_once
    peer.open()
    session = open_session(connect=["tcp/127.0.0.1:7490"])
    try:
        sub = PoseSubscriber(session, peer.config.mocap_key)
        time.sleep(0.3)  # the subscription reaches the peer
        peer.run(duration=0.8)
        time.sleep(0.1)
        stamps = np.array([stamp for _, _, stamp in sub.drain_raw()])
    finally:
        session.close()
        peer.close()
    assert stalled and len(stamps) > 40 and peer.pauses == pauses
    steps = np.diff(stamps) * 240.0
    on_schedule = (np.abs(steps - np.round(steps)) < 0.05) & np.isin(np.round(steps), (2, 3))  # 2 or 3 steps apart
    paused = steps > (MAX_LAG_S + 0.005) * 240.0  # the world paused: a gap of about the stall
    assert np.all(on_schedule | paused), np.round(steps, 2)
    assert paused.sum() == pauses
