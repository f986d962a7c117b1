"""The simulated modules' real-time loop: what its motion capture says when the machine starves it."""

import time

import numpy as np

from groundstation.mocap.zenoh_link import PoseSubscriber, open_session
from sim.crazyflie_peer import SimulatedCrazyflies
from sim.module_peer import PeerConfig
from tests.peers import ASM


def test_a_starved_peer_stamps_its_poses_when_the_schedule_put_them():
    """A peer held up for 60 ms catches up by stepping fast; the poses it captures meanwhile are stamped at the
    moments its real-time schedule gives them (100 Hz mocap on 240 Hz physics: 2 or 3 steps apart), not when
    they are caught up with: stamped at the catch-up, a state 30 ms old looked current and pulled the ground
    station's estimator off by its speed x 30 ms per pose (a V flipped in a Crazyflie dry run)."""
    peer = SimulatedCrazyflies(ASM, PeerConfig(port=19960, mocap_endpoint="tcp/127.0.0.1:7490"))
    serve, stalled = peer._serve, []

    def slow_once(now):
        if peer.sim.time > 0.3 and not stalled:
            stalled.append(now)
            time.sleep(0.06)
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
    assert stalled and len(stamps) > 40
    steps = np.diff(stamps) * 240.0
    # on the schedule: 2 or 3 physics steps apart (a stall over 0.1 s would be given up on: a gap, never less)
    assert np.all((np.abs(steps - np.round(steps)) < 0.01) & np.isin(np.round(steps), (2, 3)) | (steps > 24)), \
        np.round(steps, 2)
