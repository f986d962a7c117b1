"""Selection across configurations (paper §IV-C, Algorithm 2).

For n = 1, 2, ... solve every candidate topology of n modules (exhaustive, sampled, or from a candidates file);
stop at the first n with a feasible design and pick the least cost; the runner-up and its gap are reported with
it. Every candidate also gets the least input bound ``u_max`` at which it is feasible
(:func:`groundstation.design.optimize.least_bound`), or the proof that no bound makes it so; the figure of cost
against ``u_max`` per topology comes from :func:`cost_against_bound`. Candidates run in parallel, in a local
process pool or on a Dask distributed scheduler. Every finished candidate is appended to a JSON-lines results file
at once, with its design records, so an interrupted sweep (Ctrl-C, a kill) resumes without redoing finished
candidates.

A resumed row is not trusted: it is reused only if its fingerprint includes this solver's version
(:func:`solver_version`), and only after its records have been re-verified from the saved angles and inputs
(:func:`groundstation.assembly.assembly_file.checked_record`) and the row agrees with them: its topology,
feasibility, cost, clearance, residual and certificate, and its least bound (the least-bound design passes the
verification at that bound) with its cost and its proof of never being feasible. A row that disagrees (an edited
results file) is a ConfigError naming ``FILE:LINE`` and the key; it is never reported as the best.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import signal
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, replace
from multiprocessing import get_context
from pathlib import Path

import casadi as ca
import numpy as np

import groundstation.assembly
import groundstation.design
from groundstation import __version__
from groundstation.assembly.assembly import Assembly
from groundstation.assembly.assembly_file import COST_RTOL, POSE_TOLERANCE, CheckedDesign, checked_record
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.assembly.verification import Verification
from groundstation.design.certificates import force_span_certificate, infeasibility_certificate
from groundstation.design.enumeration import SamplingPolicy, enumerate_levels
from groundstation.design.optimize import SolverOptions, least_bound, optimize, with_input_bound
from groundstation.design.task import Task
from groundstation.errors import ConfigError, GroundstationError, TopologyError
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
    # The least-bound fields have defaults so that rows written before them still parse: they belong to another
    # solver version and are solved again, not refused as malformed.
    least_searched: bool = False
    """Whether the least-bound search ran (``design --least-u-max``); the fields below are its results."""
    least_u_max: float = math.inf
    """Least input bound ``u_max`` at which a start met every constraint, rad^2/s^2; the design needing it is
    verified at that bound (``least_u_max_record`` of the results line). ``inf`` when no start did, or when
    ``never_feasible``."""
    least_u_max_cost: float = math.inf
    """Cost of that design, (rad^2/s^2)^2."""
    least_u_max_hits: int = 0
    """Starts of the least-bound search that reached it."""
    least_u_max_s: float = 0.0
    """Wall time of the least-bound search, s."""
    never_feasible: str = ""
    """Proof that no input bound makes the topology feasible (its thrust axes cannot span the task's forces), or
    empty."""


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


DRAWING_ONLY = frozenset({"figures.py", "drawing.py"})
"""Modules of ``design`` that only draw what was solved: a change to a figure does not make a sweep solve again."""


@functools.cache
def solver_version() -> str:
    """What a design depends on besides its inputs: the package version, the source of the ``assembly`` and
    ``design`` packages, and the CasADi (with its Ipopt) and numpy versions, hashed. Any change there makes rows of
    an earlier run new work instead of results reused as if this code had solved them."""
    digest = hashlib.sha256(f"{__version__} casadi {ca.__version__} numpy {np.__version__}".encode())
    for package in (groundstation.assembly, groundstation.design):
        for path in sorted(Path(package.__file__).parent.glob("*.py")):
            if path.name not in DRAWING_ONLY:
                digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def fingerprint(task: Task, params: ModuleParams, opts: SolverOptions, code: str, least: bool = False) -> str:
    """What a results line was solved for (``least``: with the least-bound search); a line is reused only for the
    same."""
    what = [asdict(task), asdict(params), asdict(opts), code, solver_version()] + (["least"] if least else [])
    blob = json.dumps(what, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def solve_candidate(code: str, task: Task, params: ModuleParams, opts: SolverOptions,
                    least: bool = False) -> tuple[CandidateResult, dict, dict | None]:
    """Solve one topology (runs in a worker process): its least cost and, with ``least``, its least input bound
    (about as long again as the cost search: not by default). Returns its row, its assembly record and the record
    of its least-bound design (None without ``least``)."""
    topo = Topology.from_code(code)
    wrenches, weights = task.wrenches_for(topo.n, params)
    d = optimize(topo, params, wrenches, weights, opts)
    row = CandidateResult(topo.n, code, d.status, d.feasible, d.cost, d.iterations, d.wall_s,
                          d.verification.min_capsule_distance, d.verification.max_wrench_residual,
                          fingerprint(task, params, opts, code, least), starts=len(d.starts),
                          feasible_starts=sum(s.feasible for s in d.starts), optima=len(d.optima),
                          best_hits=d.best_hits, spread=d.spread, stop_reason=d.stop_reason,
                          certificate=d.certificate.reason if d.certificate else "")
    if not least:
        return row, d.record(task.name), None
    bound = least_bound(topo, params, wrenches, weights, opts)
    row = replace(row, least_searched=True, least_u_max=bound.params.u_max if bound.feasible else math.inf,
                  least_u_max_cost=bound.cost, least_u_max_hits=bound.best_hits, least_u_max_s=bound.wall_s,
                  never_feasible=bound.certificate.reason if bound.certificate else "")
    return row, d.record(task.name), bound.record(task.name)


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
    least_record: dict | None
    """The record of its least-bound design (``None`` in files written before there was one)."""
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
        except (ValueError, TypeError, KeyError, RecursionError) as exc:
            if lineno == len(lines):
                continue
            raise ConfigError(f"line {lineno} is not a result row: {exc}", path=str(path)) from None
        done[row.key] = SavedRow(row, entry.get("record"), entry.get("least_u_max_record"), f"{path}:{lineno}")
    return done


def _close(stored, recomputed: float, rel: float, abs_: float = 0.0) -> bool:
    """A stored number agrees with the recomputed one (``inf`` only with ``inf``; a non-number never)."""
    if not isinstance(stored, int | float) or isinstance(stored, bool):
        return False
    try:
        return math.isclose(stored, recomputed, rel_tol=rel, abs_tol=abs_)
    except OverflowError:  # an integer past any float (10**400)
        return False


def _checked_design(record: dict | None, src: str, row: CandidateResult, task: Task, params: ModuleParams,
                    any_bound: bool = False) -> tuple[Assembly, CheckedDesign]:
    """A results line's design record re-verified from its angles and inputs, once it is a design of the row's
    topology for this task and the module parameters ``params`` (with ``any_bound``: but for the input bound, as a
    least-bound design is verified at its own); otherwise a ConfigError naming ``src`` and the key."""
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
    if assembly.params != (with_input_bound(params, assembly.params.u_max) if any_bound else params):
        raise ConfigError("not the module parameters of this run", path=src, key="module_params")
    wrenches, weights = task.wrenches_for(assembly.n, params)
    for key, stored, wanted in (("wrenches", design.wrenches, wrenches), ("weights", design.weights, weights)):
        if stored.shape != wanted.shape or not np.allclose(stored, wanted, rtol=1e-12, atol=0.0):
            raise ConfigError(f"not the task's {key} for {assembly.n} modules", path=src, key=key)
    return assembly, design


def _reverified(saved: SavedRow, task: Task, params: ModuleParams) -> tuple[CandidateResult, dict]:
    """A resumed row and its record, once the record and the least-bound record re-verify from their angles and
    inputs and the row agrees with them and with this task; otherwise a ConfigError naming ``FILE:LINE`` and the
    key (``row.*`` for the row, the records' own keys otherwise)."""
    row, src = saved.row, saved.src
    assembly, design = _checked_design(saved.record, src, row, task, params)
    ver = design.verification
    wrenches = design.wrenches
    certificate = infeasibility_certificate(assembly.topology, params, wrenches)
    checks = (  # the row's field, its value recomputed from the records, whether they agree
        ("feasible", ver.feasible, row.feasible is ver.feasible),
        ("cost", design.cost, _close(row.cost, design.cost, COST_RTOL)),
        ("min_clearance_m", ver.min_capsule_distance, _close(row.min_clearance_m, ver.min_capsule_distance, 1e-9,
                                                             POSE_TOLERANCE)),
        ("max_wrench_residual", ver.max_wrench_residual, _close(row.max_wrench_residual, ver.max_wrench_residual,
                                                                1e-9, ver.residual_tolerance)),
        ("certificate", certificate.reason if certificate else "",
         row.certificate == (certificate.reason if certificate else "")),
    )
    if row.least_searched:  # (the fingerprint says the line was solved with the search: it has the record)
        least_assembly, least = _checked_design(saved.least_record, f"{src}: least_u_max_record", row, task, params,
                                                any_bound=True)
        never = force_span_certificate(assembly.topology, wrenches)
        least_u_max = least_assembly.params.u_max if least.verification.feasible else math.inf
        checks += (
            ("least_u_max", least_u_max, _close(row.least_u_max, least_u_max, 0.0)),
            ("least_u_max_cost", least.cost, _close(row.least_u_max_cost, least.cost, COST_RTOL)),
            ("never_feasible", never.reason if never else "", row.never_feasible == (never.reason if never else "")),
        )
    for name, recomputed, ok in checks:
        if not ok:
            raise ConfigError(f"says {getattr(row, name)!r}, but its record, re-verified, gives {recomputed!r}",
                              path=src, key=f"row.{name}")
    return row, saved.record


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

            try:
                self._client = Client(self.scheduler, timeout="20s")
            except (OSError, ValueError) as exc:  # refused, timed out, not an address: one line, not a traceback
                raise GroundstationError(f"cannot reach the Dask scheduler {self.scheduler}: {exc}") from None
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

    def map(self, codes: list[str], task: Task, params: ModuleParams, opts: SolverOptions,
            least: bool) -> Iterable:
        if self._client is not None:
            from distributed import as_completed as dask_completed

            futures = [self._client.submit(solve_candidate, c, task, params, opts, least, pure=False) for c in codes]
            for fut in dask_completed(futures):
                yield fut.result()
        elif self._pool is not None:
            yield from self._pool.imap_unordered(_solve_args, [(c, task, params, opts, least) for c in codes])
        else:
            for c in codes:
                yield solve_candidate(c, task, params, opts, least)


def _solve_args(args: tuple) -> tuple[CandidateResult, dict, dict | None]:
    return solve_candidate(*args)


def select(task: Task, params: ModuleParams, max_modules: int, *, sampling: SamplingPolicy | None = None,
           candidates: dict[int, list[str]] | None = None, opts: SolverOptions | None = None, workers: int = 1,
           scheduler: str | None = None, results_path: str | Path | None = None,
           on_level: Callable[[int, int], None] | None = None,
           on_result: Callable[[CandidateResult], None] | None = None, min_modules: int = 1,
           least: bool = False) -> Selection:
    """Algorithm 2 from ``min_modules`` on. ``candidates`` (codes per n) overrides enumeration; ``results_path``
    makes it resumable; ``least``: each candidate's least input bound too (:func:`solve_candidate`)."""
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
            key = fingerprint(task, params, opts, c, least)
            if key in done:
                level.append(_reverified(done[key], task, params))
                if on_result is not None:
                    on_result(level[-1][0])
            else:
                todo.append(c)
        # No more processes than candidates to solve (--workers 256 for one candidate started 256, each loading
        # CasADi: load 67 on 2 cores, hostile campaign 32).
        with _Runner(max(1, min(workers, len(todo))), scheduler) as runner:
            for row, record, least_record in runner.map(todo, task, params, opts, least):
                level.append((row, record))
                if path is not None:
                    with writing(path), path.open("a") as fh:  # one line per finished candidate, flushed at once
                        fh.write(json.dumps({"row": asdict(row), "record": record,
                                             "least_u_max_record": least_record}) + "\n")
                if on_result is not None:
                    on_result(row)
        rows.extend(r for r, _ in level)
        feasible = [(r, rec) for r, rec in level if r.feasible]
        if feasible:
            best_row, best_record = min(feasible, key=lambda x: (x[0].cost, x[0].code))
            src = done[best_row.key].src if best_row.key in done else f"the design of {best_row.code}"
            return Selection(SelectedDesign.of(best_row, best_record, src), n, tuple(rows))
    return Selection(None, None, tuple(rows))


CURVE_HEADROOM = 1.2
"""The figure's input bounds reach this factor above the largest least bound (or the nominal bound): far enough
for the costs of the topologies feasible at the nominal bound to cross as the bound relaxes."""


@dataclass(frozen=True)
class CostCurve:
    """One topology's least cost against the input bound: why the paper's Fig. 5 shows the designs it shows."""

    code: str
    least_u_max: float
    """Its row's least input bound, rad^2/s^2 (``inf``: none found, or never)."""
    never_feasible: str
    """Its row's proof that no bound works, or empty."""
    u_max: tuple[float, ...]
    """Input bounds at which a design was found, ascending, rad^2/s^2: the least bound, the nominal bound when the
    row is feasible there, and the grid points above the least bound where a solve was feasible."""
    cost: tuple[float, ...]
    """The least cost of the designs found at each bound or a smaller one (a design within a bound is within every
    larger one; the multi-start at a larger bound may stop in a poorer optimum: n = 12, up to 1 %),
    (rad^2/s^2)^2."""


def bound_grid(rows: Iterable[CandidateResult], nominal: float, points: int = 8) -> np.ndarray:
    """Input bounds for the figure, rad^2/s^2: ``points`` evenly from the least bound any row needs to
    :data:`CURVE_HEADROOM` times the largest least bound or the ``nominal`` bound, whichever is larger; empty when
    no row has a least bound."""
    least = [r.least_u_max for r in rows if math.isfinite(r.least_u_max)]
    if not least:
        return np.array([])
    return np.linspace(min(least), CURVE_HEADROOM * max(*least, nominal), points)


def cost_against_bound(task: Task, params: ModuleParams, rows: Iterable[CandidateResult], bounds: np.ndarray,
                       opts: SolverOptions | None = None,
                       on_solve: Callable[[int, int], None] | None = None) -> list[CostCurve]:
    """Each row's least cost at every bound of ``bounds`` (rad^2/s^2) above its least bound, solved by
    :func:`optimize` with that ``u_max`` in this process, plus the designs its row already has: at the least bound
    and at the nominal ``params.u_max``. ``on_solve(done, total)`` is called after each solve."""
    plan = []
    for r in rows:
        known = {}
        if math.isfinite(r.least_u_max):
            known[r.least_u_max] = r.least_u_max_cost
        if r.feasible:
            known[params.u_max] = r.cost
        plan.append((r, known, [float(b) for b in bounds if b > r.least_u_max and b not in known]))
    total, done = sum(len(todo) for *_, todo in plan), 0
    curves = []
    for r, points, todo in plan:
        topo = Topology.from_code(r.code)
        wrenches, weights = task.wrenches_for(topo.n, params)
        for bound in todo:
            d = optimize(topo, with_input_bound(params, bound), wrenches, weights, opts)
            if d.feasible:
                points[bound] = d.cost
            done += 1
            if on_solve is not None:
                on_solve(done, total)
        ordered = sorted(points.items())
        least = np.minimum.accumulate([c for _, c in ordered]) if ordered else []
        curves.append(CostCurve(r.code, r.least_u_max, r.never_feasible, tuple(b for b, _ in ordered),
                                tuple(float(c) for c in least)))
    return curves


def results_table(results: Iterable[CandidateResult]) -> list[dict]:
    """Rows as dicts, sorted by n then cost (infeasible last), for JSON or CSV output."""
    rows = [asdict(r) for r in results]
    return sorted(rows, key=lambda r: (r["n"], not r["feasible"], r["cost"] if np.isfinite(r["cost"]) else 0,
                                       r["code"]))
