"""Every file a command writes, on a full disk: one line naming the file, exit 2, no traceback. (The flight log
under ``fly`` has its own row in the fault table; ``log recover``, ``replay --csv/--plot`` and ``enumerate --out``
JSON have rows in ``tests/faults/test_log_damage.py``.)"""

from pathlib import Path

from tests.disks import full, tiny_disk

ROOT = Path(__file__).resolve().parents[2]
TOY = str(ROOT / "configs/tasks/toy_push_y.toml")


def one_line(code: int, err: str, name: str) -> bool:
    return code == 2 and err.count("\n") == 1 and f"{name}: cannot write: No space left on device" in err


def test_enumerate_npz_and_drawing(cli, tmp_path):
    code, _, err = cli("enumerate", "4", "--out", str(full(tmp_path / "c.npz")))
    assert one_line(code, err, "c.npz"), err
    code, _, err = cli("enumerate", "3", "--draw", str(full(tmp_path / "level3.png")))
    assert one_line(code, err, "level3.png"), err


def test_design_results_filling_a_tmpfs(cli, tmp_path):
    """The results file is read before it is appended to (resume), so it is a real file on a disk with no room."""
    with tiny_disk(tmp_path / "disk", "4k") as disk:
        (disk / "fill").write_bytes(bytes(4096))
        results = disk / "r.jsonl"
        results.touch()
        code, _, err = cli("design", TOY, "--max-modules", "2", "--results", str(results))
    assert one_line(code, err, "r.jsonl"), err


def test_design_table_optimize_out_and_simulate_plot(cli, tmp_path):
    toy_v2 = str(ROOT / "configs/assemblies/toy_v2.json")
    code, _, err = cli("design", TOY, "--max-modules", "2", "--table", str(full(tmp_path / "t.csv")))
    assert one_line(code, err, "t.csv"), err
    code, _, err = cli("optimize", TOY, "--topology", "oW", "--out", str(full(tmp_path / "best.json")))
    assert one_line(code, err, "best.json"), err
    code, _, err = cli("simulate", toy_v2, "--duration", "1", "--plot", str(full(tmp_path / "flight.png")))
    assert one_line(code, err, "flight.png"), err
