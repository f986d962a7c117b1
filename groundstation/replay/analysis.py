"""What a flight log says about the flight: the figures the flight reported, and more, from the log alone.

:func:`analyse` streams a log once (:mod:`groundstation.replay.reader`) and feeds every control period to the
same :class:`~groundstation.runtime.metrics.FlightMetrics` the flight used, so tracking and attitude figures match
the flight's own; it adds what only the log has in one place: the flight-state timeline and every event, loop
timing, mocap counters, battery and link quality per module, motor saturation per module, and time series for
plots, decimated to a bounded number of points. Optionally it feeds the logged states and setpoints through the
controller and allocation of the current code (:class:`Rerun`) and says how far the commands differ.
"""

from __future__ import annotations

import json
import math
from array import array
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from groundstation.assembly.assembly_file import flown_assembly
from groundstation.control.allocation import allocate, allocate_bounded
from groundstation.control.geometric import Gains, control
from groundstation.control.model import ControlModel
from groundstation.control.phase import Phase
from groundstation.control.state import RigidState, Setpoint
from groundstation.errors import ConfigError
from groundstation.flightlog.mcap_log import being_written
from groundstation.replay.reader import commands, is_mocap_pose, open_log
from groundstation.rotations import quat_to_matrix
from groundstation.runtime.metrics import FlightFigures, FlightMetrics, figures_of
from groundstation.runtime.plots import Series

NO_END = ("the log has no end of flight: its flight process stopped before finishing it (killed, crashed, or its log "
          "writer failed first); the phase is the last one logged")
"""The reason of a log without the flight's summary: never an end in a phase with no reason."""
STILL_WRITTEN = ("the log has no end of flight yet: its writer is still writing it (the flight under way, or its "
                 "writer hung)")
"""...while a log writer process still holds the file (:func:`~groundstation.flightlog.mcap_log.being_written`)."""
COPIED_LIVE = ("the log has no end of flight: it is a `log recover` copy taken while its flight was still under way "
               "(the source holds the rest)")
"""...of a copy of a log its writer still held (:attr:`~groundstation.replay.reader.LogFile.copied_live`)."""
SERIES_POINTS = 20_000
"""Most points kept per time series (a 30-minute 500 Hz flight has 900,000 periods)."""
RATE_MIN_SPAN_S = 0.5
"""Shortest stretch of arrivals a mocap rate is measured over, s: poses are timed when a period polls them (one
period late at most), so over 0.5 s a 250 Hz loop's polling moves the rate by 1 % at most; shorter, it could not
say (:func:`arrival_rate`)."""
RATE_MIN_POSES = 3
"""Fewest poses a mocap rate is measured from."""


class Decimated:
    """Rows of a stream, at most ``cap``: when full, every other row goes and the stride doubles."""

    def __init__(self, cap: int = SERIES_POINTS) -> None:
        self.cap = cap
        self.stride = 1
        self._k = 0
        self.rows: list = []

    def add(self, row) -> None:
        if self._k % self.stride == 0:
            self.rows.append(row)
            if len(self.rows) > self.cap:
                self.rows = self.rows[::2]
                self.stride *= 2
        self._k += 1


def _per_module(modules: list[dict], key: str) -> np.ndarray:
    """A telemetry value of every module, (n,), NaN where a module's record leaves it out (not measured)."""
    return np.array([m.get(key, np.nan) for m in modules], float)


@dataclass(frozen=True)
class RerunFigures:
    """The logged commands against the current code's, over the periods replayed."""

    periods: int
    max_motor_diff: float
    """Largest |difference| of a rotor command, fraction of u_max."""
    rms_motor_diff: float
    """RMS over periods and rotors, fraction of u_max (NaN: no period)."""
    max_force_diff_n: float
    """Largest |difference| of a wrench force component, N."""
    max_torque_diff_nm: float
    """Largest |difference| of a wrench torque component, N m."""


