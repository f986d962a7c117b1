"""Zenoh over mutual TLS on loopback, configured from a flight config, with certificates made here by openssl."""

import shutil
import subprocess
import time

import numpy as np
import pytest

from groundstation.config import validate
from groundstation.errors import ConfigError, SessionError
from groundstation.mocap.zenoh_link import PosePublisher, PoseSubscriber, open_session
from groundstation.runtime.flight_config import MocapSection, mocap_security

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")


def _certificates(d):
    """A lab CA and two peers' certificates (for localhost and 127.0.0.1), and a stranger's own CA."""
    def run(*args):
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True)

    (d / "ext.cnf").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    for ca in ("lab", "stranger"):
        run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{ca}-ca.key", "-out", f"{ca}-ca.pem",
            "-days", "2", "-subj", f"/CN={ca}-ca")
    for name, ca in (("gs", "lab"), ("mocap", "lab"), ("intruder", "stranger")):
        run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj",
            "/CN=localhost")
        run("x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}-ca.pem", "-CAkey", f"{ca}-ca.key",
            "-CAcreateserial", "-out", f"{name}.pem", "-days", "2", "-extfile", "ext.cnf")


def test_mutual_tls_from_the_flight_config(tmp_path):
    _certificates(tmp_path)
    section = validate(MocapSection, {"endpoint": "tls/127.0.0.1:7612", "listen": True,
                                      "tls": {"root_ca": "lab-ca.pem", "certificate": "gs.pem",
                                              "private_key": "gs.key"}})
    gs = mocap_security(section, tmp_path, "flight.toml")
    mocap = validate(MocapSection, {"endpoint": "tls/localhost:7612", "tls": {
        "root_ca": "lab-ca.pem", "certificate": "mocap.pem", "private_key": "mocap.key"}})
    a = open_session(listen=["tls/127.0.0.1:7612"], security=gs)
    b = open_session(connect=["tls/localhost:7612"], security=mocap_security(mocap, tmp_path, "m.toml"))
    try:
        sub = PoseSubscriber(a, "mocap/body/pose")
        pub = PosePublisher(b, "mocap/body/pose")
        time.sleep(0.5)
        pub.publish(np.array([0.1, 0.2, 1.0]), np.eye(3), time.time())
        assert sub.wait_for(1, timeout=3.0)
        np.testing.assert_allclose(sub.latest().position, [0.1, 0.2, 1.0])
        # A peer whose certificate the lab CA did not sign gets no session with the ground station.
        intruder = validate(MocapSection, {"endpoint": "tls/localhost:7612", "tls": {
            "root_ca": "lab-ca.pem", "certificate": "intruder.pem", "private_key": "intruder.key"}})
        try:
            c = open_session(connect=["tls/localhost:7612"], security=mocap_security(intruder, tmp_path, "i"))
        except SessionError:
            c = None
        if c is not None:
            bad = PosePublisher(c, "mocap/body/pose")
            time.sleep(0.5)
            bad.publish(np.array([9.0, 9.0, 9.0]), np.eye(3), time.time())
            time.sleep(0.5)
            c.close()
        assert sub.received == 1 and sub.foreign == 0 and sub.malformed == 0
    finally:
        b.close()
        a.close()


def test_tls_config_errors_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match="with tls the endpoint must be tls/HOST:PORT"):
        validate(MocapSection, {"endpoint": "tcp/127.0.0.1:7448", "tls": {"root_ca": "x", "certificate": "c",
                                                                          "private_key": "k"}})
    with pytest.raises(ConfigError, match="mutual TLS needs this peer's certificate"):
        validate(MocapSection, {"endpoint": "tls/127.0.0.1:7448", "tls": {"root_ca": "x"}})
    section = validate(MocapSection, {"endpoint": "tls/127.0.0.1:7448", "tls": {
        "root_ca": "nope.pem", "certificate": "c.pem", "private_key": "k.pem"}})
    with pytest.raises(ConfigError, match=r"flight.toml: mocap.tls.root_ca: file not found"):
        mocap_security(section, tmp_path, "flight.toml")
