"""A write that fails part way (a full disk) is one line naming the file, and a figure is closed all the same."""

import os
import subprocess
import sys

import pytest

from groundstation.design.figures import plot_costs
from groundstation.errors import UsageError
from groundstation.output import writing
from tests.disks import full
from tests.peers import ROOT


def test_a_full_disk_is_a_usage_error_naming_the_file(tmp_path):
    out = full(tmp_path / "out.json")
    with pytest.raises(UsageError, match=r"^.*out\.json: cannot write: No space left on device$"), writing(out), \
            open(out, "w") as fh:
        fh.write("x" * 100)  # buffered: the error comes from the flush at close, naming no file


def test_a_figure_on_a_full_disk_is_closed(tmp_path):
    import matplotlib.pyplot as plt

    rows = [{"n": 2, "feasible": True, "cost": 1.0, "code": "oE"}]
    with pytest.raises(UsageError, match="fig5.png: cannot write"):
        plot_costs(rows, 2, full(tmp_path / "fig5.png"))
    assert plt.get_fignums() == []
    assert plot_costs(rows, 2, tmp_path / "ok.png").stat().st_size > 1000


def test_closed_standard_descriptors_are_held_on_dev_null(tmp_path):
    """With descriptors 1 and 2 closed (``>&- 2>&-``), the next file opened takes descriptor 1 and what the process
    prints lands in it; held on /dev/null first, a file opened after gets another descriptor and stays clean."""
    script = (
        "import os, sys\n"
        "from groundstation.output import hold_standard_descriptors\n"
        "if sys.argv[1] == 'hold':\n"
        "    hold_standard_descriptors()\n"
        "fd = os.open(sys.argv[2], os.O_WRONLY | os.O_CREAT)\n"
        "os.write(1, b'summary')\n"
        "null = os.stat(os.devnull).st_rdev == os.fstat(1).st_rdev\n"
        "os.close(fd)\n"
        "print(fd, null, file=open(sys.argv[3], 'w'))\n"
    )

    def closed():
        os.close(1)
        os.close(2)

    for mode in ("bare", "hold"):
        log, report = tmp_path / f"{mode}.log", tmp_path / f"{mode}.txt"
        subprocess.run([sys.executable, "-c", script, mode, str(log), str(report)], cwd=ROOT, preexec_fn=closed,
                       check=True, timeout=60)
        fd, null = report.read_text().split()
        if mode == "bare":
            assert (fd, log.read_bytes()) == ("1", b"summary")  # what the process printed, in the file
        else:
            assert int(fd) > 2 and null == "True" and log.read_bytes() == b""


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_stderr_on_a_full_device_changes_no_exit_status_nor_stdout(tmp_path):
    """Stderr carries the diagnostics: on a full device they are lost, the command's status and its output are not
    (bad input exited 1 with a traceback nobody saw, and a warning before the output made ``replay`` print nothing:
    hostile campaign 30)."""
    def run(*args: str) -> subprocess.CompletedProcess:
        with open("/dev/full", "w") as full_stderr:
            return subprocess.run([sys.executable, "-m", "groundstation", *args], cwd=ROOT, stdout=subprocess.PIPE,
                                  stderr=full_stderr, text=True, timeout=120)

    assert run("enumerate", "0").returncode == 2  # bad input, its one line lost
    missing = run("replay", str(tmp_path / "none.mcap"))
    assert missing.returncode == 2 and missing.stdout == ""
    levels = run("enumerate", "3", "--json")  # a progress bar on stderr meanwhile
    assert levels.returncode == 0 and [line.count('"n"') for line in levels.stdout.splitlines()] == [1, 1, 1]
