import pytest

from groundstation.cli import main


@pytest.fixture
def cli(capsys):
    """Run ``groundstation ARGS...`` in-process; returns (exit code, stdout, stderr)."""

    def run(*args):
        with pytest.raises(SystemExit) as ex:
            main(list(args))
        out, err = capsys.readouterr()
        return ex.value.code, out, err

    return run
