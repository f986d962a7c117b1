"""``groundstation mocap-key``: the key the mocap bridge and the ground station share (authenticated mocap); the option
types of ``mocap-bridge`` and ``sim-peer``'s mocap (keys, mock bodies, the endpoint they listen on)."""

from __future__ import annotations

import math
import re

import click

from groundstation.mocap.auth import write_key_file


@click.command("mocap-key")
@click.argument("path", type=click.Path(dir_okay=False))
def mocap_key_command(path: str) -> int:
    """Write a new random mocap key to PATH (readable by you only; an existing file is never replaced).

    Give the same file to the bridge (mocap-bridge --key-file PATH) and to the flight (mocap.key_file): every pose
    then carries a MAC, and the ground station uses no sample without a valid one.
    """
    written = write_key_file(path)
    click.echo(f"wrote a new mocap key to {written} (mode 600): copy it to the mocap host over a trusted channel")
    return 0


class KeyChunks(click.ParamType):
    """A Zenoh key option: concrete chunks (``chunks``: "one", or "many" separated by ``/``), the rules and the
    check of the flight config's ``mocap.body`` and ``mocap.key_prefix``: a wildcard (``*``, ``**``, ``$*``) would
    publish on (or subscribe to) every body's key."""

    name = "key"

    def __init__(self, chunks: str) -> None:
        self.chunks = chunks

    def convert(self, value, param, ctx):
        from groundstation.runtime.flight_config import _concrete_key

        try:
            return _concrete_key(value, self.chunks)
        except ValueError as exc:
            self.fail(str(exc), param, ctx)


BODY = KeyChunks("one")
"""One rigid body's name (a key chunk)."""


class BodyList(click.ParamType):
    """Comma-separated rigid body names, each a concrete key chunk (:class:`KeyChunks`); returned as given."""

    name = "bodies"

    def convert(self, value, param, ctx):
        for body in (b.strip() for b in value.split(",")):
            if body:
                BODY.convert(body, param, ctx)
        return value


MOCK_BODY = re.compile(r"\s*([^();\s]+)\(([^()]*)\)\s*")
"""One body of ``--mock-bodies``: ``name(x,y,z,qw,qx,qy,qz)``."""
UNIT_QUATERNION_TOLERANCE = 1e-3
"""How far a mock body's quaternion's norm may be from 1 (a rounded unit quaternion: 0.7071 is 0.99998)."""


class MockBodies(click.ParamType):
    """The mock system's bodies, ``name(x,y,z,qw,qx,qy,qz)`` separated by ``;``: each name a key chunk, the position
    finite and within the largest geofence, the quaternion a unit one (libmotioncapture's mock publishes NaN, a zero
    quaternion and bodies it cannot parse as they come, or not at all); returned as its parser reads it (no spaces:
    it makes them part of the name, or drops the body)."""

    name = "bodies"

    def convert(self, value, param, ctx):
        from groundstation.runtime.flight_config import MAX_GEOFENCE_M

        bodies = []
        for entry in filter(str.strip, value.split(";")):
            m = MOCK_BODY.fullmatch(entry)
            if m is None:
                self.fail(f"{entry.strip()!r} is not name(x,y,z,qw,qx,qy,qz)", param, ctx)
            BODY.convert(m[1], param, ctx)
            try:
                numbers = [float(x) for x in m[2].split(",")]
            except ValueError:
                numbers = []
            if len(numbers) != 7 or not all(math.isfinite(x) for x in numbers):
                self.fail(f"{entry.strip()!r}: need 7 finite numbers (x,y,z,qw,qx,qy,qz)", param, ctx)
            if max(abs(x) for x in numbers[:3]) > MAX_GEOFENCE_M:
                self.fail(f"{entry.strip()!r}: a position beyond {MAX_GEOFENCE_M:g} m", param, ctx)
            norm = math.hypot(*numbers[3:])
            if abs(norm - 1.0) > UNIT_QUATERNION_TOLERANCE:
                self.fail(f"{entry.strip()!r}: the quaternion's norm is {norm:.4g}, not 1", param, ctx)
            bodies.append(f"{m[1]}({','.join(repr(x) for x in numbers)})")
        return ";".join(bodies)


class ListenEndpoint(click.ParamType):
    """A Zenoh endpoint to listen on: an IP one (``tcp/HOST:PORT``, ``tls``, ``udp``, ``quic``) on a port of 1-65535
    (0 listens on a port no one is told of; beyond 65535 Zenoh's own error names no option)."""

    name = "endpoint"

    def convert(self, value, param, ctx):
        from groundstation.runtime.flight_config import endpoint_port_problem

        problem = endpoint_port_problem(value)
        if problem:
            self.fail(problem, param, ctx)
        return value
