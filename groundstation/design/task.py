"""Task wrench sets (paper §II-B, §IV-C): what an assembly must be able to generate.

A task file (``configs/tasks/*.toml``)::

    name = "toy push along y (paper §VI-B)"
    units = "N"              # or "nmg": forces in units of n m g, torques in units of n m g l_c
    add_gravity = true       # selection adds n m g to every f_z ...
    add_hover = true         # ... and the hover wrench [0, 0, n m g, 0, 0, 0], as the paper does

    [[wrench]]
    force = [0.0, 0.36, 0.0]   # body frame
    torque = [0.0, 0.0, 0.0]
    weight = 1.0               # lambda_k, optional (default 1)

``Task.wrenches_for(n, params)`` gives the modified set the optimizer solves for ``n`` modules.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import ConfigDict, Field
from pydantic.dataclasses import dataclass

from groundstation import config
from groundstation.assembly.module import GRAVITY, ModuleParams

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


MAX_COMPONENT = 1e6
"""Largest wrench component, N or N m (or in n m g units): a module lifts well under 10 N; a 1e308 force overflowed
the verification ("needs inf N", numpy warnings: hostile campaigns 30, 32)."""
MAX_WEIGHT = 1e6
"""Largest ``lambda_k`` (the hover wrench's is 1): a weight of 1e308 made the cost inf and ``optimize`` called the
design feasible, writing a file its own loader refused (hostile campaign 32)."""
_Component = Annotated[float, Field(ge=-MAX_COMPONENT, le=MAX_COMPONENT)]


@dataclass(frozen=True, config=_STRICT)
class TaskWrench:
    force: tuple[_Component, _Component, _Component]
    """Force, body frame; N, or units of n m g when the task's ``units`` is ``nmg``."""
    torque: tuple[_Component, _Component, _Component] = (0.0, 0.0, 0.0)
    """Torque about the centroid, body frame; N m, or units of n m g l_c."""
    weight: float = Field(1.0, ge=0, le=MAX_WEIGHT)
    """``lambda_k``: weight of this wrench's input effort in the cost."""


@dataclass(frozen=True, config=_STRICT)
class Task:
    """A set of target wrenches and how to adapt it to an assembly of ``n`` modules."""

    wrench: tuple[TaskWrench, ...] = Field(min_length=1)
    name: str = ""
    units: Literal["N", "nmg"] = "N"
    add_gravity: bool = True
    """Add ``n m g`` to every ``f_z`` (paper §IV-C)."""
    add_hover: bool = True
    """Append the hover wrench ``[0, 0, n m g, 0, 0, 0]`` with weight 1 (paper §IV-C)."""

    def wrenches_for(self, n: int, params: ModuleParams) -> tuple[np.ndarray, np.ndarray]:
        """The modified wrench set ``(K, 6)`` in N and N m, and the weights ``(K,)``, for ``n`` modules."""
        nmg = n * params.mass * GRAVITY
        f_scale, t_scale = (nmg, nmg * params.l_c) if self.units == "nmg" else (1.0, 1.0)
        rows = [np.concatenate([np.multiply(w.force, f_scale), np.multiply(w.torque, t_scale)]) for w in self.wrench]
        weights = [w.weight for w in self.wrench]
        b = np.array(rows, dtype=float)
        if self.add_gravity:
            b[:, 2] += nmg
        if self.add_hover:
            b = np.vstack([b, [0.0, 0.0, nmg, 0.0, 0.0, 0.0]])
            weights.append(1.0)
        return b, np.array(weights, dtype=float)


def load_task(path: str | Path) -> Task:
    """Load a task file; errors name the file and the key (e.g. ``wrench.1.force``)."""
    task = config.load(Task, path)
    return task if task.name else dataclasses.replace(task, name=Path(path).stem)


def random_task(seed: int, count: int = 10) -> Task:
    """The paper's §IV-C timing set: ``count`` wrenches with f_x, f_y in [-0.2, 0.2] n m g, f_z in [0.9, 1.1] n m g,
    torques in [-0.1, 0.1] l_c n m g; no gravity or hover modification."""
    rng = np.random.default_rng(seed)
    wrenches = []
    for _ in range(count):
        f = rng.uniform([-0.2, -0.2, 0.9], [0.2, 0.2, 1.1])
        t = rng.uniform(-0.1, 0.1, size=3)
        wrenches.append(TaskWrench(force=tuple(np.round(f, 6)), torque=tuple(np.round(t, 6))))
    return Task(wrench=tuple(wrenches), name=f"random-{count}-seed{seed}", units="nmg",
                add_gravity=False, add_hover=False)


def task_to_toml(task: Task) -> str:
    """Serialise a task as a TOML task file."""
    lines = [f'name = "{task.name}"', f'units = "{task.units}"',
             f"add_gravity = {str(task.add_gravity).lower()}", f"add_hover = {str(task.add_hover).lower()}"]
    for w in task.wrench:
        lines += ["", "[[wrench]]", f"force = [{', '.join(repr(float(v)) for v in w.force)}]",
                  f"torque = [{', '.join(repr(float(v)) for v in w.torque)}]", f"weight = {float(w.weight)!r}"]
    return "\n".join(lines) + "\n"

