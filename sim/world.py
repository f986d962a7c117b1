"""The simulated world of a dry run (``backend.kind = "sim"``): PyBullet physics in the ground-station process,
publishing its pose over Zenoh through a virtual mocap, so a dry run exercises the same loop, Zenoh path and
logging as a flight with real mocap. The flight advances it to the wall time at the start of every period.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from typing import TYPE_CHECKING

import numpy as np

from groundstation.assembly.assembly import Assembly
from groundstation.control.state import RigidState
from groundstation.loop_activity import LoopActivity
from groundstation.mocap.auth import MocapKey
from groundstation.mocap.zenoh_link import PosePublisher, Security, open_session
from sim.module_peer import MAX_LAG_S
from sim.pybullet_backend import PyBulletBackend, SimConfig
from sim.virtual_mocap import VirtualMocap

if TYPE_CHECKING:  # types only: the runtime reaches this module through groundstation.backend_kinds
    from groundstation.runtime.flight_config import FlightConfig
    from groundstation.runtime.fly import Faults


def _decoy(resting: RigidState, height: float) -> RigidState:
    """Another body, at rest: where the assembly rested, ``height`` m higher."""
    return RigidState(resting.position + np.array([0.0, 0.0, height]), np.zeros(3), resting.rotation, np.zeros(3))


class SimulatedWorld:
    """PyBullet plus a virtual mocap; ``listen``: the Zenoh endpoints it listens on (empty: it connects to the
    config's endpoint, where the ground station listens)."""

    def __init__(self, assembly: Assembly, cfg: FlightConfig, key: str, listen: list[str], faults: Faults,
                 activity: LoopActivity, security: Security | None = None, mac_key: MocapKey | None = None) -> None:
        m = cfg.mocap
        self.faults = faults
        self._paused_s = 0.0
        """Preflight time the world stood still while the process stalled, s (its schedule is that much later)."""
        self.pauses = 0
        """Times the physics fell more than ``MAX_LAG_S`` behind the preflight's clock and the world paused."""
        self._stack = ExitStack()
        connect = [] if listen else [m.endpoint]
        session = open_session(listen=listen, connect=connect, security=security)
        self._stack.callback(session.close)
        publisher = PosePublisher(session, key, mac_key)
        vmocap = VirtualMocap(publisher, m.rate_hz, m.position_noise, np.radians(m.attitude_noise_deg), m.latency_s,
                              threaded=True, activity=activity)
        self._stack.callback(lambda: vmocap.current_publisher.close())
        self._stack.callback(vmocap.close)

        restarts = [0]
        resting: list[RigidState] = []
        climbed = [0.0, 0.0]  # the decoy's height above its rest, m; the physics time of the last step, s

        def observe(t_sim, state):
            resting[:] = resting or [state]  # where it stood at the start: the decoy's pose
            vmocap.paused = faults.mocap_paused
            vmocap.frozen = faults.mocap_frozen
            self.backend.stuck_gyros = faults.gyros_stuck  # from the preflight on: a failure before take-off
            if faults.mocap_restarts > restarts[0]:
                restarts[0] = faults.mocap_restarts
                replaced = vmocap.restart(PosePublisher(session, key, mac_key))
                replaced.close()
            if faults.mocap_decoy:
                climbed[0] += faults.mocap_decoy_climb_mps * (t_sim - climbed[1])
            climbed[1] = t_sim
            vmocap.on_step(t_sim, _decoy(resting[0], climbed[0]) if faults.mocap_decoy else state)

        self.backend = PyBulletBackend(assembly, SimConfig(physics_hz=cfg.backend.physics_hz,
                                                           motor_time_constant=cfg.backend.motor_time_constant,
                                                           gyro_delay=cfg.backend.gyro_delay_s,
                                                           mocap_rate_hz=0.0),  # the virtual mocap measures
                                       observers=[observe])
        self.backend.connect()
        self._stack.callback(self.backend.close)
        self._stack.callback(self.backend.emergency_stop)  # runs first on the way out: motors off

    @property
    def truth(self) -> Callable[[], RigidState]:
        """The physics state, logged beside the mocap estimate."""
        return self.backend.true_state

    def settle(self, t: float) -> None:
        """Preflight: ``t`` s have passed since it began; the physics (from 0) catches up, and the assembly settles
        on the ground. Kept on the wall clock so that the virtual mocap's poses come at its rate: 0.02 s of
        physics for every ~10 ms turn of the preflight's watch sent a 100 Hz stream at 215 Hz. A call catches up
        ``MAX_LAG_S`` at most and the rest of the way the world pauses (as a module peer's does): every pose of
        a catch-up is stamped at the call, and a 1.5 s stall caught up at once sent 65 poses with nearly one
        stamp, 5 of them rejected."""
        behind = t - self._paused_s - self.backend.time
        if behind > MAX_LAG_S:
            self._paused_s += behind - MAX_LAG_S
            self.pauses += 1
        self.backend.advance_to(t - self._paused_s)

    def before_period(self, on_period: Callable[[float], None] | None) -> Callable[[float], None]:
        """What runs at the start of every period: the faults applied, the caller's hook, physics to time ``t``."""
        t0 = self.backend.time

        def advance(t: float) -> None:
            self.backend.link_ok = not self.faults.link_lost
            self.backend.failed_gyro = self.faults.gyro_failed
            self.backend.flipped_gyros = self.faults.gyros_flipped
            self.backend.push = self.faults.push_n
            if self.faults.tied_down:
                self.backend.tie_down()
            if on_period is not None:
                on_period(t)
            self.backend.advance_to(t0 + t)

        return advance

    def __enter__(self) -> SimulatedWorld:
        return self

    def __exit__(self, *exc) -> None:
        self._stack.close()
