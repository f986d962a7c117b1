"""The option types of mocap-bridge and sim-peer's mocap (refusals: rows of tests/faults/test_absurd_input.py)."""

import click
import pytest

from groundstation.cli.mocap_cmd import BODY, BodyList, KeyChunks, ListenEndpoint, MockBodies


@pytest.mark.parametrize("kind, value", [
    (KeyChunks("many"), "mocap/lab-1"), (BODY, "assembly_2"), (BodyList(), " a, b ,c"),
    (MockBodies(), f"assembly(0.5,-0.25,1.5,{0.5 ** 0.5},0.0,0.0,{0.5 ** 0.5})"), (MockBodies(), ""),
    (ListenEndpoint(), "tcp/127.0.0.1:7448"), (ListenEndpoint(), "tls/[::1]:7448"),
    (ListenEndpoint(), "tcp/lab-host:1"), (ListenEndpoint(), "unixsock-stream//tmp/mocap.sock"),
])
def test_what_is_not_absurd_passes_as_given(kind, value):
    assert kind.convert(value, None, None) == value


@pytest.mark.parametrize("kind, value", [
    (KeyChunks("many"), "mocap/**"), (BODY, "a/b"), (BODY, "$*"), (BodyList(), "a,b c"),
    (MockBodies(), "a(0,0,1,1,0,0,0,5)"), (MockBodies(), "a(0x10,0,1,1,0,0,0)"), (MockBodies(), "a(inf,0,1,1,0,0,0)"),
    (MockBodies(), "a(0,0,1,0.5,0,0,0)"), (MockBodies(), "a*(0,0,1,1,0,0,0)"), (MockBodies(), "a (0,0,1,1,0,0,0)"),
    (ListenEndpoint(), "tcp/127.0.0.1:0"), (ListenEndpoint(), "udp/127.0.0.1:65536"), (ListenEndpoint(), "tcp/host"),
])
def test_what_is_absurd_is_refused(kind, value):
    with pytest.raises(click.BadParameter):
        kind.convert(value, None, None)


def test_mock_bodies_are_passed_as_the_mock_reads_them():
    """libmotioncapture's mock makes a space part of the body's name (" b": never published as "b")."""
    import motioncapture

    given = "a(0,0,1,1,0,0,0); b( 1.5, -2, 0.1, 0.7071, 0.7071, 0, 0 )"
    text = MockBodies().convert(given, None, None)
    assert text == "a(0.0,0.0,1.0,1.0,0.0,0.0,0.0);b(1.5,-2.0,0.1,0.7071,0.7071,0.0,0.0)"
    mc = motioncapture.connect("mock", {"hostname": "", "rigid_bodies": text})
    mc.waitForNextFrame()
    assert sorted(mc.rigidBodies) == ["a", "b"] and list(mc.rigidBodies["b"].position) == pytest.approx([1.5, -2, 0.1])
