"""The flight figure of replayed logs (:mod:`groundstation.runtime.plots`: the paper's Fig. 9, one column per log)
from what each log holds: its series, its assembly and its metadata."""

from __future__ import annotations

from pathlib import Path

from groundstation.assembly.assembly_file import assembly_from_record
from groundstation.control.geometric import free_angles
from groundstation.control.model import ControlModel
from groundstation.replay.analysis import Replay
from groundstation.runtime.plots import FlightTrace, assembly_fact, date_fact, save_flight_figure


def trace_of(r: Replay) -> FlightTrace:
    """The figure's view of a replayed log: the attitude angles its assembly does not track from the assembly it
    logged (a log without one: every angle drawn with its target)."""
    meta = r.metadata
    cfg, record = meta["config"], meta["assembly"]
    free = free_angles(ControlModel.from_assembly(assembly_from_record(record, str(r.path)))) if record else ()
    traj = cfg.get("trajectory", {})
    label = traj.get("kind", "flight") + (f", roll target {traj['roll_deg']:g} deg" if "roll_deg" in traj else "")
    name = Path(cfg.get("assembly", "assembly")).stem
    facts = (assembly_fact(name, r.series.motors.shape[1], record.get("controllable_dof") if record else None),
             ("config", Path(meta["config_path"]).name or "config not logged"), date_fact(meta["started_s"]),
             ("code", f"code {meta['code_version'] or 'version not logged'}"), ("log", r.path.name))
    return FlightTrace(label, facts, r.series, free)


def plot_replays(replays: list[Replay], path: str | Path) -> Path:
    """The flight figure of ``replays`` (each flew: it has control periods), one column each, into ``path``."""
    return save_flight_figure([trace_of(r) for r in replays], path)
