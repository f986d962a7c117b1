"""What Foxglove gets from a flight, checked with Foxglove's official protobuf schemas: the scene and transform
tree that make the assembly move in the 3D panel, and the live view, by a client speaking the Foxglove WebSocket
protocol (the JSON channels and the shipped layout by Foxglove's own rules: :mod:`tests.flightlog.test_schemas`)."""

import json
import logging
import os
import struct
import threading
import time

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader
from mcap_protobuf.schema import build_file_descriptor_set
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from groundstation.assembly.assembly_file import load_assembly
from groundstation.flightlog.mcap_log import SUBPROTOCOLS, _Live
from groundstation.flightlog.scene import scene
from groundstation.runtime.flight import Requests
from groundstation.runtime.fly import fly
from tests.peers import ROOT
from tests.runtime.test_fly import config_with

LIVE_PORT = 8791
ASM, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
MODULE_FRAMES = {("body", f"module_{i}") for i in range(ASM.n)}
FRAMES = MODULE_FRAMES | {("world", "body")}
"""(parent, child) of every transform: the estimate's, every period, and one per module."""
LATE_CLIENT_S = 10.0
"""How long the client that connects mid-flight waits for the scene and every transform: they come when it
subscribes (and again every second), so on a slow machine this only bounds a failing run, s."""
DECODERS = {"foxglove.SceneUpdate": SceneUpdate, "foxglove.FrameTransform": FrameTransform}


class Client:
    """A Foxglove WebSocket client (subprotocol ``foxglove.sdk.v1``, the one with inline schemas): subscribes to
    ``topics`` as they are advertised and keeps what arrives on them, decoded by the advertised encoding and schema
    name (protobuf by Foxglove's official classes, JSON), and the server's status messages."""

    def __init__(self, ws, topics: tuple[str, ...]) -> None:
        self.ws = ws
        self.advertised: dict[str, dict] = {}
        """topic -> its channel as advertised (id, encoding, schemaName, ...)."""
        self.received: dict[str, list] = {t: [] for t in topics}
        self.status: list[str] = []
        self._subscriptions: dict[int, str] = {}
        """subscription id -> topic."""

    def poll(self, timeout: float) -> None:
        """Handle what arrives within ``timeout`` s (at most one message); raises ConnectionClosed at the end."""
        try:
            msg = self.ws.recv(timeout=timeout)
        except TimeoutError:
            return
        if isinstance(msg, str):
            op = json.loads(msg)
            if op["op"] == "advertise":
                self._subscribe(op["channels"])
            elif op["op"] == "status":  # e.g. "Unknown channel ID": a refused subscription
                self.status.append(op["message"])
        elif msg[0] == 0x01:  # message data: opcode, subscription id (u32), log time (u64, ns), payload
            topic = self._subscriptions[struct.unpack_from("<I", msg, 1)[0]]
            ch = self.advertised[topic]
            payload = msg[13:]
            self.received[topic].append(json.loads(payload) if ch["encoding"] == "json"
                                        else DECODERS[ch["schemaName"]].FromString(payload))

    def _subscribe(self, channels: list[dict]) -> None:
        wanted = []
        for ch in channels:
            self.advertised[ch["topic"]] = ch
            if ch["topic"] in self.received and ch["topic"] not in self._subscriptions.values():
                sid = len(self._subscriptions) + 1
                self._subscriptions[sid] = ch["topic"]
                wanted.append({"id": sid, "channelId": ch["id"]})
        if wanted:
            self.ws.send(json.dumps({"op": "subscribe", "subscriptions": wanted}))

    def frames(self) -> set[tuple[str, str]]:
        """(parent, child) of every transform received on ``/tf``."""
        return {(tf.parent_frame_id, tf.child_frame_id) for tf in self.received["/tf"]}


def _watch_until(client: Client, done, deadline: float) -> None:
    """Poll ``client`` until ``done()`` or the deadline (or the flight's end: the assertions say what was missed)."""
    while not done() and time.monotonic() < deadline:
        try:
            client.poll(1.0)
        except ConnectionClosed:
            return


