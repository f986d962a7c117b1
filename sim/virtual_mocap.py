"""Virtual motion capture: the simulator's physics pose published on Zenoh like a real mocap system.

Called after every physics step; publishes at ``rate_hz`` with Gaussian noise and a latency (poses are held back
and sent ``latency`` later), stamped with the host's wall clock at measurement time, the same codec and
keys the ``mocap-bridge`` uses, so a dry run goes through Zenoh end to end.
"""

from __future__ import annotations

import threading
import time
from collections import deque

import numpy as np

from groundstation.control.state import RigidState
from groundstation.loop_activity import LoopActivity
from groundstation.mocap.zenoh_link import PosePublisher
from groundstation.rotations import rotvec_to_matrix


class VirtualMocap:
    """Publishes noisy, delayed physics poses. With ``threaded``, a thread of its own encodes and sends them, as
    a real mocap system does independently of the ground station: in the ``fly`` dry run the physics runs on the
    control thread, and a Zenoh put there cost ~0.25 ms of a 2 ms period. That thread sends between control
    periods (``activity``), so a pose reaches the ground station at most one period later than it would directly.
    Call :meth:`close` to stop it."""

    def __init__(self, publisher: PosePublisher, rate_hz: float = 100.0, position_noise: float = 0.0,
                 attitude_noise: float = 0.0, latency: float = 0.0, seed: int = 0, clock=time.time,
                 threaded: bool = False, activity: LoopActivity | None = None) -> None:
        self._pub = publisher
        self._period = 1.0 / rate_hz
        self._next = 0.0
        self._pos_noise, self._att_noise, self._latency = position_noise, attitude_noise, latency
        self._rng = np.random.default_rng(seed)
        self._clock = clock
        self._pending: deque = deque()
        self.published = 0
        self.paused = False
        """While True nothing is published (fault injection: a mocap dropout)."""
        self._outbox: deque = deque()
        self._activity = activity or LoopActivity()
        self._closed = False
        self._thread = threading.Thread(target=self._send_loop, name="virtual-mocap", daemon=True) \
            if threaded else None
        if self._thread is not None:
            self._thread.start()

    def on_step(self, t_sim: float, state: RigidState) -> None:
        if t_sim + 1e-9 >= self._next:
            self._next += self._period * max(1, int((t_sim - self._next) / self._period) + 1)
            pos = state.position + self._rng.normal(0.0, self._pos_noise, 3)
            rot = state.rotation @ rotvec_to_matrix(self._rng.normal(0.0, self._att_noise, 3))
            self._pending.append((t_sim + self._latency, pos, rot, self._clock()))
        while self._pending and self._pending[0][0] <= t_sim + 1e-9:
            _, pos, rot, stamp = self._pending.popleft()
            if not self.paused:
                if self._thread is None:
                    self._pub.publish(pos, rot, stamp)
                else:
                    self._outbox.append((pos, rot, stamp))  # no wake-up: the thread sends between periods
                self.published += 1

    def _send_loop(self) -> None:
        while not self._closed:
            self._activity.wait_end(0.005)
            while self._outbox and self._activity.may_work(3e-4):  # encode + put: ~0.1 ms
                self._pub.publish(*self._outbox.popleft())

    def close(self) -> None:
        """Send what is pending and stop the publishing thread (if any). Idempotent."""
        if self._thread is not None and not self._closed:
            self._closed = True
            self._thread.join(2.0)
            while self._outbox:
                self._pub.publish(*self._outbox.popleft())
