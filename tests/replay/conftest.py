"""The flight every replay test reads: a 5 s figure-8 of the two-module V, roll held at -5 deg, simulated through
``fly`` (made once for the package: a flight takes ~15 s)."""

import pytest

from groundstation.runtime.fly import fly
from tests.runtime.test_fly import config_with


@pytest.fixture(scope="package")
def sim_flight(tmp_path_factory):
    """(the flight's result, its log)."""
    tmp = tmp_path_factory.mktemp("replay")
    cfg = config_with(tmp, endpoint="tcp/127.0.0.1:7485", **{"roll_deg = 0.0": "roll_deg = -5.0"})
    log = tmp / "roll-5.mcap"
    res = fly(cfg, duration=5.0, log_path=log)
    assert res.phase == "done"
    return res, log
