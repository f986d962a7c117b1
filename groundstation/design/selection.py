"""Selection across configurations (paper §IV-C, Algorithm 2).

For n = 1, 2, ... solve every candidate topology of n modules (exhaustive, sampled, or from a candidates file);
stop at the first n with a feasible design and pick the least cost; the runner-up and its gap are reported with
it. Candidates run in parallel, in a local process pool or on a Dask distributed scheduler. Every finished
candidate is appended to a JSON-lines results file at once, with its design record, so an interrupted sweep
(Ctrl-C, a kill) resumes without redoing finished candidates.

A resumed row is not trusted: it is reused only if its fingerprint includes this solver's version
(:func:`solver_version`), and only after its record has been re-verified from the saved angles and inputs
(:func:`groundstation.assembly.assembly_file.checked_record`) and the row agrees with it: its topology, feasibility,
cost, clearance, residual and certificate. A row that disagrees (an edited results file) is a ConfigError naming
``FILE:LINE`` and the key; it is never reported as the best.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import signal
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path

import casadi as ca
import numpy as np

import groundstation.assembly
import groundstation.design
from groundstation import __version__
from groundstation.assembly.assembly import Assembly
from groundstation.assembly.assembly_file import COST_RTOL, POSE_TOLERANCE, checked_record
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.assembly.verification import Verification
from groundstation.design.certificates import infeasibility_certificate
from groundstation.design.enumeration import SamplingPolicy, enumerate_levels
from groundstation.design.optimize import SolverOptions, optimize
from groundstation.design.task import Task
from groundstation.errors import ConfigError, TopologyError
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
    """Fingerprint of (task, module parameters, solver options, topology, solver version): what resuming matches
    on."""
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
        """From a candidate's row and record, re-verified like an assembly file being loaded; a record that does
        not verify (a hand-edited results file ``src``) is a ConfigError naming it and the key."""
        assembly, design = checked_record(record, src)
        if design is None:
            raise ConfigError(f"the record of {row.code} is not a design record", path=src, key="verification")
        return cls(row, assembly, design.wrenches, design.verification, record)


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


@functools.cache
def solver_version() -> str:
    """What a design depends on besides its inputs: the package version, the source of the ``assembly`` and
    ``design`` packages, and the CasADi (with its Ipopt) and numpy versions, hashed. Any change there makes rows of
    an earlier run new work instead of results reused as if this code had solved them."""
    digest = hashlib.sha256(f"{__version__} casadi {ca.__version__} numpy {np.__version__}".encode())
    for package in (groundstation.assembly, groundstation.design):
        for path in sorted(Path(package.__file__).parent.glob("*.py")):
            digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def fingerprint(task: Task, params: ModuleParams, opts: SolverOptions, code: str) -> str:
    blob = json.dumps([asdict(task), asdict(params), asdict(opts), code, solver_version()], sort_keys=True,
                      default=str)
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


@dataclass(frozen=True, eq=False)
class SavedRow:
    """A finished candidate as an earlier run wrote it: not yet verified."""

    row: CandidateResult
    record: dict | None
    """Its design record (``None`` in files written before records were kept for infeasible rows)."""
    src: str
    """``FILE:LINE`` it was read from, for errors."""


def read_results(path: Path) -> dict[str, SavedRow]:
    """Finished candidates of an earlier run, by fingerprint. A torn last line (killed mid-write) is skipped."""
    done: dict[str, SavedRow] = {}
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
        done[row.key] = SavedRow(row, entry.get("record"), f"{path}:{lineno}")
    return done


def _close(stored, recomputed: float, rel: float, abs_: float = 0.0) -> bool:
    """A stored number agrees with the recomputed one (``inf`` only with ``inf``; a non-number never)."""
    return isinstance(stored, int | float) and math.isclose(stored, recomputed, rel_tol=rel, abs_tol=abs_)


def _reverified(saved: SavedRow, task: Task, params: ModuleParams) -> tuple[CandidateResult, dict]:
    """A resumed row and its record, once the record re-verifies from its angles and inputs and the row agrees
    with it and with this task; otherwise a ConfigError naming ``FILE:LINE`` and the key (``row.*`` for the row,
    the record's own keys otherwise)."""
    row, record, src = saved.row, saved.record, saved.src
    if record is None:
        raise ConfigError("no design record to verify the row against", path=src, key="record")
    assembly, design = checked_record(record, src)
    if design is None:
        raise ConfigError("not a design record", path=src, key="record")
    try:
        code = Topology.from_code(row.code).code
    except TopologyError as exc:
        raise ConfigError(f"invalid topology: {exc}", path=src, key="row.code") from None
    if code != assembly.topology.code:
        raise ConfigError(f"says {row.code}, but the record is a design of {assembly.topology.code}", path=src,
                          key="row.code")
    if row.n != assembly.n:
        raise ConfigError(f"says {row.n}, but {code} has {assembly.n} modules", path=src, key="row.n")
    if assembly.params != params:
        raise ConfigError("not the module parameters of this run", path=src, key="module_params")
    wrenches, weights = task.wrenches_for(assembly.n, params)
    for key, stored, wanted in (("wrenches", design.wrenches, wrenches), ("weights", design.weights, weights)):
        if stored.shape != wanted.shape or not np.allclose(stored, wanted, rtol=1e-12, atol=0.0):
            raise ConfigError(f"not the task's {key} for {assembly.n} modules", path=src, key=key)
    ver = design.verification
    certificate = infeasibility_certificate(assembly.topology, params, wrenches)
    checks = (  # the row's field, its value recomputed from the record, whether they agree
        ("feasible", ver.feasible, row.feasible is ver.feasible),
        ("cost", design.cost, _close(row.cost, design.cost, COST_RTOL)),
        ("min_clearance_m", ver.min_capsule_distance, _close(row.min_clearance_m, ver.min_capsule_distance, 1e-9,
                                                             POSE_TOLERANCE)),
        ("max_wrench_residual", ver.max_wrench_residual, _close(row.max_wrench_residual, ver.max_wrench_residual,
                                                                1e-9, ver.residual_tolerance)),
        ("certificate", certificate.reason if certificate else "",
         row.certificate == (certificate.reason if certificate else "")),
    )
    for name, recomputed, ok in checks:
        if not ok:
            raise ConfigError(f"says {getattr(row, name)!r}, but its record, re-verified, gives {recomputed!r}",
                              path=src, key=f"row.{name}")
    return row, record


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
                level.append(_reverified(done[key], task, params))
                if on_result is not None:
                    on_result(level[-1][0])
            else:
                todo.append(c)
        with _Runner(workers, scheduler) as runner:
            for row, record in runner.map(todo, task, params, opts):
                level.append((row, record))
                if path is not None:
                    with writing(path), path.open("a") as fh:  # one line per finished candidate, flushed at once
                        fh.write(json.dumps({"row": asdict(row), "record": record}) + "\n")
                if on_result is not None:
                    on_result(row)
        rows.extend(r for r, _ in level)
        feasible = [(r, rec) for r, rec in level if r.feasible]
        if feasible:
            best_row, best_record = min(feasible, key=lambda x: (x[0].cost, x[0].code))
            src = done[best_row.key].src if best_row.key in done else f"the design of {best_row.code}"
            return Selection(SelectedDesign.of(best_row, best_record, src), n, tuple(rows))
    return Selection(None, None, tuple(rows))


def results_table(results: Iterable[CandidateResult]) -> list[dict]:
    """Rows as dicts, sorted by n then cost (infeasible last), for JSON or CSV output."""
    rows = [asdict(r) for r in results]
    return sorted(rows, key=lambda r: (r["n"], not r["feasible"], r["cost"] if np.isfinite(r["cost"]) else 0,
                                       r["code"]))
