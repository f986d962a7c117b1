"""The command line starts light: help of every command imports no numerical, simulation or link library (each
command imports what it needs when it runs). The time this saves is measured by ``benchmarks.cli_startup``."""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY = ("numpy", "scipy", "casadi", "numba", "pybullet", "zenoh", "mcap", "cflib", "pymavlink", "pydantic",
         "matplotlib", "foxglove")

PROBE = """
import json, sys
from click.testing import CliRunner
from groundstation.cli import cli
runner = CliRunner()
codes = [runner.invoke(cli, ["--help"]).exit_code]
codes += [runner.invoke(cli, [name, "--help"]).exit_code for name in sorted(cli.commands)]
print(json.dumps({"codes": codes, "commands": sorted(cli.commands),
                  "loaded": sorted({m.split(".")[0] for m in sys.modules})}))
"""


def test_help_of_every_command_imports_no_heavy_library():
    out = json.loads(subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, check=True,
                                    timeout=120).stdout)
    assert len(out["commands"]) == 11 and set(out["codes"]) == {0}
    assert [m for m in HEAVY if m in out["loaded"]] == []


def test_the_probe_sees_a_heavy_import():
    probe = PROBE.replace("from groundstation.cli import cli", "import numpy\nfrom groundstation.cli import cli")
    out = json.loads(subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True,
                                    timeout=120).stdout)
    assert "numpy" in out["loaded"]
