"""The flight log written by foxglove-sdk's native MCAP writer in the flight process, for comparison only.

``benchmarks.loop --writer sdk`` puts this in place of :class:`groundstation.flightlog.mcap_log.FlightLog` to
measure whether the SDK (encoding and writing in Rust) could replace the writer process: the records are
serialized (JSON, protobuf) on the caller's thread, which is the control loop's, and handed to the SDK there.
"""

from __future__ import annotations

import json
import time

import foxglove
import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap_protobuf.schema import build_file_descriptor_set

from groundstation.flightlog.mcap_log import LEVELS, _jsonable, _stamp, _with_attitudes
from groundstation.flightlog.scene import module_transforms, scene
from groundstation.flightlog.schemas import schema_of
from groundstation.rotations import matrix_to_quat


class SdkFlightLog:
    """The subset of FlightLog's interface ``fly`` uses, on foxglove-sdk's MCAP writer."""

    def __init__(self, path, metadata=None, activity=None, live_port=None) -> None:
        self.path = path
        self._writer = foxglove.open_mcap(str(path), allow_overwrite=True)
        self._channels: dict[str, foxglove.Channel] = {}
        self.error = None
        self.dropped = 0

    def _channel(self, topic: str, message_type=None) -> foxglove.Channel:
        ch = self._channels.get(topic)
        if ch is None:
            if message_type is None:
                schema = foxglove.Schema(name=topic.strip("/").replace("/", "."), encoding="jsonschema",
                                         data=schema_of(topic))
                ch = foxglove.Channel(topic, message_encoding="json", schema=schema)
            else:
                schema = foxglove.Schema(name=message_type.DESCRIPTOR.full_name, encoding="protobuf",
                                         data=build_file_descriptor_set(message_type).SerializeToString())
                ch = foxglove.Channel(topic, message_encoding="protobuf", schema=schema)
            self._channels[topic] = ch
        return ch

    def protobuf(self, topic: str, message, t: float) -> None:
        self._channel(topic, type(message)).log(message.SerializeToString(), log_time=int(t * 1e9))

    def raw_protobuf(self, topic, message_type, payload, t, publish_time=None) -> None:
        self._channel(topic, message_type).log(payload, log_time=int(t * 1e9))

    def record(self, topic: str, data: dict, t: float) -> None:
        self._channel(topic).log(json.dumps(_with_attitudes(data), default=_jsonable).encode(),
                                 log_time=int(t * 1e9))

    def event(self, level: str, text: str, t: float, name: str = "groundstation") -> None:
        self.protobuf("/log", Log(timestamp=_stamp(t), level=LEVELS[level], message=text, name=name), t)

    def pose(self, topic: str, position, rotation, t: float) -> None:
        msg = PoseInFrame(timestamp=_stamp(t), frame_id="world")
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = matrix_to_quat(np.asarray(rotation, float))
        tf = FrameTransform(timestamp=_stamp(t), parent_frame_id="world", child_frame_id="body")
        tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in position)
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = o.x, o.y, o.z, o.w
        self.protobuf(topic, msg, t)
        self.protobuf("/tf", tf, t)

    def scene(self, assembly, t, reference=None, geofence=None) -> None:
        for tf in module_transforms(assembly, t):
            self.protobuf("/tf", tf, t)
        self.protobuf("/scene", scene(assembly, t, reference, geofence), t)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
            time.sleep(0.01)