@dataclass
class RerunStats:
    """Running sums behind :class:`RerunFigures`."""

    periods: int = 0
    max_motor_diff: float = 0.0
    sum_sq: float = 0.0
    max_force_diff_n: float = 0.0
    max_torque_diff_nm: float = 0.0

    def result(self) -> RerunFigures:
        return RerunFigures(self.periods, self.max_motor_diff,
                            math.sqrt(self.sum_sq / self.periods) if self.periods else math.nan,
                            self.max_force_diff_n, self.max_torque_diff_nm)


class Rerun:
    """The logged state and setpoint of each period through :func:`~groundstation.control.geometric.control` and
    the allocation of this code, with the log's assembly (as flown: its design is not judged again) and (unless
    given) its gains and allocation mode."""

    def __init__(self, assembly_record: dict, config: dict, gains: Gains | None = None,
                 allocation: str | None = None, src: str = "log") -> None:
        self.model = ControlModel.from_assembly(flown_assembly(assembly_record, src))
        self.gains = gains or Gains(**config["gains"])
        mode = allocation or config.get("allocation", "clip")
        self.alloc = allocate if mode == "clip" else allocate_bounded
        self.stats = RerunStats()

    def add(self, d: dict) -> None:
        st, sp = d["state"], d["setpoint"]
        state = RigidState(np.array(st["position_m"]), np.array(st["velocity_mps"]),
                           quat_to_matrix(np.array(st["orientation"])), np.array(st["omega_radps"]))
        setpoint = Setpoint(np.array(sp["position_m"]), np.array(sp["velocity_mps"]),
                            np.array(sp["acceleration_mps2"]), quat_to_matrix(np.array(sp["orientation"])),
                            np.array(sp.get("omega_radps", [0.0] * 3)))
        out = control(state, setpoint, self.model, self.gains)
        u = self.alloc(out.wrench, self.model) / self.model.u_max
        diff = np.abs(u - commands(d).reshape(-1))
        s = self.stats
        s.periods += 1
        s.max_motor_diff = max(s.max_motor_diff, float(diff.max()))
        s.sum_sq += float(diff @ diff) / diff.size
        w = d["wrench"]
        s.max_force_diff_n = max(s.max_force_diff_n, float(np.abs(out.wrench[:3] - w["force_n"]).max()))
        s.max_torque_diff_nm = max(s.max_torque_diff_nm, float(np.abs(out.wrench[3:] - w["torque_nm"]).max()))


@dataclass
class _Modules:
    """Per-module battery and link figures from the telemetry records."""

    battery_first: list = field(default_factory=list)
    battery_last: list = field(default_factory=list)
    battery_min: np.ndarray | None = None
    latency_max: np.ndarray | None = None
    latency_sum: np.ndarray | None = None
    latency_n: np.ndarray | None = None
    loss_max: np.ndarray | None = None

    def add(self, d: dict) -> None:
        modules = d.get("modules", [])
        if any("battery_v" in m for m in modules):
            b = _per_module(modules, "battery_v")
            self.battery_first = self.battery_first or b.tolist()
            self.battery_last = b.tolist()
            self.battery_min = b if self.battery_min is None else np.fmin(self.battery_min, b)
        if any("link_latency_s" in m for m in modules):
            lat = _per_module(modules, "link_latency_s")
            ok = np.isfinite(lat)
            if self.latency_max is None:
                self.latency_max, self.latency_sum = np.zeros(lat.size), np.zeros(lat.size)
                self.latency_n, self.loss_max = np.zeros(lat.size), np.full(lat.size, np.nan)  # NaN: not measured
            self.latency_max = np.where(ok, np.maximum(self.latency_max, np.where(ok, lat, 0)), self.latency_max)
            self.latency_sum += np.where(ok, lat, 0.0)
            self.latency_n += ok
            self.loss_max = np.fmax(self.loss_max, _per_module(modules, "link_loss_frac"))

    def result(self) -> dict:
        """The :class:`ReplayFigures` battery and link fields (empty tuples without telemetry)."""
        out = {"battery_v_first": tuple(self.battery_first), "battery_v_last": tuple(self.battery_last),
               "battery_v_min": () if self.battery_min is None else tuple(self.battery_min.tolist()),
               "link_latency_ms_mean": (), "link_latency_ms_max": (), "link_loss_max": ()}
        if self.latency_max is not None:
            mean = np.where(self.latency_n > 0, self.latency_sum / np.maximum(self.latency_n, 1), np.nan)
            out |= {"link_latency_ms_mean": tuple((mean * 1e3).tolist()),
                    "link_latency_ms_max": tuple((self.latency_max * 1e3).tolist()),
                    "link_loss_max": tuple(self.loss_max.tolist())}
        return out


