"""The README's reliability section counts every row of the fault table (all ``tests/faults/test_*.py`` modules)."""

import importlib
import inspect
import re
from pathlib import Path

from tests.faults.table import FAULTS

HERE = Path(__file__).resolve().parent


def test_readme_counts_every_row():
    for path in sorted(HERE.glob("test_*.py")):
        importlib.import_module(f"tests.faults.{path.stem}")
    readme = (HERE.parents[1] / "README.md").read_text()
    stated = re.findall(r"\*\*(\d+) rows\*\*", readme)
    # pytest may have imported a row module under another name (rootdir-relative) before: one row per function
    rows = {(inspect.getsourcefile(f.run), f.run.__name__): f.id for f in FAULTS}
    ids = list(rows.values())
    assert len(ids) == len(set(ids)), "two rows share an id"
    assert stated == [str(len(rows))], (stated, len(rows))
