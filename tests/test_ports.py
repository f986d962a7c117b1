"""The test groups that run beside each other under pytest-xdist (``tests/conftest.py``) never share a loopback port:
every port number written in a ``tests/faults`` file (or in a shipped config it names) is written in no other test
file that may fly at the same time, nor one or two above it (a peer's second and third module links)."""

from __future__ import annotations

import re
from pathlib import Path

from groundstation.runtime.flight_config import MocapSection
from sim.module_peer import PeerConfig
from tests.conftest import COMPUTE_ONLY, ROOT, SEPARATE_PORTS, xdist_scope

PORT = re.compile(r"(?<![\d.\w])(7\d{3}|8\d{3}|1[4-9]\d{3}|2\d{4})(?![\d.])")
"""The ranges the tests take their ports from (Zenoh 7xxx-8xxx, module links 14xxx-2xxxx)."""
CONFIG = re.compile(r"configs/[\w/]+\.(?:toml|json)")
LINKS_PER_PEER = 3
"""A peer at port p serves module i at p + i: the toy assemblies have 2 modules, one test 3."""


def _product_defaults() -> set[int]:
    """The shipped configs' and the product's own default ports (Zenoh 7448, the simulated modules' 19850): in
    fault rows they are only text that a row replaces or a config that is refused before anything opens."""
    mocap = int(MocapSection().endpoint.rsplit(":", 1)[1])
    peer = PeerConfig.__dataclass_fields__["port"].default
    return {p + i for p in (mocap, peer, peer + 1) for i in range(LINKS_PER_PEER)}  # as _ports reads them


def _ports(path: Path) -> set[int]:
    """The port numbers written in ``path`` and in the shipped configs it names, each with the ports of the further
    links of a peer there."""
    text = path.read_text()
    for name in CONFIG.findall(text):
        if (ROOT / name).is_file():
            text += (ROOT / name).read_text()
    return {p + i for p in map(int, PORT.findall(text)) for i in range(LINKS_PER_PEER)}


def test_the_fault_rows_share_no_port_with_the_other_flights():
    faults, others = {}, {}
    for path in sorted((ROOT / "tests").rglob("*.py")):
        top = path.relative_to(ROOT / "tests").parts[0]
        if top in COMPUTE_ONLY or path.name == "test_ports.py":
            continue
        (faults if top == SEPARATE_PORTS else others)[path] = _ports(path)
    assert len(faults) > 5 and len(others) > 20  # the scan found the files
    defaults = _product_defaults()
    assert defaults >= {7448, 19850}, defaults
    theirs = set().union(*others.values())
    shared = {str(p.relative_to(ROOT)): sorted((ports - defaults) & theirs) for p, ports in faults.items()}
    assert not any(shared.values()), {k: v for k, v in shared.items() if v}


def test_the_scan_sees_a_shared_port():
    """The check above would fail on a clash: the scan reads ports as flights spell them."""
    a = ROOT / "tests/faults/test_slow_links.py"
    assert 22974 in _ports(a) and 22975 in _ports(a)  # PX4_PEER and its second module's link
    assert {7461, 7462} <= _ports(ROOT / "tests/runtime/test_fly.py")  # config_with's endpoint


def test_the_groups_are_the_directories():
    assert xdist_scope("tests/faults/test_slow_links.py::test_fault[px4-links-swapped-in-flight]") == "faults"
    assert xdist_scope("tests/runtime/test_fly.py::test_fly_sitl[mavlink]") == "flights"
    assert xdist_scope("tests/test_ports.py::test_the_groups_are_the_directories") == "flights"
    pure = "tests/design/test_paper_iv_c.py::test_iv_c_feasible"
    assert xdist_scope(pure) == pure