@pytest.fixture(scope="module")
def live_flight(tmp_path_factory):
    """A dry run served live, watched by three clients in turn, and what the log writer printed (its standard error
    is the terminal's: the pilot's status line). The first client, subscribed to /control from the start, records
    what it saw; the flight tracks until it has seen it tracking (the operator's land request ends the flight, so
    a slow machine only makes it longer). Mid-flight, a client offering only the older subprotocol
    ``foxglove.websocket.v1`` is refused, and a third one subscribes to /scene and /tf until it has the scene and
    every transform (or :data:`LATE_CLIENT_S` has passed)."""
    tmp = tmp_path_factory.mktemp("foxglove")
    cfg = config_with(tmp, endpoint="tcp/127.0.0.1:7488")
    log, stderr = tmp / "live.mcap", tmp / "stderr.txt"
    result = {}
    requests = Requests()
    flight = threading.Thread(target=lambda: result.update(res=fly(cfg, duration=60.0, log_path=log,
                                                                   live_port=LIVE_PORT, requests=requests)))
    seen = {}
    terminal = os.dup(2)
    with open(stderr, "wb") as fh:  # the writer process inherits this descriptor as its standard error
        os.dup2(fh.fileno(), 2)
    try:
        flight.start()
        deadline = time.monotonic() + 90.0
        ws = None
        while ws is None and time.monotonic() < deadline and flight.is_alive():
            try:
                ws = connect(f"ws://127.0.0.1:{LIVE_PORT}", subprotocols=[SUBPROTOCOLS[0]], open_timeout=1)
            except OSError:
                time.sleep(0.1)
        assert ws is not None, "the live view never came up"
        with ws:
            first = Client(ws, ("/control",))
            _watch_until(first, lambda: sum(r["phase"] == "track" for r in first.received["/control"]) >= 10,
                         deadline)
        seen["first"] = first
        try:  # mid-flight (a flight that ended early, e.g. a failsafe, refuses the connections: the tests say why)
            try:  # what the @foxglove/ws-protocol client and Lichtblick before 1.22 offer
                connect(f"ws://127.0.0.1:{LIVE_PORT}", subprotocols=["foxglove.websocket.v1"], open_timeout=5).close()
                seen["old_subprotocol"] = "accepted"
            except InvalidStatus as exc:
                seen["old_subprotocol"] = exc.response.status_code
            with connect(f"ws://127.0.0.1:{LIVE_PORT}", subprotocols=[SUBPROTOCOLS[0]], open_timeout=5) as ws:
                late = Client(ws, ("/scene", "/tf"))
                seen["late_while_tracking"] = flight.is_alive() and not requests.land.is_set()
                _watch_until(late, lambda: late.received["/scene"] and late.frames() >= FRAMES,
                             time.monotonic() + LATE_CLIENT_S)
            seen["late"] = late
        except OSError as exc:
            seen["mid_flight"] = f"{type(exc).__name__}: {exc}"
    finally:
        requests.land.set()
        flight.join(120)
        os.dup2(terminal, 2)
        os.close(terminal)
    return result["res"], log, seen, stderr.read_text()


def _mid_flight(live_flight) -> dict:
    """What the clients that connected mid-flight saw; fails naming how the flight ended if none could."""
    res, _, seen, _ = live_flight
    assert "late" in seen, f"the flight ended ({res.phase}: {res.reason}) before a client connected mid-flight " \
                           f"({seen.get('mid_flight')})"
    return seen


def test_the_live_view_serves_the_flight(live_flight):
    res, _, seen, _ = live_flight
    first = seen["first"]
    assert res.phase == "done" and res.reason == "operator land"
    assert {"/control", "/tf", "/state/pose", "/mocap/assembly", "/scene"} <= set(first.advertised)
    assert first.status == []
    records = first.received["/control"]
    assert sum(r["phase"] == "track" for r in records) >= 10
    assert "modules" in records[-1] and "attitude_target" in records[-1]


