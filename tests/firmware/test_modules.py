"""Every module's parameters checked at once, through the real cflib against simulated Crazyflies."""

import threading

from groundstation.firmware import modules
from groundstation.firmware.modules import check_modules, required_params
from groundstation.firmware.params import issues
from groundstation.runtime.flight_config import load_flight_config
from sim.crazyflie_peer import SimulatedCrazyflies
from tests.peers import start_peer, stop_peer
from tests.runtime.test_fly import sitl_config


def _backend(tmp_path, port: int):
    cfg, base = load_flight_config(sitl_config(tmp_path, "crazyflie", port, "tcp/127.0.0.1:7610"))
    return cfg.backend, required_params(cfg.backend, base)


def test_modules_are_checked_at_once_and_reported_in_their_order(tmp_path, monkeypatch):
    backend, wanted = _backend(tmp_path, 19732)
    both = threading.Barrier(len(backend.modules), timeout=60)  # broken unless every check runs at the same time

    def check(link, i, wanted, apply, cache_dir):
        both.wait()
        return [modules.ParamCheck(i, link, "p", 1.0, 1.0)]

    monkeypatch.setattr(modules, "load", lambda _path: check)
    progress = []
    checks = check_modules(backend, wanted, on_module=progress.append)
    assert [(c.module, c.link) for c in checks] == list(enumerate(backend.modules))
    assert progress == [1, 2]


def test_modules_answering_all_but_their_parameters_cost_two_waits_each(tmp_path):
    """A module whose link and console answer but whose parameter service never does: two attempts each (five,
    each waiting the whole timeout, kept ``params`` 51 s on two modules; one alone gave up on a table of contents
    that a lossy link had stalled), named with what it did answer."""
    backend, wanted = _backend(tmp_path, 19732)
    peer, th = start_peer(SimulatedCrazyflies, 19732, 7610)
    asked = [0, 0]
    try:
        for i in range(2):
            def mute(head, channel, body, i=i):
                asked[i] += 1
                return []

            peer.firmware(i).services._param_service = mute
        checks = check_modules(backend, wanted)
    finally:
        stop_peer(peer, th)
    assert all(c.unreachable for c in checks) and all(asked), asked
    assert issues(checks) == [f"module {i} ({link}) does not answer: it answered, but its parameters did not arrive "
                              f"within 5 s (2 attempts)" for i, link in enumerate(backend.modules)]
