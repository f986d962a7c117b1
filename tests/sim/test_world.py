"""The dry run's world in preflight: its physics follows the preflight's clock, and a stalled process pauses it."""

import time

import numpy as np

from groundstation.loop_activity import LoopActivity
from groundstation.mocap.zenoh_link import PoseSubscriber, open_session
from groundstation.runtime.fly import Faults, prepare
from sim.module_peer import MAX_LAG_S
from sim.world import SimulatedWorld
from tests.runtime.test_fly import config_with

ENDPOINT = "tcp/127.0.0.1:7498"
STALL_S = 1.0


def test_a_stalled_preflight_pauses_the_world_instead_of_racing(tmp_path):
    """The preflight's watch settles the world every few ms; held up for a second, the next call catches up
    ``MAX_LAG_S`` and the world pauses for the rest: one gap in the poses' stamps, about as long as the stall, and
    none rejected. Caught up in one call, the second's poses left at once with nearly one stamp (100 of them at
    100 Hz, a few rejected by the subscriber)."""
    p = prepare(config_with(tmp_path, endpoint=ENDPOINT), log_path=tmp_path / "unused.mcap")
    with SimulatedWorld(p.assembly, p.cfg, p.key, [ENDPOINT], Faults(), LoopActivity()) as world:
        session = open_session(connect=[ENDPOINT])
        try:
            sub = PoseSubscriber(session, p.key)
            time.sleep(0.3)  # the subscription reaches the world
            stamps, t0, stalled = [], time.monotonic(), False
            while (t := time.monotonic() - t0) < 1.0 + STALL_S:
                world.settle(t)
                if t > 0.4 and not stalled:
                    stalled = True
                    time.sleep(STALL_S)
                time.sleep(0.005)
                stamps += [stamp for _, _, stamp in sub.drain_raw()]
            time.sleep(0.1)
            stamps += [stamp for _, _, stamp in sub.drain_raw()]
            rejected = sub.rejected
        finally:
            session.close()
        physics_s = world.backend.time
    gaps = np.diff(stamps)
    assert len(stamps) > 60
    assert np.count_nonzero(gaps < 0.002) <= 5, np.round(gaps * 1e3, 1)  # a catch-up of MAX_LAG_S: 2-3 poses
    assert rejected == 0
    assert STALL_S - 0.05 < gaps.max() < STALL_S + 0.05  # the pause
    assert physics_s < 1.0 + MAX_LAG_S + 0.05  # behind the clock by the stall (less the catch-up)
    assert world.pauses >= 1  # more only if the machine held a turn up beyond MAX_LAG_S
