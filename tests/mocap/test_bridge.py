import threading
import time

import numpy as np
import pytest

from groundstation.errors import UsageError
from groundstation.mocap.auth import MocapKey, load_key_file
from groundstation.mocap.bridge import Y_UP_TO_Z_UP, run_bridge
from groundstation.mocap.zenoh_link import PoseSubscriber, open_session

pytest.importorskip("motioncapture")


def test_mock_system_poses_reach_a_subscriber():
    endpoint = "tcp/127.0.0.1:7485"
    stop = threading.Event()
    result = {}

    def bridge():
        # quaternion (w, x, y, z) = 90 deg about z
        result["stats"] = run_bridge("mock", "", ["assembly"], endpoint,
                                     mock_bodies=f"assembly(0.5,-0.25,1.5,{np.sqrt(0.5)},0,0,{np.sqrt(0.5)})",
                                     stop=stop)

    th = threading.Thread(target=bridge)
    th.start()
    time.sleep(0.5)
    gs = open_session(connect=[endpoint])
    sub = PoseSubscriber(gs, "mocap/assembly/pose")
    ok = sub.wait_for(5, timeout=5.0)
    s = sub.latest()
    measured = sub.measurements()
    stop.set()
    th.join(timeout=10)
    sub.close()
    gs.close()
    assert ok
    np.testing.assert_allclose(s.position, [0.5, -0.25, 1.5], atol=1e-6)
    np.testing.assert_allclose(s.rotation, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-6)
    assert measured and 0 <= sub.now() - measured[-1].t < 1.0  # timed on this process's clock
    assert result["stats"].published["assembly"] >= 5 and result["stats"].missing["assembly"] == 0


def test_y_up_conversion_maps_up_to_z():
    np.testing.assert_allclose(Y_UP_TO_Z_UP @ [0, 1, 0], [0, 0, 1])
    assert np.linalg.det(Y_UP_TO_Z_UP) == pytest.approx(1.0)


def test_bad_arguments():
    with pytest.raises(UsageError, match="unknown mocap system"):
        run_bridge("kinect", "", ["a"], "tcp/127.0.0.1:7486")
    with pytest.raises(UsageError, match="at least one rigid body"):
        run_bridge("mock", "", [], "tcp/127.0.0.1:7486")


def test_the_bridge_cli_authenticates_with_the_key_file(tmp_path, cli):
    """``mocap-key`` then ``mocap-bridge --key-file``: a subscriber with the key takes every pose, one with
    another key takes none (counted)."""
    code, out, err = cli("mocap-key", str(tmp_path / "lab.key"))
    assert code == 0 and "mode 600" in out
    key = load_key_file(tmp_path / "lab.key")
    endpoint = "tcp/127.0.0.1:7488"
    done = threading.Thread(target=cli, args=("mocap-bridge", "--system", "mock", "--bodies", "assembly",
                                              "--endpoint", endpoint, "--duration", "1.5", "--key-file",
                                              str(tmp_path / "lab.key")))
    done.start()
    time.sleep(0.5)
    gs = open_session(connect=[endpoint])
    good = PoseSubscriber(gs, "mocap/assembly/pose", mac_key=key)
    bad = PoseSubscriber(gs, "mocap/assembly/pose", mac_key=MocapKey(bytes(32)))
    assert good.wait_for(5, timeout=5.0)
    done.join(timeout=10)
    bad.poll()
    for s in (good, bad):
        s.close()
    gs.close()
    assert good.unauthenticated == 0 and bad.accepted == 0 and bad.unauthenticated >= 5
