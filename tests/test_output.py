"""A write that fails part way (a full disk) is one line naming the file, and a figure is closed all the same."""

import pytest

from groundstation.design.figures import plot_costs
from groundstation.errors import UsageError
from groundstation.output import writing
from tests.disks import full


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