def test_a_client_connecting_mid_flight_gets_the_scene_and_every_transform(live_flight):
    """The scene and the body -> module transforms are written once, before the server starts: a client gets them
    because they are sent to each one that subscribes (and to all every second)."""
    seen = _mid_flight(live_flight)
    late = seen["late"]
    assert seen["late_while_tracking"]  # it connected while the flight was tracking, long after the scene was written
    assert late.status == []
    assert (late.advertised["/scene"]["encoding"], late.advertised["/scene"]["schemaName"]) == \
        ("protobuf", "foxglove.SceneUpdate")
    assert late.advertised["/tf"]["schemaName"] == "foxglove.FrameTransform"
    assert late.received["/scene"], "no scene reached a client that connected mid-flight"
    upd = late.received["/scene"][-1]
    ents = {e.id: e for e in upd.entities}
    assert set(ents) == {"assembly", "reference", "geofence"}
    assert ents["assembly"].frame_id == "body" and len(ents["assembly"].cubes) == ASM.n
    assert late.frames() == FRAMES  # every transform, and only those
    for i, p in enumerate(ASM.module_positions):
        tf = next(tf for tf in late.received["/tf"] if tf.child_frame_id == f"module_{i}")
        np.testing.assert_allclose([tf.translation.x, tf.translation.y, tf.translation.z], p, atol=1e-12)


def test_a_refused_client_is_logged_not_printed(live_flight):
    """The SDK refuses a client that offers only ``foxglove.websocket.v1`` (its handshake knows the sdk
    subprotocols only); that goes to the flight's /log, not over the pilot's status line."""
    _, log, _, printed = live_flight
    assert _mid_flight(live_flight)["old_subprotocol"] == 400
    events = [Log.FromString(m.data) for _, m in _messages(log, "/log")]
    refusals = [e for e in events if "handshake failed" in e.message]
    assert refusals and all(e.name.startswith("foxglove.") and e.level == Log.ERROR for e in refusals)
    assert "handshake failed" not in printed and "Dropping client" not in printed


def test_a_new_subscriber_gets_the_static_messages_at_once():
    """Without a flight: a client subscribing to /scene gets the scene written before the server started at the
    writer's next turn (:meth:`_Live.serve`), not only at the once-a-second resend."""
    live = _Live(0)
    try:
        live.publish("/scene", "protobuf", "foxglove.SceneUpdate", "protobuf",
                     build_file_descriptor_set(SceneUpdate).SerializeToString(), scene(ASM, 1.0).SerializeToString(),
                     10**9, static=True)
        live.publish("/control", "json", "control", "jsonschema", b"{}", b"{}", 10**9)  # starts the server
        with connect(f"ws://127.0.0.1:{live._server.port}", subprotocols=[SUBPROTOCOLS[0]], open_timeout=5) as ws:
            client = Client(ws, ("/scene",))
            deadline = time.monotonic() + 5.0
            while not live._subscribed and time.monotonic() < deadline:  # the SDK reports it on its own thread
                client.poll(0.05)
            live.serve(2 * 10**9)
            while not client.received["/scene"] and time.monotonic() < deadline:
                client.poll(0.1)
        assert [u.entities[0].id for u in client.received["/scene"]] == ["assembly"]
    finally:
        live.close()
        logging.getLogger("foxglove").removeHandler(live.log)


def _messages(log, topic):
    with open(log, "rb") as fh:
        return [(s, m) for s, _, m in make_reader(fh).iter_messages([topic])]


def test_scene_and_transforms_with_the_official_schemas(live_flight):
    _, log, _, _ = live_flight
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
    _, log, _, _ = live_flight
    (schema, msg), *_ = _messages(log, "/control")
    assert schema.encoding == "jsonschema"
    props = json.loads(schema.data)["properties"]
    assert {"state", "setpoint", "attitude_target", "roll_target_deg", "yaw_target_deg", "modules"} <= set(props)
    record = json.loads(msg.data)
    assert set(record) <= set(props)  # every field the writer wrote is described