@dataclass(frozen=True)
class ReplayFigures(FlightFigures):
    """The flight's own figures recomputed from its log, with what only the log has in one place. Per-module
    tuples are in module order; empty when the log has no telemetry. In a window (``--from``/``--to``) every
    figure covers the window alone (None: the log cannot say for a window), but the flight's end (``phase``,
    ``reason``)."""

    overruns: int | None
    """Periods that ran late (their step ended after the next one's deadline), from the loop's count in each
    period's record (None: a log whose records have no count, in a window; unwindowed, its loop summary's)."""
    loop_period_error_max_ms: float
    mocap_rate_hz: float
    """Poses per second among those that arrived from the first period to the last (every pose of the body's
    source, as logged when it arrived), by :func:`arrival_rate` (NaN: too few to say, or none logged)."""
    mocap_rejected: int | None
    """Poses the subscriber rejected (jumps, stale or out of order), from its counts in the periods' records: in a
    window, those of its periods (from the first period: less the counts as preflight passed, ``/flight/start``);
    unwindowed, since the stream began, preflight included, like the events (None: a window of a log whose
    records have no counts, or from the first period of a log without ``/flight/start``; unwindowed, a log
    whose records have no counts gives its last ``/mocap/stats`` count)."""
    mocap_malformed: int | None
    mocap_missed: int | None
    duration_s: float
    """Flight time from the first to the last period analysed, s."""
    tracked_s: float
    """Flight time from the first to the last tracking period analysed, s (0: none)."""
    phase: str
    """The state the flight ended in."""
    reason: str
    """Why it ended early ("" when it flew its plan)."""
    stalls: int
    """Loop stalls among the events."""
    battery_v_first: tuple[float, ...]
    battery_v_last: tuple[float, ...]
    battery_v_min: tuple[float, ...]
    link_latency_ms_mean: tuple[float, ...]
    """Mean command round trip per module, ms."""
    link_latency_ms_max: tuple[float, ...]
    link_loss_max: tuple[float, ...]
    """Largest lost share of commands per module."""
    estimator_rejected: int | None
    """Poses the estimator's innovation gates rejected, counted as ``mocap_rejected`` is (0 for logs before it
    counted them)."""
    estimator_late: int | None
    """Poses that reached the estimator too late to use (captured before the history it keeps), counted as
    ``mocap_rejected`` is (0 for logs before it counted them)."""
    position_sigma_max_m: float
    """Largest horizontal position std the estimator reported (blind flight shows here), m (NaN: not logged)."""
    height_sigma_max_m: float
    """...and height std, m (NaN: not logged, as in logs before 2026-12-03)."""
    innovation_position_p95_mm: float
    """95th percentile of the newest pose's position innovation, over the periods, mm (NaN: not logged)."""
    innovation_attitude_p95_deg: float
    """...and of its attitude innovation, deg."""


