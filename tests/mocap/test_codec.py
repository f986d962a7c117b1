import numpy as np
import pytest

from groundstation.control.trajectory import euler_zyx
from groundstation.mocap.codec import PoseSample, decode, encode


def test_round_trip():
    s = PoseSample(42, 1234.5678, np.array([0.1, -0.2, 1.3]), euler_zyx(0.1, -0.4, 2.0))
    back = decode(*encode(s))
    assert back.sequence == 42 and back.stamp == s.stamp
    np.testing.assert_allclose(back.position, s.position)
    np.testing.assert_allclose(back.rotation, s.rotation, atol=1e-12)


@pytest.mark.parametrize("payload, attachment", [
    (b"\xff\xff\xff", b"\x00" * 16),
    (encode(PoseSample(1, 0.0, np.zeros(3), np.eye(3)))[0], None),
    (encode(PoseSample(1, 0.0, np.zeros(3), np.eye(3)))[0], b"\x00" * 3),
])
def test_malformed_rejected(payload, attachment):
    with pytest.raises(ValueError):
        decode(payload, attachment)
