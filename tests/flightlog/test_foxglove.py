"""What Foxglove gets from a flight, checked with Foxglove's official protobuf schemas: the scene and transform
tree that make the assembly move in the 3D panel, and the live view (the JSON channels and the shipped layout by
Foxglove's own rules: :mod:`tests.flightlog.test_schemas`)."""

import json
import struct
import threading
import time

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader
from mcap_protobuf.schema import build_file_descriptor_set
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from groundstation.assembly.assembly_file import load_assembly
from groundstation.runtime.flight import Requests
from groundstation.runtime.fly import fly
from tests.peers import ROOT
from tests.runtime.test_fly import config_with

LIVE_PORT = 8791
ASM, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")


@pytest.fixture(scope="module")
def live_flight(tmp_path_factory):
    """A dry run served live; a client subscribed to /control records what it saw. The flight tracks until the
    client has seen it tracking (the operator's land request ends it), so a slow machine only makes it longer."""
    tmp = tmp_path_factory.mktemp("foxglove")
    cfg = config_with(tmp, endpoint="tcp/127.0.0.1:7488")
    log = tmp / "live.mcap"
    result = {}
    requests = Requests()
    flight = threading.Thread(target=lambda: result.update(res=fly(cfg, duration=60.0, log_path=log,
                                                                   live_port=LIVE_PORT, requests=requests)))
    flight.start()
    seen = {"advertised": set(), "messages": 0, "tracking": 0, "status": []}
    deadline = time.monotonic() + 90.0
    ws = None
    while ws is None and time.monotonic() < deadline and flight.is_alive():
        try:
            ws = connect(f"ws://127.0.0.1:{LIVE_PORT}", subprotocols=["foxglove.sdk.v1"], open_timeout=1)
        except OSError:
            time.sleep(0.1)
    assert ws is not None, "the live view never came up"
    with ws:
        subscribed = False
        while time.monotonic() < deadline and seen["tracking"] < 10:
            try:
                msg = ws.recv(timeout=1.0)
            except TimeoutError:
                continue
            except ConnectionClosed:  # the flight ended: the assertions below say what was missed
                break
            if isinstance(msg, str):
                op = json.loads(msg)
                if op["op"] == "advertise":
                    for ch in op["channels"]:
                        seen["advertised"].add(ch["topic"])
                        if ch["topic"] == "/control" and not subscribed:
                            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1,
                                                                                      "channelId": ch["id"]}]}))
                            subscribed = True
                elif op["op"] == "status":  # e.g. "Unknown channel ID": a refused subscription
                    seen["status"].append(op["message"])
            elif msg[0] == 0x01 and struct.unpack_from("<I", msg, 1)[0] == 1:
                record = json.loads(msg[13:])
                seen["messages"] += 1
                seen["tracking"] += record["phase"] == "track"
                seen["last"] = record
    requests.land.set()
    flight.join(120)
    return result["res"], log, seen


def test_the_live_view_serves_the_flight(live_flight):
    res, _, seen = live_flight
    assert res.phase == "done" and res.reason == "operator land"
    assert {"/control", "/tf", "/state/pose", "/mocap/assembly"} <= seen["advertised"]
    assert seen["status"] == []
    assert seen["tracking"] >= 10 and "modules" in seen["last"] and "attitude_target" in seen["last"]


def _messages(log, topic):
    with open(log, "rb") as fh:
        return [(s, m) for s, _, m in make_reader(fh).iter_messages([topic])]


def test_scene_and_transforms_with_the_official_schemas(live_flight):
    _, log, _ = live_flight
    (schema, msg), = _messages(log, "/scene")
    # The schema in the log is the official SceneUpdate's: Foxglove decodes it as its built-in type.
    assert schema.name == "foxglove.SceneUpdate"
    assert schema.data == build_file_descriptor_set(SceneUpdate).SerializeToString()
    upd = SceneUpdate()
    upd.ParseFromString(msg.data)
    ents = {e.id: e for e in upd.entities}
    body = ents["assembly"]
    assert body.frame_id == "body" and body.frame_locked  # moves with the body transform
    n, prm = ASM.n, ASM.params
    assert (len(body.cubes), len(body.arrows), len(body.cylinders), len(body.spheres)) == (n, 4 * n, n, 2 * n)
    for cyl, p, r in zip(body.cylinders, ASM.module_positions, ASM.module_rotations, strict=True):
        centre = np.array([cyl.pose.position.x, cyl.pose.position.y, cyl.pose.position.z])
        np.testing.assert_allclose(centre, p - r[:, 2] * (prm.capsule_a + prm.capsule_b) / 2, atol=1e-9)
        assert cyl.size.x == pytest.approx(2 * prm.r) and cyl.size.z == pytest.approx(prm.capsule_b - prm.capsule_a)
    ref = ents["reference"].lines[0]
    assert ents["reference"].frame_id == "world" and ref.type == LinePrimitive.LINE_STRIP and len(ref.points) > 100
    fence = ents["geofence"].lines[0]
    pts = np.array([[q.x, q.y, q.z] for q in fence.points])
    assert fence.type == LinePrimitive.LINE_LIST and len(pts) == 24  # the 12 edges of the box
    np.testing.assert_allclose(pts.min(0), [-3.5, -3.5, -0.2]) and np.testing.assert_allclose(pts.max(0), 3.5)
    tree = {}
    for _, m in _messages(log, "/tf"):
        tf = FrameTransform()
        tf.ParseFromString(m.data)
        tree.setdefault((tf.parent_frame_id, tf.child_frame_id), []).append(tf)
    assert len(tree[("world", "body")]) > 250  # every period
    for i, p in enumerate(ASM.module_positions):
        (tf,) = tree[("body", f"module_{i}")]
        np.testing.assert_allclose([tf.translation.x, tf.translation.y, tf.translation.z], p, atol=1e-12)


def test_json_channels_carry_schemas_with_the_fields(live_flight):
    _, log, _ = live_flight
    (schema, msg), *_ = _messages(log, "/control")
    assert schema.encoding == "jsonschema"
    props = json.loads(schema.data)["properties"]
    assert {"state", "setpoint", "attitude_target", "roll_target_deg", "yaw_target_deg", "modules"} <= set(props)
    record = json.loads(msg.data)
    assert set(record) <= set(props)  # every field the writer wrote is described