@dataclass
class _Counts:
    """Running counts that every period's record holds (since the stream began, that period's included), over a
    window: their values at its last period less those just before its first: the record before it, or for a
    window from the first period the counts as preflight passed (``/flight/start``; the first record's include
    the preflight's, and how many are its period's own no record says)."""

    before: dict | None = None
    """The counts just before the window (None: not logged)."""
    last: dict | None = None
    """...at its last period (None: no record in it had them)."""

    def add(self, counts: dict, inside: bool) -> None:
        """A period's counts, or (not ``inside``, before any period) those as preflight passed."""
        if inside:
            self.last = counts
        elif self.last is None:  # a record before the window
            self.before = counts

    def result(self, windowed: bool) -> dict | None:
        """The counts over the window, each None where its start is not logged; unwindowed, since the stream
        began (None: no record in the window had them)."""
        if self.last is None or not windowed:
            return self.last
        return {k: None if self.before is None else v - self.before.get(k, 0) for k, v in self.last.items()}


@dataclass
class _Overruns:
    """Late periods of a window from the loop's running count. A period's record holds the count before the
    period ran, so whether the window's last period ran late shows in the next record, or (the flight's last)
    in the loop's summary."""

    first: int | None = None
    """The count at the window's first period."""
    last: int | None = None
    """...at its last."""
    after: int | None = None
    """...at the first period after it."""

    def add(self, count: int, inside: bool) -> None:
        if inside:
            self.first = count if self.first is None else self.first
            self.last = count
        elif self.last is not None and self.after is None:
            self.after = count

    def result(self, total: int | None, windowed: bool) -> int | None:
        """``total``: the loop's own count at the end of the flight (None: not logged)."""
        if self.first is None:  # no record had a count: only the summary's, of the whole flight
            return None if windowed else total or 0
        return (self.after if self.after is not None else total if total is not None else self.last) - self.first


@dataclass
class _Estimates:
    """The estimator's figures from the control records."""

    counts: _Counts = field(default_factory=_Counts)
    sigma_max: float = -math.inf
    height_sigma_max: float = -math.inf
    position: Decimated = field(default_factory=Decimated)
    attitude: Decimated = field(default_factory=Decimated)

    def add(self, e: dict, inside: bool) -> None:
        self.counts.add({"rejected": e["rejected"], "late": e.get("late", 0)}, inside)
        if inside:
            self.sigma_max = max(self.sigma_max, e["position_sigma_m"])
            self.height_sigma_max = max(self.height_sigma_max, e.get("height_sigma_m", -math.inf))
            self.position.add(math.hypot(*e["innovation_position_m"]) * 1e3)
            self.attitude.add(math.hypot(*e["innovation_attitude_deg"]))

    def result(self, windowed: bool) -> dict:
        p95 = lambda d: float(np.percentile(d.rows, 95)) if d.rows else math.nan  # noqa: E731
        counts = self.counts.result(windowed) or {}
        return {"estimator_rejected": counts.get("rejected", 0), "estimator_late": counts.get("late", 0),
                "position_sigma_max_m": self.sigma_max if self.sigma_max > -math.inf else math.nan,
                "height_sigma_max_m": self.height_sigma_max if self.height_sigma_max > -math.inf else math.nan,
                "innovation_position_p95_mm": p95(self.position), "innovation_attitude_p95_deg": p95(self.attitude)}


@dataclass(frozen=True, eq=False)
class Replay:
    """One flight log, analysed."""

    path: Path
    complete: bool
    """The whole flight: the file ended cleanly with nothing damaged and the flight's end in it (False: cut short by
    a crash, damaged, a recovered copy of such a file, or finished by a writer that outlived its flight process;
    everything intact was read)."""
    warnings: tuple[str, ...]
    """What reading skipped: one line per damaged stretch and a line of totals (empty for an intact log); then what
    could not be done for want of metadata (a re-run without the log's gains or assembly)."""
    metadata: dict
    """``config`` (the flight config, a dict; empty when its record was skipped as damaged), ``config_path``,
    ``code_version``, ``assembly`` (the assembly record, None in a log before it was metadata or when its record
    was skipped as damaged) and ``started_s`` (when flight time 0 was, s since the epoch)."""
    metrics: ReplayFigures
    events: list
    """(flight time s, level, text), every event the flight logged in the window."""
    timeline: list
    """(flight time s, phase): the phase at the window's first period, then at every change of phase in it."""
    series: Series
    """Decimated to at most :data:`SERIES_POINTS` rows, for plots."""
    rerun: RerunFigures | None