def test_a_client_that_stops_reading_does_not_hold_the_writer(tmp_path):
    """A live client subscribes to everything and never reads again while the flight writes 4 kB records: the
    writer finishes the file and exits with its result (before: the server's stop() blocked 40-75 s, the flight
    reported "the log writer did not finish the file" and the port stayed taken for the next flight)."""
    import socket

    from groundstation.flightlog.mcap_log import FlightLog

    path = tmp_path / "stalled.mcap"
    port = LIVE_PORT + 7
    log = FlightLog(path, live_port=port)
    log.scene(ASM, 0.0)
    log.record("/control", {"t_s": 0.0}, 0.0)  # the server starts with the first record
    ws = None
    deadline = time.monotonic() + 10.0
    while ws is None and time.monotonic() < deadline:
        try:
            ws = connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOLS[0]], open_timeout=2)
        except OSError:
            log.record("/control", {"t_s": 0.0}, 0.0)
            time.sleep(0.1)
    assert ws is not None, "the live server did not come up"
    client = Client(ws, ("/scene", "/tf", "/control"))
    while len(client.advertised) < 3 and time.monotonic() < deadline:
        log.record("/control", {"t_s": 0.0, "pad": "x" * 4000}, 0.0)
        client.poll(0.05)
    for k in range(2000):  # ~8 MB nobody reads: the socket buffers fill
        log.record("/control", {"t_s": k * 0.004, "pad": "x" * 4000}, k * 0.004)
    log.close()
    assert log.error is None
    with open(path, "rb") as fh:  # finished: the summary is there
        assert make_reader(fh).get_summary() is not None
    with socket.socket() as s:  # the writer process is gone and nothing listens there (closed connections linger)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
    ws.close()


def test_a_flood_of_server_warnings_is_kept_to_its_rate_and_counted(monkeypatch):
    """A client retrying a refused handshake in a loop: one SDK warning per attempt, 10 a second reach /log, and
    then one record with how many more there were."""
    from groundstation.flightlog import mcap_log

    clock = [100.0]
    monkeypatch.setattr(mcap_log.time, "monotonic", lambda: clock[0])
    handler = mcap_log._SdkLog()
    logger = logging.getLogger("foxglove.test-flood")
    logger.propagate = False
    logger.addHandler(handler)
    try:
        for k in range(1000):  # 1000 in 0.5 s
            clock[0] = 100.0 + k * 0.0005
            logger.warning("Dropping client %d: handshake failed", k)
        clock[0] = 101.2  # the next second
        logger.warning("Dropping client 1000: handshake failed")
    finally:
        logger.removeHandler(handler)
    messages = [r.getMessage() for r in handler.records]
    assert messages[:10] == [f"Dropping client {k}: handshake failed" for k in range(10)]
    assert messages[10] == "990 more messages of the live server in a second, not logged"
    assert messages[11:] == ["Dropping client 1000: handshake failed"]


def test_a_live_view_that_fails_costs_the_log_nothing(tmp_path, monkeypatch):
    """The live server raising while it serves its clients: the writer stops the live view, says so on /log, and
    finishes the file (before, the exception ended the writer: the flight landed on "log writer failed")."""
    from groundstation.flightlog import mcap_log

    def broken(self, ns):
        raise RuntimeError("the server's socket went away")

    monkeypatch.setattr(mcap_log._Live, "serve", broken)
    path = tmp_path / "live.mcap"
    writer = mcap_log._Writer(str(path), {"config": "{}"}, live_port=LIVE_PORT + 9)
    writer.serve()
    writer.serve()  # the live view is off now: nothing more to fail
    writer.finish()
    with open(path, "rb") as fh:
        logs = [Log.FromString(m.data).message for _, _, m in make_reader(fh).iter_messages(["/log"])]
    assert logs == [f"live view on port {LIVE_PORT + 9} stopped: RuntimeError: the server's socket went away"]
