"""The parallel workers' loopbacks (``own_network.py``): two of them bind the same port at once."""

import subprocess
import sys
from pathlib import Path

import pytest

from tests.own_network import available

WRAPPER = Path(__file__).with_name("own_network.py")
BIND = ("import socket, sys, time; s = socket.create_server(('127.0.0.1', 7448)); print('bound', flush=True); "
        "time.sleep(1.0)")


@pytest.mark.skipif(not available(), reason="no network namespaces here (needs root or unprivileged user namespaces)")
def test_two_workers_bind_the_same_loopback_port_at_once():
    held = subprocess.Popen([sys.executable, "-c", BIND], stdout=subprocess.PIPE, text=True)
    try:
        assert held.stdout.readline() == "bound\n"  # 7448 taken here
        runs = [subprocess.Popen([sys.executable, str(WRAPPER), "-c", BIND], stdout=subprocess.PIPE, text=True)
                for _ in range(2)]
        assert [r.communicate(timeout=30)[0] for r in runs] == ["bound\n"] * 2
        assert [r.returncode for r in runs] == [0, 0]
    finally:
        held.kill()
        held.wait()
