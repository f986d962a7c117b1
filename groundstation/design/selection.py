"""Selection across configurations (paper §IV-C, Algorithm 2).

For n = 1, 2, ... solve every candidate topology of n modules (exhaustive, sampled, or from a candidates file);
stop at the first n with a feasible design and pick the least cost; the runner-up and its gap are reported with
it. Candidates run in parallel, in a local process pool or on a Dask distributed scheduler. Every finished
candidate is appended to a JSON-lines results file at once, so an interrupted sweep (Ctrl-C, a kill) resumes
without redoing finished candidates.
"""

from __future__ import annotations

import hashlib
import json
import signal
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.assembly_file import assembly_from_record
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.design.enumeration import SamplingPolicy, enumerate_levels
from groundstation.design.optimize import SolverOptions, Verification, optimize
from groundstation.design.task import Task
from groundstation.errors import ConfigError
from groundstation.output import writing


@dataclass(frozen=True)
class CandidateResult:
    """One row of the results table."""

    n: int
    code: str
    status: str
    feasible: bool
    cost: float
    iterations: int
    wall_s: float
    min_clearance_m: float
    max_wrench_residual: float
    """Of the chosen start: the least any start reached when infeasible, N or N m."""
    key: str
    """Fingerprint of (task, module parameters, solver options, topology): what resuming matches on."""
    starts: int = 0
    feasible_starts: int = 0
    optima: int = 0
    """Distinct local optima the starts reached."""
    best_hits: int = 0
    """Starts that reached the best cost."""
    spread: float | None = None
    """Relative gap from the best to the second-best local optimum of this topology."""
    stop_reason: str = ""
    certificate: str = ""
    """Proof of infeasibility, when there is one."""


