"""Motion-capture bridge: read a real mocap system through ``motioncapture`` and publish poses on Zenoh.

Systems: ``vicon``, ``optitrack``, ``qualisys``, ``vrpn`` and ``mock`` (libmotioncapture's simulated system,
for dry runs and tests). The Python binding carries no timestamps, so every frame is stamped with the host's
wall clock when ``waitForNextFrame`` returns (the age the subscriber measures then includes the system's
own latency, which is the conservative side).

Frames: poses are published in a z-up world frame, metres. Vicon and Qualisys stream z-up; OptiTrack streams
whatever Motive is set to: set "Up Axis" to Z in Motive's streaming pane, or pass ``y_up=True`` to convert a
y-up stream (x' = x, y' = -z, z' = y, rotations conjugated accordingly).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from groundstation.choices import MOCAP_SYSTEMS
from groundstation.errors import UsageError
from groundstation.mocap.auth import MocapKey
from groundstation.mocap.zenoh_link import PosePublisher, Security, open_session, pose_key
from groundstation.rotations import quat_to_matrix

SYSTEMS = MOCAP_SYSTEMS
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass
class BridgeStats:
    frames: int = 0
    published: dict | None = None
    missing: dict | None = None
    """Frames in which a requested body was not seen, per body."""


def run_bridge(system: str, host: str, bodies: list[str], endpoint: str, key_prefix: str = "mocap",
               listen: bool = True, y_up: bool = False, mock_bodies: str = "", duration: float | None = None,
               stop: threading.Event | None = None, on_frame: Callable[[int], None] | None = None,
               security: Security | None = None, mac_key: MocapKey | None = None) -> BridgeStats:
    """Publish every requested body's pose per mocap frame until ``stop`` is set or ``duration`` elapses; with
    ``mac_key`` every sample carries a MAC (:mod:`groundstation.mocap.auth`)."""
    if system not in SYSTEMS:
        raise UsageError(f"unknown mocap system {system!r}; choose one of {', '.join(SYSTEMS)}")
    if not bodies:
        raise UsageError("name at least one rigid body (--bodies)")
    import motioncapture

    params = {"hostname": host}
    if system == "mock":
        params["rigid_bodies"] = mock_bodies or ";".join(f"{b}(0,0,0,1,0,0,0)" for b in bodies)
    try:
        mc = motioncapture.connect(system, params)
    except Exception as exc:  # the C++ layer raises RuntimeError with the SDK's reason
        raise UsageError(f"cannot connect to {system} at {host!r}: {exc}") from None
    stop = stop or threading.Event()
    stats = BridgeStats(published={b: 0 for b in bodies}, missing={b: 0 for b in bodies})
    session = open_session(listen=[endpoint] if listen else [], connect=[] if listen else [endpoint],
                           security=security)
    pubs = {b: PosePublisher(session, pose_key(key_prefix, b), mac_key) for b in bodies}
    t_end = time.monotonic() + duration if duration is not None else None
    try:
        while not stop.is_set() and (t_end is None or time.monotonic() < t_end):
            mc.waitForNextFrame()
            stamp = time.time()
            seen = mc.rigidBodies
            for b in bodies:
                rb = seen.get(b)
                if rb is None:
                    stats.missing[b] += 1
                    continue
                q = rb.rotation
                pos = np.asarray(rb.position, dtype=float)
                rot = quat_to_matrix((q.x, q.y, q.z, q.w))
                if y_up:
                    pos, rot = Y_UP_TO_Z_UP @ pos, Y_UP_TO_Z_UP @ rot @ Y_UP_TO_Z_UP.T
                pubs[b].publish(pos, rot, stamp)
                stats.published[b] += 1
            stats.frames += 1
            if on_frame is not None:
                on_frame(stats.frames)
    finally:
        for p in pubs.values():
            p.close()
        session.close()
    return stats
