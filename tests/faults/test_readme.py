"""The README's reliability section counts every row of the fault table (all ``tests/faults/test_*.py`` modules),
in all and per kind."""

import importlib
import inspect
import re
from collections import Counter
from pathlib import Path

from tests.faults.table import FAULTS, KINDS

HERE = Path(__file__).resolve().parent


def test_readme_counts_every_row():
    for path in sorted(HERE.glob("test_*.py")):
        importlib.import_module(f"tests.faults.{path.stem}")
    readme = (HERE.parents[1] / "README.md").read_text()
    # pytest may have imported a row module under another name (rootdir-relative) before: one row per function
    rows = {(inspect.getsourcefile(inspect.unwrap(f.run)), f.run.__name__): f for f in FAULTS}
    ids = [f.id for f in rows.values()]
    assert len(ids) == len(set(ids)), "two rows share an id"
    assert re.findall(r"\*\*(\d+) rows\*\*", readme) == [str(len(rows))]
    counted = Counter(f.kind for f in rows.values())
    stated = {kind: re.findall(rf"^\* {re.escape(kind)} \((\d+) rows", readme, re.M) for kind in KINDS}
    assert stated == {kind: [str(counted[kind])] for kind in KINDS}
