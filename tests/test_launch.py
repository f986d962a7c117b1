"""A Ctrl-C while the command is still loading its modules: one line and exit 130, as later."""

import subprocess
import sys

INTERRUPTED_WHILE_LOADING = """
import os, signal, sys
signal.signal(signal.SIGINT, signal.default_int_handler)  # as a shell gives it (a test runner may pass it ignored)

class Interrupt:  # the operator's Ctrl-C lands while click, a module the CLI loads, is being found
    def find_spec(self, name, path=None, target=None):
        if name == "click":
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.meta_path.insert(0, Interrupt())
from groundstation.launch import main
main()
"""


def test_a_ctrl_c_while_loading_is_one_line_and_exit_130():
    proc = subprocess.run([sys.executable, "-c", INTERRUPTED_WHILE_LOADING, "--version"], capture_output=True,
                          text=True, timeout=120)
    assert (proc.returncode, proc.stderr, proc.stdout) == (130, "groundstation: interrupted\n", "")


def test_the_command_runs_through_it():
    proc = subprocess.run([sys.executable, "-m", "groundstation", "--version"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and "groundstation, version" in proc.stdout, proc
