import time

import numpy as np
import pytest

from groundstation.errors import SessionError
from groundstation.mocap.zenoh_link import PosePublisher, PoseSubscriber, open_session


@pytest.fixture
def sessions():
    a = open_session(listen=["tcp/127.0.0.1:7481"])
    b = open_session(connect=["tcp/127.0.0.1:7481"])
    yield a, b
    b.close()
    a.close()


def test_measurements_on_the_local_clock_and_jump_rejection(sessions):
    a, b = sessions
    sub = PoseSubscriber(b, "mocap/body/pose")
    pub = PosePublisher(a, "mocap/body/pose")
    time.sleep(0.3)
    t0 = time.monotonic()
    for k in range(60):  # 0.5 m/s along x at 100 Hz, stamped 10 ms apart, sent at least 10 ms apart
        pub.publish(np.array([0.005 * k, 0.0, 1.0]), np.eye(3), t0 + 0.01 * k)
        time.sleep(0.01)
    pub.publish(np.array([5.0, 0.0, 1.0]), np.eye(3), t0 + 0.6)  # a 4.7 m jump in 10 ms: an outlier
    assert sub.wait_for(60, timeout=2.0)
    time.sleep(0.2)
    measured = sub.measurements()
    assert sub.received == 61 and sub.rejected == 1 and len(measured) == 60 and sub.measurements() == []
    np.testing.assert_allclose(measured[-1].position, [0.295, 0, 1.0])
    # timed by their stamps (10 ms apart) mapped onto this clock: the fastest sample's arrival, not the polls'
    np.testing.assert_allclose(np.diff([m.t for m in measured]), 0.01, atol=1e-9)
    assert 0 <= sub.now() - measured[-1].t < 1.0
    assert len(sub.drain_raw()) == 61 and sub.drain_raw() == []
    sub.close()
    pub.close()


def test_unopenable_endpoint():
    with pytest.raises(SessionError):
        open_session(listen=["tcp/256.1.1.1:1"])


def test_an_endpoint_zenoh_cannot_parse_is_a_session_error():
    """Zenoh's own parse error (a ZError from the config, a traceback at the command line) as one line."""
    with pytest.raises(SessionError, match=r"bad Zenoh endpoint \(listen None, connect \['tcp/127.0.0.1:1\?'\]\): "):
        open_session(connect=["tcp/127.0.0.1:1?"])
