"""Replay of a long flight log in bounded memory: peak RSS and time of ``groundstation replay`` on a synthetic
30-minute 500 Hz log, against loading the log's control records whole.

    python -m benchmarks.replay [--minutes 30] [--rate 500]

The synthetic log is made from a real short dry run's log (same channels, schemas and records), its control
periods repeated with fresh times up to the length asked, plus the pose, transform and mocap traffic of a real
flight, written with the ``mcap`` writer directly. Both readers run as their own processes; peak RSS is the
kernel's (``wait4``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from benchmarks._util import print_table
from groundstation.runtime.fly import fly

ROOT = Path(__file__).resolve().parents[1]
NAIVE = """
import json, sys
from mcap.reader import make_reader
with open(sys.argv[1], "rb") as fh:
    records = [json.loads(m.data) for _, _, m in make_reader(fh).iter_messages(["/control"])]
print(len(records))
"""


def _template(tmp: Path) -> Path:
    cfg = (ROOT / "configs/flights/toy_figure8_sim.toml").read_text()
    cfg = cfg.replace('assembly = "../assemblies/toy_v2.json"', f'assembly = "{ROOT}/configs/assemblies/toy_v2.json"')
    cfg = cfg.replace("tcp/127.0.0.1:7448", "tcp/127.0.0.1:7496")
    path = tmp / "template.toml"
    path.write_text(cfg)
    log = tmp / "template.mcap"
    fly(path, duration=4.0, log_path=log)
    return log


def _synthesize(template: Path, out: Path, minutes: float, rate: float) -> int:
    """A log of ``minutes`` at ``rate`` from the template's records; returns the control periods written."""
    with open(template, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        meta = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    per_topic: dict[str, list] = {}
    with open(template, "rb") as fh:
        for _, ch, m in make_reader(fh).iter_messages():
            per_topic.setdefault(ch.topic, []).append(m.data)
    control = [json.loads(d) for d in per_topic["/control"] if b'"state"' in d]
    periods = int(minutes * 60 * rate)
    t0 = time.time()
    with open(out, "wb") as fh:
        w = Writer(fh, chunk_size=32 * 1024, compression=CompressionType.ZSTD)
        w.start(profile="", library="groundstation")
        for name, data in meta:
            w.add_metadata(name, data)
        schema_ids = {sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        chans = {c.topic: w.register_channel(c.topic, c.message_encoding, schema_ids[c.schema_id])
                 for c in summary.channels.values()}
        for k in range(periods):
            t = k / rate
            ns = int((t0 + t) * 1e9)
            rec = dict(control[k % len(control)], t_s=t)
            w.add_message(chans["/control"], ns, json.dumps(rec).encode(), ns)
            w.add_message(chans["/state/pose"], ns, per_topic["/state/pose"][k % 100], ns)
            w.add_message(chans["/tf"], ns, per_topic["/tf"][k % 100 + 2], ns)
            if k % 5 == 0:  # 100 Hz mocap
                w.add_message(chans["/mocap/assembly"], ns, per_topic["/mocap/assembly"][k % 100], ns)
            if k % 50 == 0:
                w.add_message(chans["/backend/telemetry"], ns, per_topic["/backend/telemetry"][0], ns)
        w.finish()
    return periods


def _measure(cmd: list[str]) -> tuple[float, float]:
    """(wall s, peak RSS MiB) of a command in its own process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
    _, status, usage = os.wait4(proc.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{cmd} failed")
    return time.perf_counter() - t0, usage.ru_maxrss / 1024


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--rate", type=float, default=500.0)
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        template = _template(tmp)
        short = tmp / "short.mcap"
        long = tmp / "long.mcap"
        for path, minutes in ((short, args.minutes / 30), (long, args.minutes)):
            t0 = time.perf_counter()
            periods = _synthesize(template, path, minutes, args.rate)
            made = time.perf_counter() - t0
            replay_s, replay_mb = _measure([sys.executable, "-m", "groundstation", "replay", str(path), "--json"])
            naive_s, naive_mb = _measure([sys.executable, "-c", NAIVE, str(path)])
            rows.append([f"{minutes:g} min", periods, f"{path.stat().st_size / 2**20:.0f}", f"{made:.0f}",
                         f"{replay_s:.1f}", f"{replay_mb:.0f}", f"{naive_s:.1f}", f"{naive_mb:.0f}"])
    print_table(f"Replay of synthetic {args.rate:g} Hz flight logs (streamed vs loading the control records)",
                ["log", "periods", "file MiB", "made in s", "replay s", "replay peak MiB", "load-all s",
                 "load-all peak MiB"], rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