@dataclass(frozen=True, eq=False)
class SelectedDesign:
    """The design a sweep chose, read back from the assembly-file record it will be saved as (so what is used is
    what a later ``fly`` or ``simulate`` loads)."""

    row: CandidateResult
    assembly: Assembly
    wrenches: np.ndarray
    """(k, 6) task wrenches it was solved for: force (N) then torque (N m), body frame."""
    verification: Verification
    record: dict
    """The assembly-file record (geometry plus the design's inputs, solver statistics and checks)."""

    @classmethod
    def of(cls, row: CandidateResult, record: dict, src: str) -> SelectedDesign:
        """From a candidate's row and record; a malformed record (a hand-edited results file ``src``) is a
        ConfigError naming it."""
        assembly = assembly_from_record(record, src)
        try:
            wrenches = np.array(record["wrenches"], float).reshape(-1, 6)
            verification = Verification(**record["verification"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"the record of {row.code} is not a design record: {exc}", path=src) from None
        return cls(row, assembly, wrenches, verification, record)


@dataclass(frozen=True, eq=False)
class Selection:
    """Outcome of a sweep: the best design (if any), the n it was found at, and every candidate's row."""

    best: SelectedDesign | None
    """The least-cost feasible design at the first feasible n, or None."""
    n: int | None
    results: tuple[CandidateResult, ...]

    @property
    def ranking(self) -> list[CandidateResult]:
        """Feasible candidates of the chosen n, least cost first (ties broken by code)."""
        return sorted((r for r in self.results if r.n == self.n and r.feasible), key=lambda r: (r.cost, r.code))

    @property
    def runner_up(self) -> CandidateResult | None:
        """The second-best feasible candidate of the chosen n."""
        ranked = self.ranking
        return ranked[1] if len(ranked) > 1 else None


def fingerprint(task: Task, params: ModuleParams, opts: SolverOptions, code: str) -> str:
    blob = json.dumps([asdict(task), asdict(params), asdict(opts), code], sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def solve_candidate(code: str, task: Task, params: ModuleParams, opts: SolverOptions) -> tuple[CandidateResult, dict]:
    """Solve one topology (runs in a worker process); returns its row and its assembly record."""
    topo = Topology.from_code(code)
    wrenches, weights = task.wrenches_for(topo.n, params)
    d = optimize(topo, params, wrenches, weights, opts)
    row = CandidateResult(topo.n, code, d.status, d.feasible, d.cost, d.iterations, d.wall_s,
                          d.verification.min_capsule_distance, d.verification.max_wrench_residual,
                          fingerprint(task, params, opts, code), starts=len(d.starts),
                          feasible_starts=sum(s.feasible for s in d.starts), optima=len(d.optima),
                          best_hits=d.best_hits, spread=d.spread, stop_reason=d.stop_reason,
                          certificate=d.certificate.reason if d.certificate else "")
    return row, d.record(task.name)


def candidate_codes(n: int, sampling: SamplingPolicy | None, symmetry: str = "C4") -> list[str]:
    """Topology codes of level ``n``: exhaustive, or thinned by Algorithm 1."""
    *_, level = enumerate_levels(n, symmetry, sampling)
    return [t.code for t in level.topologies()]


def read_results(path: Path) -> dict[str, tuple[CandidateResult, dict | None]]:
    """Finished candidates of an earlier run, by fingerprint. A torn last line (killed mid-write) is skipped."""
    done: dict[str, tuple[CandidateResult, dict | None]] = {}
    if not path.exists():
        return done
    lines = path.read_text().splitlines()
    for lineno, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
            row = CandidateResult(**entry["row"])
        except (ValueError, TypeError, KeyError) as exc:
            if lineno == len(lines):
                continue
            raise ConfigError(f"line {lineno} is not a result row: {exc}", path=str(path)) from None
        done[row.key] = (row, entry.get("record"))
    return done


def _truncate_torn_tail(path: Path) -> None:
    """Cut a partial last line (left by a kill mid-write) so that appended rows start on a line of their own."""
    if not path.exists():
        return
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        with path.open("r+b") as fh:
            fh.truncate(data.rfind(b"\n") + 1)


def _ignore_sigint() -> None:
    """Pool worker initializer: Ctrl-C is the parent's to handle (it terminates the pool)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _Runner:
    """Submits candidates to a local process pool or a Dask scheduler and yields results as they finish.

    On Ctrl-C (``KeyboardInterrupt`` in the parent) the local pool is terminated at once: the candidates in flight
    are lost and solved again on resume, the finished ones are already in the results file."""

    def __init__(self, workers: int, scheduler: str | None) -> None:
        self.workers, self.scheduler = workers, scheduler
        self._pool = None
        self._client = None

    def __enter__(self) -> _Runner:
        if self.scheduler:
            from distributed import Client

            self._client = Client(self.scheduler, timeout="20s")
        elif self.workers > 1:
            # spawn, not fork: CasADi and the numba runtime hold threads and state a fork would copy half-done.
            self._pool = get_context("spawn").Pool(self.workers, initializer=_ignore_sigint)
        return self

    def __exit__(self, exc_type, *_exc) -> None:
        if self._pool is not None:
            if exc_type is None:
                self._pool.close()
            else:
                self._pool.terminate()
            self._pool.join()
        if self._client is not None:
            self._client.close()

    def map(self, codes: list[str], task: Task, params: ModuleParams, opts: SolverOptions) -> Iterable:
        if self._client is not None:
            from distributed import as_completed as dask_completed

            futures = [self._client.submit(solve_candidate, c, task, params, opts, pure=False) for c in codes]
            for fut in dask_completed(futures):
                yield fut.result()
        elif self._pool is not None:
            yield from self._pool.imap_unordered(_solve_args, [(c, task, params, opts) for c in codes])
        else:
            for c in codes:
                yield solve_candidate(c, task, params, opts)


def _solve_args(args: tuple) -> tuple[CandidateResult, dict]:
    return solve_candidate(*args)


def select(task: Task, params: ModuleParams, max_modules: int, *, sampling: SamplingPolicy | None = None,
           candidates: dict[int, list[str]] | None = None, opts: SolverOptions | None = None, workers: int = 1,
           scheduler: str | None = None, results_path: str | Path | None = None,
           on_level: Callable[[int, int], None] | None = None,
           on_result: Callable[[CandidateResult], None] | None = None, min_modules: int = 1) -> Selection:
    """Algorithm 2 from ``min_modules`` on. ``candidates`` (codes per n) overrides enumeration; ``results_path``
    makes it resumable."""
    opts = opts or SolverOptions()
    path = Path(results_path) if results_path else None
    done = read_results(path) if path else {}
    if path is not None:
        _truncate_torn_tail(path)
    rows: list[CandidateResult] = []
    for n in range(min_modules, max_modules + 1):
        codes = candidates.get(n, []) if candidates is not None else candidate_codes(n, sampling)
        if on_level is not None:
            on_level(n, len(codes))
        level: list[tuple[CandidateResult, dict | None]] = []
        todo = []
        for c in codes:
            key = fingerprint(task, params, opts, c)
            if key in done:
                level.append(done[key])
                if on_result is not None:
                    on_result(done[key][0])
            else:
                todo.append(c)
        with _Runner(workers, scheduler) as runner:
            for row, record in runner.map(todo, task, params, opts):
                level.append((row, record))
                if path is not None:
                    with writing(path), path.open("a") as fh:  # one line per finished candidate, flushed at once
                        fh.write(json.dumps({"row": asdict(row), "record": record if row.feasible else None}) + "\n")
                if on_result is not None:
                    on_result(row)
        rows.extend(r for r, _ in level)
        feasible = [(r, rec) for r, rec in level if r.feasible and rec is not None]
        if feasible:
            best_row, best_record = min(feasible, key=lambda x: (x[0].cost, x[0].code))
            src = str(path) if path is not None and best_row.key in done else f"the design of {best_row.code}"
            return Selection(SelectedDesign.of(best_row, best_record, src), n, tuple(rows))
    return Selection(None, None, tuple(rows))


def results_table(results: Iterable[CandidateResult]) -> list[dict]:
    """Rows as dicts, sorted by n then cost (infeasible last), for JSON or CSV output."""
    rows = [asdict(r) for r in results]
    return sorted(rows, key=lambda r: (r["n"], not r["feasible"], r["cost"] if np.isfinite(r["cost"]) else 0,
                                       r["code"]))