def _metadata_json(metadata: dict, src: str, key: str) -> dict | None:
    """The log's ``key`` metadata, parsed (None when the log has none). The reader skips, as damage, a ``config``
    or ``assembly`` record that is not a JSON object (:mod:`groundstation.flightlog.salvage`); one that got past
    it is a ConfigError naming file and key."""
    if not metadata.get(key):
        return None
    try:
        value = json.loads(metadata[key])
    except (ValueError, RecursionError):
        raise ConfigError(f"the log's {key} metadata is not JSON", path=src, key=key) from None
    if not isinstance(value, dict):
        raise ConfigError(f"the log's {key} metadata is not a JSON object", path=src, key=key)
    return value


NO_CONFIG = "the log has no intact config metadata (its record skipped as damaged, or never written)"
"""Why a log's flight config is unknown."""


def log_config(metadata: dict, src: str) -> dict:
    """The flight config the log was flown with (its ``config`` metadata); a ConfigError when the log has none
    (what it holds, a latency, a gain, would otherwise be taken for 0 or a default without a word)."""
    config = _metadata_json(metadata, src, "config")
    if config is None:
        raise ConfigError(NO_CONFIG, path=src, key="config")
    return config


def _assembly(metadata: dict, src: str) -> dict | None:
    """The log's assembly record (None: a log written before the assembly was metadata, or its record skipped as
    damaged)."""
    return _metadata_json(metadata, src, "assembly")


def _rerun(metadata: dict, src: str, gains: Gains | None, allocation: str | None) -> tuple[Rerun | None, str]:
    """The re-run of the log's periods, or why there is none: it needs the log's assembly record, and unless
    ``gains`` are given its config's gains and allocation (what ``--rerun-with`` gives instead). A malformed
    assembly record is refused naming its key (:class:`Rerun`)."""
    record = _assembly(metadata, src)
    if record is None:
        return None, ("not re-run: the log has no intact assembly metadata (its record skipped as damaged, or a log "
                      "written before it was metadata): the modules' geometry is unknown")
    config = _metadata_json(metadata, src, "config")
    if gains is None:
        rerun_with = "; --rerun-with FLIGHT.toml gives them"
        if config is None:
            return None, f"not re-run: {NO_CONFIG}: the gains and allocation it flew with are unknown{rerun_with}"
        try:
            gains = Gains(**config["gains"])
        except (KeyError, TypeError, ValueError):
            return None, f"not re-run: the log's config metadata has no usable gains{rerun_with}"
    return Rerun(record, config or {}, gains, allocation, src), ""


def _skipped(log, malformed: dict[str, int]) -> str:
    """What reading skipped, for the error of a log left with nothing to analyse: its damage (how many chunks and
    messages) and its records that are not what their topic holds; empty if nothing was."""
    said = ([log.skipped] if log.skipped else []) + [f"{n} message(s) on {topic} not what the topic holds"
                                                     for topic, n in malformed.items()]
    return f" (the log is damaged: {'; '.join(said)})" if said else ""


MOCAP_COUNTS = ("rejected", "malformed", "missed")
"""The subscriber's counters replay reports."""


