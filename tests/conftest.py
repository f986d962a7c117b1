"""Test configuration: the repository root is importable so tests can use ``benchmarks`` as an oracle."""

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


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


def _workers_wanted(config) -> bool:
    return bool(getattr(config.option, "numprocesses", None)) and config.option.dist != "no"


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    """Parallel workers (``-n``) need a loopback each (``own_network.py``); where this machine cannot give them one,
    say so and run in this process, not in workers that would take each other's ports and links."""
    from tests.own_network import available

    if _workers_wanted(config) and not available():
        config.issue_config_time_warning(pytest.PytestConfigWarning(
            "-n ignored: this machine gives the test workers no network namespace of their own (needs root or "
            "unprivileged user namespaces), and they share fixed loopback ports: running in one process"), 2)
        config.option.numprocesses, config.option.dist, config.option.tx = 0, "no", []


COMPUTING = ("assembly", "control", "design", "estimation", "cli/test_design_cmd.py", "cli/test_enumerate_cmd.py",
             "cli/test_optimize_cmd.py", "test_config.py", "test_layers.py", "test_output.py", "test_rotations.py")
"""Test files that only compute (no flight, no link, no process of ours beside them), by path under ``tests/``."""


@pytest.fixture(scope="module", autouse=True)
def _one_flying_file_at_a_time(request, tmp_path_factory):
    """In a parallel worker, a test file that flies, links or starts processes holds a lock shared by the workers
    while it runs; files that only compute (:data:`COMPUTING`) run beside it. Two flights at once on 2 cores, each
    with a real-time loop, its simulator and its log writer, starved each other's writers and links beyond any
    bound of theirs (a CI machine is not a lab machine running two flights); one flight beside a computing test is
    a flight beside a busy neighbour, which every test must pass."""
    rel = request.path.relative_to(Path(__file__).parent).as_posix()
    if not os.environ.get("PYTEST_XDIST_WORKER") or any(rel == c or rel.startswith(c + "/") for c in COMPUTING):
        yield
        return
    import fcntl

    with open(tmp_path_factory.getbasetemp().parent / "flying.lock", "a") as lock:  # the workers' common basetemp
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


@pytest.fixture(scope="session", autouse=True)
def _own_link_locks(tmp_path_factory):
    """In a parallel worker, the links' host locks (``$XDG_RUNTIME_DIR/groundstation-links``) in a directory of its
    own: both workers fly links named alike (``udp://127.0.0.1:19850``), each on its own loopback."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        os.environ["XDG_RUNTIME_DIR"] = str(tmp_path_factory.mktemp("runtime"))


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_setupnodes(config, specs):
    """Start every worker through ``own_network.py``: a loopback and link locks of its own."""
    import shlex

    wrapper = Path(__file__).with_name("own_network.py")
    for spec in specs:
        spec.python = f"{shlex.quote(sys.executable)} {shlex.quote(str(wrapper))}"
