"""Test configuration: the repository root is importable so tests can use ``benchmarks`` as an oracle; under
pytest-xdist (the README's ``-n 2``) the tests that fly in real time or hold loopback ports run in two serial
groups beside each other, and the tests that only compute fill in on whichever worker is free."""

import fcntl
import os
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


COMPUTE_ONLY = ("assembly", "control", "design", "estimation")
"""Test directories that open no socket and fly nothing in real time: any worker, any order."""
SEPARATE_PORTS = "faults"
"""The directory whose tests keep to loopback ports no other test uses (``tests/test_ports.py`` checks it), so its
tests run beside the rest: each group alone runs one test at a time, as the whole suite did on one process."""


def xdist_scope(nodeid: str) -> str:
    """The unit a worker runs whole, one test after another: the fault rows, the other tests that fly or hold
    ports, or (for computation) the test alone."""
    parts = nodeid.split("::", 1)[0].split("/")
    top = parts[1] if len(parts) > 2 else ""
    if top in COMPUTE_ONLY:
        return nodeid
    return SEPARATE_PORTS if top == SEPARATE_PORTS else "flights"


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """Any distributed run keeps the groups of :func:`xdist_scope` (xdist's own ``loadgroup`` reads marks through
    node ids that pytest 9.2 no longer lets it change: pytest-xdist#1386, the groups silently lost)."""
    if config.getvalue("dist") == "each":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ScopedScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return xdist_scope(nodeid)

    return ScopedScheduling(config, log)


@pytest.fixture(autouse=True)
def _one_test_of_a_group_at_a_time(request):
    """Fail a test whose group (:func:`xdist_scope`) already runs a test elsewhere (the scheduler lost the groups,
    or a second test run on this machine uses the same ports): not a port clash that reads as a flight fault."""
    scope = xdist_scope(request.node.nodeid)
    if scope == request.node.nodeid:
        yield
        return
    with open(Path(tempfile.gettempdir()) / f"groundstation-tests-{scope}.lock", "a+") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.seek(0)
            pytest.fail(f"another test of group {scope!r} runs now (process {lock.read().strip() or '?'}): its "
                        "loopback ports are taken")
        lock.seek(0)
        lock.truncate()
        lock.write(str(os.getpid()))
        lock.flush()
        yield


@pytest.fixture
def cli(capsys):
    """Run ``groundstation ARGS...`` in-process; returns (exit code, stdout, stderr)."""
    from groundstation.cli import main

    def run(*args):
        with pytest.raises(SystemExit) as ex:
            main(list(args))
        out, err = capsys.readouterr()
        return ex.value.code, out, err

    return run