def arrival_rate(arrived: np.ndarray) -> float:
    """Poses per second from their arrival times (s, ascending): the intervals between the first and the last over
    the time they span, (N - 1) / (last - first). Counting the poses of a closed interval over its length instead
    is 1 / (span x rate) high (two periods of a 250 Hz loop read a 100 Hz stream as 250 Hz). NaN, too few to say:
    under :data:`RATE_MIN_POSES` poses or spanning under :data:`RATE_MIN_SPAN_S`. A pause in the stream inside
    the span lowers the rate; at its ends, the mocap age shows it."""
    if len(arrived) < RATE_MIN_POSES or arrived[-1] - arrived[0] < RATE_MIN_SPAN_S:
        return math.nan
    return (len(arrived) - 1) / (arrived[-1] - arrived[0])


def analyse(path: str | Path, t_from: float | None = None, t_to: float | None = None, rerun: bool = False,
            gains: Gains | None = None, allocation: str | None = None, progress=None) -> Replay:
    """Stream the flight log at ``path`` once; figures over flight time ``[t_from, t_to]`` (all if None) from
    every intact record (damage is skipped and named in :attr:`Replay.warnings`): the periods, events, telemetry
    and poses in it. A log that never flew (refused before arming) replays its events and its end.
    ``progress(fraction)`` is told how much of the file has been read."""
    log = open_log(path)
    src = str(path)
    metrics: FlightMetrics | None = None
    series = Decimated()
    modules = _Modules()
    estimates = _Estimates()
    mocap_counts = _Counts()
    late = _Overruns()
    events_raw: list[tuple[float, str, str]] = []
    timeline: list[tuple[float, str]] = []
    poses = array("d")  # log time of every raw mocap pose, s
    mocap: dict = {}
    loop_summary: dict = {}
    summary: dict = {}
    offset = None
    t_end = None  # flight time of the log's last control record, s
    last_phase = ""
    flew = False
    track_first = track_last = None
    max_start_error = 0.0
    malformed: dict[str, int] = {}
    rr: Rerun | None = None
    not_rerun = ""
    lo = -math.inf if t_from is None else t_from
    hi = math.inf if t_to is None else t_to
    windowed = lo > -math.inf or hi < math.inf
    for rec in log.records(progress=progress):
        try:
            d = rec.data
            if rec.topic == "/control":
                t = d["t_s"]
                offset = rec.log_time - t if offset is None else offset
                t_end, last_phase = t, d["phase"]
                inside = lo <= t <= hi
                if inside and (not timeline or timeline[-1][1] != d["phase"]):
                    timeline.append((t, d["phase"]))
                if "state" not in d:
                    continue  # a motors-off record (the flight's last)
                flew = True
                loop = d.get("loop") or {}
                if loop:
                    late.add(loop["overruns"], inside)
                if "estimate" in d:
                    estimates.add(d["estimate"], inside)
                if "mocap" in d:
                    mocap_counts.add(d["mocap"], inside)
                if not inside:
                    continue
                if metrics is None:
                    metrics = FlightMetrics(len(d["modules"]))
                    if rerun:
                        rr, not_rerun = _rerun(log.metadata, src, gains, allocation)
                if d["phase"] == Phase.TRACK:
                    track_first = t if track_first is None else track_first
                    track_last = t
                flown = d.get("truth", d["state"])
                rotation = quat_to_matrix(np.array(flown["orientation"]))
                target = quat_to_matrix(np.array(d["attitude_target"]["orientation"]))
                motors = commands(d)
                metrics.add(t, d["phase"], flown["position_m"], d["setpoint"]["position_m"], rotation, target,
                            math.radians(d["roll_target_deg"]), math.radians(d["yaw_target_deg"]), motors,
                            d.get("mocap_age_s"))
                if loop:
                    metrics.add_timing(loop["start_error_s"], loop["compute_s"])
                    max_start_error = max(max_start_error, abs(loop["start_error_s"]))
                series.add((t, flown["position_m"], d["setpoint"]["position_m"], rotation,
                            d["attitude_target"]["rpy_deg"], motors, d["phase"]))
                if rr is not None:
                    rr.add(d)
            elif rec.topic == "/log":
                events_raw.append((rec.log_time, *d))
            elif is_mocap_pose(rec.topic):
                poses.append(rec.log_time)
            elif rec.topic == "/backend/telemetry":
                if lo <= d["t_s"] <= hi:
                    modules.add(d)
            elif rec.topic == "/mocap/stats":
                mocap = d
            elif rec.topic == "/flight/start":  # before the first period: where a window from it starts counting
                mocap_counts.add(d["mocap"], inside=False)
                estimates.counts.add(d["estimate"], inside=False)
            elif rec.topic == "/loop/timing":
                loop_summary = d
            elif rec.topic == "/flight/summary":
                summary = d
        except (KeyError, TypeError, ValueError, IndexError, AttributeError):
            # Intact bytes (the CRC holds) and JSON, but not the record this topic holds (a log edited or
            # written by another program): skipped and counted, like a record that is not JSON.
            malformed[rec.topic] = malformed.get(rec.topic, 0) + 1
    if metrics is None and flew:
        raise ConfigError("the log has no control period to analyse in the window" + _skipped(log, malformed),
                          path=src)
    if metrics is None and not (summary or events_raw):
        raise ConfigError("the log has no control period to analyse" + _skipped(log, malformed), path=src)
    if metrics is None:  # never flew (preflight refused, stopped before arming): its events and its end
        metrics = FlightMetrics(0)
        offset = events_raw[0][0] if events_raw else None
    offset = offset or 0.0
    events = [(lt - offset, level, text) for lt, level, text in events_raw if lo <= lt - offset <= hi]
    end, t_end = summary.get("phase"), t_end or 0.0
    if end and lo <= t_end <= hi and (not timeline or timeline[-1][1] != end):
        timeline.append((t_end, end))  # the end state is only in the summary and the events
    duration = (metrics.t_last - metrics.t_first) if metrics.periods > 1 else 0.0
    arrived = np.frombuffer(poses) - offset
    counts = mocap_counts.result(windowed)
    if counts is None and mocap and not windowed:  # a log before the periods' counts: the stream's, since it began
        counts = {k: mocap.get(k, 0) for k in MOCAP_COUNTS}
    m = ReplayFigures(
        **figures_of(metrics.result()),
        overruns=late.result(loop_summary.get("overruns"), windowed),
        loop_period_error_max_ms=max_start_error * 1e3,
        mocap_rate_hz=arrival_rate(arrived[(arrived >= metrics.t_first) & (arrived <= metrics.t_last)]),
        **{f"mocap_{k}": None if counts is None else counts[k] for k in MOCAP_COUNTS},
        duration_s=duration, tracked_s=track_last - track_first if track_first is not None else 0.0,
        phase=summary.get("phase", last_phase),
        reason=summary.get("reason", "") if summary else STILL_WRITTEN if being_written(src) else
        COPIED_LIVE if log.copied_live else NO_END,
        stalls=sum("loop stalled" in text for _, _, text in events), **modules.result(), **estimates.result(windowed))
    rows = series.rows
    s = Series(np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
               np.array([r[3] for r in rows]).reshape(-1, 3, 3), np.array([r[4] for r in rows]),
               np.array([r[5] for r in rows]), np.array([r[6] for r in rows]))
    meta = {"config": _metadata_json(log.metadata, src, "config") or {},
            "code_version": log.metadata.get("code_version", ""),
            "config_path": log.metadata.get("config_path", ""), "assembly": _assembly(log.metadata, src),
            "started_s": offset}
    warnings = log.warnings + tuple(f"{n} message(s) on {topic} are not what the topic holds: skipped"
                                    for topic, n in malformed.items()) + ((not_rerun,) if not_rerun else ())
    # Complete: the file whole and the flight's end in it. A writer left running after its flight process was killed
    # finalizes a whole file with no end in it, which read "complete: true" beside "no end of flight" (campaign 26).
    return Replay(Path(path), log.complete and not malformed and bool(summary), warnings, meta, m, events, timeline, s,
                  rr.stats.result() if rr else None)
