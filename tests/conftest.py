"""Test configuration: the repository root is importable so tests can use ``benchmarks`` as an oracle."""

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

