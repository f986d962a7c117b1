"""The assembly as Foxglove draws it in its 3D panel, with no set-up: a scene and the transform tree.

Transforms (``/tf``): ``world -> body`` every control period (from the state estimate, written with each pose),
and ``body -> module_<i>`` once at the start (the modules are rigidly joined: their poses in the body frame are the
assembly's). Scene (``/scene``, ``foxglove.SceneUpdate``), written once at the start:

* ``assembly``, frame-locked to ``body`` (it moves with the estimate): one cube per module, one arrow per rotor
  along its thrust axis, and each module's downwash capsule (a cylinder between two spheres, radius ``r`` along
  ``mu in [capsule_a, capsule_b]`` below the module, the volume the design kept free of other modules);
* ``reference``, in ``world``: the reference trajectory of the flight;
* ``geofence``, in ``world``: the box the flight must stay in.
"""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.timestamp_pb2 import Timestamp

from groundstation.assembly.assembly import Assembly
from groundstation.rotations import matrix_to_quat

MODULE_COLOR = (0.1, 0.1, 0.1, 0.9)
ROTOR_COLOR = (0.85, 0.1, 0.1, 1.0)
CAPSULE_COLOR = (0.55, 0.2, 0.75, 0.18)
REFERENCE_COLOR = (0.2, 0.2, 0.2, 0.8)
FENCE_COLOR = (0.9, 0.5, 0.0, 0.6)


def stamp(t: float) -> Timestamp:
    """A protobuf timestamp of ``t`` s since the epoch."""
    return Timestamp(seconds=int(t), nanos=int((t % 1) * 1e9))


def module_frame(i: int) -> str:
    return f"module_{i}"


def _pose(p, position, rotation) -> None:
    p.position.x, p.position.y, p.position.z = (float(v) for v in position)
    q = p.orientation
    q.x, q.y, q.z, q.w = matrix_to_quat(np.asarray(rotation, float))


def _color(c, rgba) -> None:
    c.r, c.g, c.b, c.a = rgba


def _axis_to_x(axis: np.ndarray) -> np.ndarray:
    """A rotation taking +x to ``axis`` (Foxglove arrows point along their +x)."""
    x = axis / np.linalg.norm(axis)
    helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


def module_transforms(assembly: Assembly, t: float) -> list[FrameTransform]:
    """``body -> module_<i>`` for every module."""
    out = []
    for i, (p, r) in enumerate(zip(assembly.module_positions, assembly.module_rotations, strict=True)):
        tf = FrameTransform(timestamp=stamp(t), parent_frame_id="body", child_frame_id=module_frame(i))
        tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in p)
        q = tf.rotation
        q.x, q.y, q.z, q.w = matrix_to_quat(np.asarray(r, float))
        out.append(tf)
    return out


def scene(assembly: Assembly, t: float, reference: np.ndarray | None = None,
          geofence: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None) -> SceneUpdate:
    """The scene of an assembly; ``reference``: (k, 3) points of the reference path, world frame, m;
    ``geofence``: (lower, upper) corners of the flight box, world frame, m."""
    prm = assembly.params
    upd = SceneUpdate()
    ent = upd.entities.add(timestamp=stamp(t), frame_id="body", id="assembly", frame_locked=True)
    hx, hy, hz = prm.frame_half_extents
    a, b = prm.capsule_a, prm.capsule_b
    for p, r in zip(assembly.module_positions, assembly.module_rotations, strict=True):
        cube = ent.cubes.add()
        _pose(cube.pose, p, r)
        cube.size.x, cube.size.y, cube.size.z = 2 * hx, 2 * hy, 2 * hz
        _color(cube.color, MODULE_COLOR)
        down = -np.asarray(r)[:, 2]
        cyl = ent.cylinders.add()  # Foxglove cylinders stand along their z: the module's thrust axis
        _pose(cyl.pose, p + down * (a + b) / 2, r)
        cyl.size.x = cyl.size.y = 2 * prm.r
        cyl.size.z = b - a
        cyl.bottom_scale = cyl.top_scale = 1.0
        _color(cyl.color, CAPSULE_COLOR)
        for mu in (a, b):
            sph = ent.spheres.add()
            _pose(sph.pose, p + down * mu, r)
            sph.size.x = sph.size.y = sph.size.z = 2 * prm.r
            _color(sph.color, CAPSULE_COLOR)
    for pos, axis in zip(assembly.rotor_positions, assembly.rotor_axes, strict=True):
        arrow = ent.arrows.add(shaft_length=0.08, shaft_diameter=0.006, head_length=0.03, head_diameter=0.016)
        _pose(arrow.pose, pos, _axis_to_x(np.asarray(axis, float)))
        _color(arrow.color, ROTOR_COLOR)
    if reference is not None and len(reference) > 1:
        ref = upd.entities.add(timestamp=stamp(t), frame_id="world", id="reference")
        line = ref.lines.add(type=LinePrimitive.LINE_STRIP, thickness=0.004, scale_invariant=False)
        line.pose.orientation.w = 1.0
        for q in np.asarray(reference, float):
            pt = line.points.add()
            pt.x, pt.y, pt.z = (float(v) for v in q)
        _color(line.color, REFERENCE_COLOR)
    if geofence is not None:
        lo, hi = np.asarray(geofence[0], float), np.asarray(geofence[1], float)
        fence = upd.entities.add(timestamp=stamp(t), frame_id="world", id="geofence")
        line = fence.lines.add(type=LinePrimitive.LINE_LIST, thickness=0.01, scale_invariant=False)
        line.pose.orientation.w = 1.0
        corners = [np.where([i & 1, i & 2, i & 4], hi, lo) for i in range(8)]
        for i in range(8):
            for bit in (1, 2, 4):
                if not i & bit:
                    for c in (corners[i], corners[i | bit]):
                        pt = line.points.add()
                        pt.x, pt.y, pt.z = (float(v) for v in c)
        _color(line.color, FENCE_COLOR)
    return upd
