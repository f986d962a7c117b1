"""A flight log's control periods and events as CSV files, streamed (any length of log, bounded memory)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from groundstation.output import writing
from groundstation.replay.reader import commands, open_log


def export_csv(path: str | Path, out_dir: str | Path, t_from: float | None = None,
               t_to: float | None = None) -> list[Path]:
    """``<stem>_control.csv`` (one row per control period: flight time, phase, position and setpoint in m,
    attitude and its target in deg, mocap age and loop start error in s, rotor commands as fractions of u_max) and
    ``<stem>_events.csv``; returns the paths. A write that fails (a full disk) is a
    :class:`~groundstation.errors.UsageError` naming the file."""
    log = open_log(path)
    out_dir = Path(out_dir)
    stem = Path(path).stem
    control_path, events_path = out_dir / f"{stem}_control.csv", out_dir / f"{stem}_events.csv"
    lo = -np.inf if t_from is None else t_from
    hi = np.inf if t_to is None else t_to
    offset = None
    events = []
    with writing(control_path), open(control_path, "w", newline="") as fc:
        w = csv.writer(fc)
        header_done = False
        for rec in log.records({"/control", "/log"}):
            if rec.topic == "/log":
                events.append((rec.log_time, *rec.data))
                continue
            d = rec.data
            offset = rec.log_time - d["t_s"] if offset is None else offset
            if "state" not in d or not lo <= d["t_s"] <= hi:
                continue
            motors = commands(d)
            if not header_done:
                w.writerow(["t_s", "phase", "x_m", "y_m", "z_m", "x_ref_m", "y_ref_m", "z_ref_m", "roll_deg",
                            "pitch_deg", "yaw_deg", "roll_target_deg", "pitch_target_deg", "yaw_target_deg",
                            "mocap_age_s", "start_error_s"]
                           + [f"m{i}_q{q + 1}_frac_umax" for i in range(motors.shape[0]) for q in range(4)])
                header_done = True
            flown = d.get("truth", d["state"])
            w.writerow([d["t_s"], d["phase"], *flown["position_m"], *d["setpoint"]["position_m"], *flown["rpy_deg"],
                        *d["attitude_target"]["rpy_deg"], d.get("mocap_age_s", ""),
                        (d.get("loop") or {}).get("start_error_s", ""), *motors.reshape(-1)])
    with writing(events_path), open(events_path, "w", newline="") as fe:
        w = csv.writer(fe)
        w.writerow(["t_s", "level", "text"])
        for lt, level, text in events:
            w.writerow([lt - (offset or 0.0), level, text])
    return [control_path, events_path]
