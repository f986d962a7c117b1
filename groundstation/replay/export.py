"""A flight log's control periods, mocap poses and events as CSV files, streamed (any length of log, bounded memory).

Times are flight time (s since the first control period, the clock of ``replay --from/--to``), so the rows of a
window are what ``replay`` analyses in it and its figures can be recomputed from them.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from groundstation.output import writing
from groundstation.replay.reader import commands, is_mocap_pose, open_log

CONTROL_COLUMNS = ["t_s", "phase", "x_m", "y_m", "z_m", "x_ref_m", "y_ref_m", "z_ref_m", "roll_deg", "pitch_deg",
                   "yaw_deg", "roll_target_deg", "pitch_target_deg", "yaw_target_deg", "mocap_age_s", "start_error_s",
                   "late"]
MOCAP_COLUMNS = ["t_s", "capture_t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]


class _Rows:
    """A CSV writer of one of several files written at once: a write that fails names its file (the error of a
    buffered flush names none, and would pass through the other files' :func:`writing` first)."""

    def __init__(self, fh, path: Path) -> None:
        self._w, self._path = csv.writer(fh), path

    def writerow(self, row) -> None:
        with writing(self._path):
            self._w.writerow(row)

    def writerows(self, rows) -> None:
        with writing(self._path):
            self._w.writerows(rows)


def _pose_row(t: float, capture_t: float, payload: bytes) -> list:
    """A raw pose's row: arrival and capture in flight time (s), then its ``foxglove.PoseInFrame`` payload's."""
    msg = PoseInFrame()
    msg.ParseFromString(payload)
    p, q = msg.pose.position, msg.pose.orientation
    return [t, capture_t, p.x, p.y, p.z, q.x, q.y, q.z, q.w]


def _control_row(columns: list, motors: np.ndarray, before: int | None, after: int | None) -> list:
    """A period's row: its ``late`` column from the loop's late count in its record (``before``) and in the next
    one (``after``), empty when the log has no count."""
    return columns + ["" if None in (before, after) else after - before, *motors]


def export_csv(path: str | Path, out_dir: str | Path, t_from: float | None = None,
               t_to: float | None = None) -> list[Path]:
    """Over flight time ``[t_from, t_to]`` (all if None): ``<stem>_control.csv``, one row per control period
    (flight time, phase, position and setpoint in m, attitude and its target in deg, mocap age and loop start
    error in s, ``late``: 1 if the period ran late (its step ended after the next one's deadline), then the rotor
    commands as fractions of u_max); ``<stem>_mocap.csv``, one row per raw mocap pose by its arrival (arrival and
    capture in flight time, the capture on the publisher's clock; position m; orientation quaternion x, y, z, w);
    ``<stem>_events.csv``. Returns the paths. A write that fails (a full disk) is a
    :class:`~groundstation.errors.UsageError` naming the file."""
    log = open_log(path)
    out_dir = Path(out_dir)
    stem = Path(path).stem
    paths = [out_dir / f"{stem}_{part}.csv" for part in ("control", "mocap", "events")]
    control_path, mocap_path, events_path = paths
    lo = -np.inf if t_from is None else t_from
    hi = np.inf if t_to is None else t_to
    offset = None
    events = []
    early_poses = []  # (arrival, capture, payload) of the poses before the first period, where flight time starts
    held = None  # (columns, rotor commands, the loop's late count) of the window's newest period: whether it ran
    # late shows in the next record's count (in the loop's summary for the flight's last)
    total = None  # the loop's own count at the end of the flight
    with writing(control_path), open(control_path, "w", newline="") as fc, \
            writing(mocap_path), open(mocap_path, "w", newline="") as fm:
        wc, wm = _Rows(fc, control_path), _Rows(fm, mocap_path)
        wm.writerow(MOCAP_COLUMNS)
        header_done = False
        for rec in log.records():
            d = rec.data
            if rec.topic == "/log":
                events.append((rec.log_time, *d))
            elif is_mocap_pose(rec.topic):
                if offset is None:
                    early_poses.append((rec.log_time, rec.publish_time, d))
                elif lo <= rec.log_time - offset <= hi:
                    wm.writerow(_pose_row(rec.log_time - offset, rec.publish_time - offset, d))
            elif rec.topic == "/loop/timing":
                total = d.get("overruns")
            elif rec.topic == "/control":
                if offset is None:
                    offset = rec.log_time - d["t_s"]
                    wm.writerows(_pose_row(lt - offset, pt - offset, p) for lt, pt, p in early_poses
                                 if lo <= lt - offset <= hi)
                if "state" not in d:
                    continue  # a motors-off record (the flight's last)
                count = (d.get("loop") or {}).get("overruns")
                if held is not None:
                    wc.writerow(_control_row(*held, count))
                    held = None
                if not lo <= d["t_s"] <= hi:
                    continue
                motors = commands(d).reshape(-1)
                if not header_done:
                    wc.writerow(CONTROL_COLUMNS + [f"m{i}_q{q + 1}_frac_umax" for i in range(motors.size // 4)
                                                   for q in range(4)])
                    header_done = True
                flown = d.get("truth", d["state"])
                held = ([d["t_s"], d["phase"], *flown["position_m"], *d["setpoint"]["position_m"], *flown["rpy_deg"],
                         *d["attitude_target"]["rpy_deg"], d.get("mocap_age_s", ""),
                         (d.get("loop") or {}).get("start_error_s", "")], motors, count)
        if held is not None:  # the flight's last period (a log cut short has no summary: taken as on time)
            wc.writerow(_control_row(*held, total if total is not None else held[2]))
        if not header_done:  # no period (a flight that never armed): the columns all the same
            wc.writerow(CONTROL_COLUMNS)
        if offset is None:  # never flew: flight time from its first event, as replay has it
            offset = events[0][0] if events else 0.0
            wm.writerows(_pose_row(lt - offset, pt - offset, p) for lt, pt, p in early_poses
                         if lo <= lt - offset <= hi)
    with writing(events_path), open(events_path, "w", newline="") as fe:
        w = csv.writer(fe)
        w.writerow(["t_s", "level", "text"])
        w.writerows([lt - offset, level, text] for lt, level, text in events if lo <= lt - offset <= hi)
    return paths
