"""Virtual motion capture: the simulator's physics pose published on Zenoh like a real mocap system.

Called after every physics step; publishes what the sensor model (:class:`~sim.mocap_sensor.MocapSensor`: a rate,
Gaussian noise, a latency) delivers, stamped with the host's wall clock at capture time, with the same codec and
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
from sim.mocap_sensor import MocapSensor


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
        self._pub_lock = threading.Lock()
        """Held while a pose is sent, so a publisher replaced by :meth:`restart` is never used after."""
        self._sensor = MocapSensor(rate_hz, position_noise, attitude_noise, latency, np.random.default_rng(seed))
        self._clock = clock
        self.published = 0
        self.paused = False
        """While True nothing is published (fault injection: a mocap dropout)."""
        self.frozen = False
        """While True the pose last published is published again, freshly stamped (fault injection: a tracker
        that holds a lost body's pose)."""
        self._held = None
        self._outbox: deque = deque()
        self._activity = activity or LoopActivity()
        self._closed = False
        self._thread = threading.Thread(target=self._send_loop, name="virtual-mocap", daemon=True) \
            if threaded else None
        if self._thread is not None:
            self._thread.start()

    def on_step(self, t_sim: float, state: RigidState, wall: float | None = None) -> None:
        """The physics reached ``t_sim`` (s) in ``state``; ``wall``: the host's wall clock that moment belongs to
        (default: now, for a simulation kept at the present)."""
        wall = self._clock() if wall is None else wall
        for m in self._sensor.observe(t_sim, state):
            if self.paused:
                continue
            if not self.frozen or self._held is None:
                self._held = m
            stamp = wall - (t_sim - m.t)  # the host's wall clock when the pose was captured
            m = self._held
            if self._thread is None:
                with self._pub_lock:
                    self._pub.publish(m.position, m.rotation, stamp)
            else:
                self._outbox.append((m.position, m.rotation, stamp))  # no wake-up: the thread sends between periods
            self.published += 1

    def _send_loop(self) -> None:
        while not self._closed:
            self._activity.wait_end(0.005)
            while self._outbox and self._activity.may_work(3e-4):  # encode + put: ~0.1 ms
                with self._pub_lock:
                    self._pub.publish(*self._outbox.popleft())

    @property
    def current_publisher(self) -> PosePublisher:
        return self._pub

    def restart(self, publisher: PosePublisher) -> PosePublisher:
        """Publish through ``publisher`` from now on (a restarted bridge: a new entity id, its own sequence); returns
        the one replaced, no longer used, for the caller to close."""
        with self._pub_lock:
            old, self._pub = self._pub, publisher
        return old

    def close(self) -> None:
        """Send what is pending and stop the publishing thread (if any). Idempotent."""
        if self._thread is not None and not self._closed:
            self._closed = True
            self._thread.join(2.0)
            with self._pub_lock:
                while self._outbox:
                    self._pub.publish(*self._outbox.popleft())
