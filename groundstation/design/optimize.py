"""Downwash-aware optimization of one configuration (paper §IV-B), multi-started, verified, with evidence.

The NLP and its reformulations are in :mod:`groundstation.design.nlp`, the initial guesses in
:mod:`groundstation.design.starts`, the proofs of infeasibility in :mod:`groundstation.design.certificates`.
This module runs them:

1. A certificate is looked for first; a topology that provably cannot meet the wrench set is not solved.
2. Each start runs a feasibility phase (least wrench violation, all other constraints hard) and, if that reaches
   a point meeting the wrenches, the cost phase from there. A start whose feasibility phase stalls at a clear
   violation skips the cost phase: it reports how far from feasible it got.
3. The multi-start stops on evidence: once ``min_starts`` have run and the best cost has been reached by
   ``confirmations`` starts (a second basin leading to the same optimum), or when the budget is spent.
4. Every candidate is verified in numpy against the original constraints over ALL module pairs
   (:mod:`groundstation.assembly.verification`).

The design reports the distinct local optima its starts reached, how many reached the best, the relative gap to
the second best, and the Boender-Rinnooy Kan estimate of optima no start reached.

:func:`least_bound` runs the same multi-start with another objective: the least actuator bound ``u_max`` at which
the topology meets the wrench set (issue 23: why the paper's Fig. 5 shows the n = 4 designs it does). Each
start's feasibility phase is the one above, at the nominal ``u_max``; the *bound* phase then frees the bound and
minimises it, from that point whether or not it met the wrenches (§IV-C: every start of the T ``oS(W)E`` misses
them at 4e6, and the bound phase from those points finds 4.0568e6 where a feasibility phase with the inputs
unbounded led to a poorer basin, 4.0682e6). The result is a design verified at ``u_max`` = its own largest input.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from groundstation.assembly import kinematics as kin
from groundstation.assembly.assembly import Assembly
from groundstation.assembly.assembly_file import assembly_record
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.assembly.verification import Verification, input_cost, verify
from groundstation.design import starts as st
from groundstation.design.certificates import Certificate, force_span_certificate, infeasibility_certificate
from groundstation.design.interrupt import StopFlag, interruptible
from groundstation.design.nlp import BOUND, COST, FEASIBILITY, LiftedNlp, capsule_ends, close_pairs

SUCCEEDED = "Solve_Succeeded"
"""Ipopt's status of a fully converged solve (tolerance ``tol``, not only the acceptable level)."""
FEASIBILITY_GATE = 1e-3
"""A feasibility phase ending with a wrench violation above this fraction of ``max(1, |b|_inf)`` ends the start."""


@dataclass(frozen=True)
class SolverOptions:
    """Knobs of :func:`optimize`. ``None`` picks by size (see :func:`start_budget`, :func:`default_rim_tilts`)."""

    rim_tilts_deg: tuple[float, ...] | None = None
    """Fold starts, tried in order: tilt of the outermost module of the starting bowl, degrees."""
    yaw_turns: tuple[int, ...] = (0, 2, 1, 3)
    """Quarter turns of the starting yaw tried with each fold (ignored when ``free_yaw`` is off)."""
    random_starts: int = 8
    """Random shapes appended to the fold starts (used only when the budget reaches them)."""
    seed: int = 0
    """Seed of the random starts."""
    min_starts: int | None = None
    """Starts always run (unless a certificate proves infeasibility)."""
    max_starts: int | None = None
    """Start budget."""
    confirmations: int = 2
    """Stop once this many starts reached the best cost (after ``min_starts``)."""
    same_optimum_rtol: float = 1e-6
    """Costs within this relative distance are the same local optimum."""
    pair_margin: float = 0.15
    """A module pair enters the NLP when its capsules are closer than ``2 r + pair_margin``, m."""
    clearance_margin: float = 1e-4
    """The NLP asks for ``2 r + clearance_margin`` between capsule axes, so that the verified distance is at
    least ``2 r`` exactly, m."""
    max_rounds: int = 6
    """Re-solves per phase for activating pairs that came close."""
    iter_per_module: int = 4
    min_iter: int = 200
    """Ipopt iteration cap per solve: ``max(min_iter, iter_per_module * n)``. A start that converges slowly
    (n = 30: 486 iterations from one start, 61 from another) cannot eat the budget; successful starts took about
    3.5 n iterations (n = 90: 323)."""
    max_iter: int = 3000
    """Cap for the second pass: when no start was feasible, starts that hit the first cap run again with this."""
    tol: float = 1e-8
    """Ipopt convergence tolerance (scaled problem)."""
    free_yaw: bool = True
    """Optimize the body yaw (``False``: the paper's formulation, yaw fixed at 0)."""


@dataclass(frozen=True)
class StartReport:
    """What one start of the multi-start did."""

    start: str
    """The initial guess, e.g. ``fold 20 deg, yaw +90 deg``."""
    status: str
    """Ipopt's status of the last solve, or ``Infeasible_Local`` when the feasibility phase stalled."""
    feasible: bool
    cost: float
    """Cost of the verified design, (rad^2/s^2)^2 (``inf`` if infeasible)."""
    residual: float
    """Wrench residual at the end of the start, N or N m."""
    iterations: int
    wall_s: float
    """Wall time of the start, s; the split below does not count the numpy verification."""
    ipopt_s: float
    """In Ipopt itself (the KKT factorizations), s."""
    function_s: float
    """Evaluating the NLP's functions and derivatives, s."""
    build_s: float
    """Building solvers for pair sets no earlier start used, s."""


@dataclass(frozen=True, eq=False)
class Design:
    """Result of optimizing one configuration for one wrench set. Infeasible designs are results too."""

    topology: Topology
    params: ModuleParams
    wrenches: np.ndarray = field(repr=False)
    """(K, 6) wrench set solved (after the task's modification), N and N m, body frame."""
    weights: np.ndarray = field(repr=False)
    """(K,) lambda_k."""
    alpha: np.ndarray
    """(n + 1,) root angles and relative connector angles, rad (see kinematics)."""
    yaw: float
    """Body yaw, rad."""
    u: np.ndarray = field(repr=False)
    """(K, 4n) rotor inputs per wrench, rad^2/s^2, in rotor order (module-major, q = 1..4)."""
    cost: float
    """sum_k lambda_k |u_k|^2, (rad^2/s^2)^2 (``inf`` when infeasible)."""
    status: str
    """Ipopt's return status of the chosen start, or why nothing was solved."""
    iterations: int
    """Ipopt iterations of the chosen start."""
    wall_s: float
    """Wall time of the whole multi-start, s."""
    verification: Verification
    starts: tuple[StartReport, ...] = ()
    active_pairs: int = 0
    """Capsule pairs that entered the NLP for the chosen start."""
    certificate: Certificate | None = None
    """Proof of infeasibility (then nothing was solved)."""
    stop_reason: str = ""
    """``confirmed`` (best reached by enough starts), ``budget`` (start budget spent) or ``certificate``."""
    optima: tuple[float, ...] = ()
    """Distinct values of the objective at the verified designs the starts reached, ascending: costs
    ((rad^2/s^2)^2), or input bounds (rad^2/s^2) for a least-bound design."""
    best_hits: int = 0
    """Starts that reached the best value of the objective."""
    objective: str = COST
    """``cost`` (:func:`optimize`: the least cost at ``params.u_max``) or ``bound`` (:func:`least_bound`: the
    least input bound, which is then ``params.u_max``)."""

    @property
    def feasible(self) -> bool:
        return self.verification.feasible

    @property
    def n(self) -> int:
        return self.topology.n

    @property
    def spread(self) -> float | None:
        """Relative gap from the best to the second-best local optimum reached, or None with fewer than two."""
        return (self.optima[1] - self.optima[0]) / self.optima[0] if len(self.optima) > 1 else None

    @property
    def expected_unseen_optima(self) -> float:
        """Boender & Rinnooy Kan (1987): with ``w`` distinct optima from ``N`` successful starts, the posterior
        expected number of local optima is ``w (N - 1) / (N - w - 2)``; this is that minus ``w`` (``inf`` until
        ``N > w + 2``). Small means more starts are unlikely to find another optimum."""
        w, n = len(self.optima), sum(s.feasible for s in self.starts)
        return w * (n - 1) / (n - w - 2) - w if n > w + 2 else float("inf")

    @property
    def assembly(self) -> Assembly:
        """The designed assembly (geometry only)."""
        return Assembly(self.topology, self.params, self.alpha, self.yaw)

    def record(self, task_name: str = "") -> dict:
        """Assembly-file record: the geometry plus the design's wrenches, inputs, cost, statistics, checks."""
        rec = assembly_record(self.assembly)
        unseen = self.expected_unseen_optima
        rec.update({
            "status": self.status,
            "feasible": self.feasible,
            "cost": self.cost if self.feasible else None,
            "task": task_name,
            "wrenches": self.wrenches.tolist(),
            "weights": self.weights.tolist(),
            "u": self.u.tolist(),
            "solver": {"iterations": self.iterations, "wall_s": self.wall_s, "active_pairs": self.active_pairs,
                       "stop_reason": self.stop_reason, "optima": list(self.optima), "best_hits": self.best_hits,
                       "spread": self.spread, "objective": self.objective,
                       "expected_unseen_optima": unseen if np.isfinite(unseen) else None,
                       "starts": [{**asdict(s), "cost": s.cost if s.feasible else None} for s in self.starts]},
            "certificate": asdict(self.certificate) if self.certificate else None,
            "verification": asdict(self.verification),
        })
        return rec


def default_rim_tilts(n: int) -> tuple[float, ...]:
    """Fold order measured on the random-wrench sets (wall time of the whole multi-start, one core):
    20 degrees first for n = 30 took 2.9 / 8.1 / 6.5 s on three topologies against 23.8 / 5.7 / 5.5 s with
    10 first, and 20.5 vs 25.5 s at n = 60; at n = 90, 10 first took 76 s against 150 s. Larger assemblies
    want the shallower first bowl."""
    return (20.0, 10.0, 30.0, 5.0) if n <= 60 else (10.0, 20.0, 30.0, 5.0)


def start_budget(n: int) -> tuple[int, int]:
    """``(min_starts, max_starts)`` by size. Small assemblies solve in a fraction of a second per start and get
    every quarter turn of several folds (§IV-C, n = 4: 0.4-0.8 s per topology for 16-24 starts). Large ones take
    1.5-2 s (n = 30) and 10-25 s (n = 90) per start, and nearly every start ends in a local optimum of its own
    (n = 30: 6 distinct optima from 6 starts, 0.5-2 % apart), so the budget is what the default command can spend:
    about 10 s at n = 30 and under a minute at n = 90 (``python -m benchmarks.design``). Between, n = 9-20 runs
    all four folds at every quarter turn: two starts agreeing is no evidence there (n = 15: the first two folds
    agreed on an optimum 3.1 % above the one the fourth found), and random shapes almost never meet the wrenches
    (2 of 102 at n = 20) at 1-3 times a fold's cost. Against the best of 50 starts on random10_seed0,
    median over three topologies: n = 10 0.00 %, n = 15 0.41 -> 0.00 %, n = 20 0.00 %, n = 30 0.12 %, in 1.00-1.07
    times the time of the 8-16 starts before (``python -m benchmarks.design_quality``)."""
    if n <= 8:
        return 16, 32
    if n <= 20:
        return 16, 16
    if n <= 40:
        return 2, 5
    return 2, 3


def with_input_bound(params: ModuleParams, u_max: float) -> ModuleParams:
    """``params`` with another input bound ``u_max`` (rad^2/s^2). The motor map is dropped: the bound is the
    model's actuator, and a bound beyond what the motor reaches is still an answer of the design study."""
    return replace(params, u_max=u_max, motor_command=None)


def _verified_bound(params: ModuleParams, u: np.ndarray) -> ModuleParams:
    """What a least-bound design is verified at: its own largest input as ``u_max``, so its inputs meet the bound
    with no tolerance. Inputs that are not finite and positive (a failed solve) keep the nominal bound and fail
    the verification on their own."""
    top = float(np.max(u))
    return with_input_bound(params, top if np.isfinite(top) and top > 0 else params.u_max)


@dataclass(frozen=True)
class _Outcome:
    """A start's end point with its verification."""

    alpha: np.ndarray
    yaw: float
    u: np.ndarray
    params: ModuleParams
    """What the verification used (for the least-bound search: ``u_max`` = the largest input)."""
    cost: float
    value: float
    """The objective the multi-start ranks by: the cost, or the input bound ``params.u_max`` (``inf`` when
    infeasible)."""
    status: str
    iterations: int
    verification: Verification
    active_pairs: int


class _MultiStart:
    """The starts of one topology: shared NLP (and its cached solvers), the runs, and what they found."""

    def __init__(self, topo: Topology, params: ModuleParams, wrenches: np.ndarray, weights: np.ndarray,
                 opts: SolverOptions, stop: StopFlag) -> None:
        self.topo, self.params, self.wrenches, self.weights, self.opts = topo, params, wrenches, weights, opts
        self.stop = stop
        self.nlp = LiftedNlp(topo, params, wrenches, weights, free_yaw=opts.free_yaw,
                             clearance=2 * params.r + opts.clearance_margin, tol=opts.tol, should_stop=stop)
        self.scale = max(1.0, float(np.max(np.abs(wrenches))))
        self.known: set[tuple[int, int]] = set()
        """Module pairs some start has had under clearance constraints."""

    def _ends(self, alpha, yaw) -> np.ndarray:
        pos, rot = kin.module_frames(self.topo, alpha, self.params.l_c, yaw)
        return capsule_ends(pos, rot, self.params)

    def _phase(self, phase: str, alpha, yaw, v, active: set, max_iter: int, rounds: int):
        """One phase with up to ``rounds`` solves, each adding the pairs that came close to ``active``;
        returns the new point, status, iterations."""
        p, status, iters = self.params, "not solved", 0
        for _ in range(rounds):
            sol = self.nlp.solve(phase, alpha, yaw, v, tuple(sorted(active)), max_iter)
            self.stop.check()
            alpha, yaw, v, status = sol.alpha, sol.yaw, sol.v, sol.status
            iters += sol.iterations
            self.split[0] += sol.wall_s - sol.function_s
            self.split[1] += sol.function_s
            new = close_pairs(self._ends(alpha, yaw), 2 * p.r + 0.5 * self.opts.pair_margin) - active
            if not new:
                break
            active |= new
        return alpha, yaw, v, status, iters

    def run(self, start: st.Start, max_iter: int, objective: str) -> tuple[_Outcome, StartReport]:
        """One start: the feasibility phase, then the phase of ``objective`` (``cost`` or ``bound``)."""
        t0, built = time.perf_counter(), self.nlp.build_s
        self.split = [0.0, 0.0]  # Ipopt, function evaluations, s
        p = self.params
        alpha, yaw = st.initial_shape(start, self.topo, self.wrenches, self.opts.free_yaw)
        pos, rot = kin.module_frames(self.topo, alpha, p.l_c, yaw)
        v = st.least_squares_inputs(kin.allocation_matrix(pos, rot, p), self.wrenches, p.u_max).T / p.u_max
        # Pairs any earlier start needed join this one's from the outset: a solver is built per pair set (2 s at
        # n = 90), and with the union later starts mostly reuse one (n = 90, 4 starts: 7 builds without it).
        active = close_pairs(self._ends(alpha, yaw), 2 * p.r + self.opts.pair_margin) | self.known
        # One feasibility solve: pairs that came close during it join the cost phase, whose rounds start from
        # points that already meet the wrenches and take 15-30 iterations (n = 90) where a second feasibility
        # round took 70-120.
        alpha, yaw, v, status, iters = self._phase(FEASIBILITY, alpha, yaw, v, active, max_iter, 1)
        u = np.clip(v.T * p.u_max, 0.0, p.u_max)
        residual = verify(Assembly(self.topo, p, alpha, yaw), u, self.wrenches).max_wrench_residual
        # The bound phase runs from a point that misses the wrenches too: above the nominal bound it may meet them.
        if objective == COST and residual > FEASIBILITY_GATE * self.scale:
            status = "Infeasible_Local"
        elif self.nlp.equalities <= self.nlp.unknowns:
            # (One module with several wrenches has more equalities than unknowns: Ipopt refuses the cost phase,
            # and the feasibility phase's point is the only candidate.)
            alpha, yaw, v, status, it = self._phase(objective, alpha, yaw, v, active, max_iter, self.opts.max_rounds)
            iters += it
            u = np.clip(v.T * p.u_max, 0.0, p.u_max if objective == COST else np.inf)
        self.known |= active
        checked = p if objective == COST else _verified_bound(p, u)
        ver = verify(Assembly(self.topo, checked, alpha, yaw), u, self.wrenches)
        cost = input_cost(u, self.weights) if ver.feasible else float("inf")
        value = cost if objective == COST or not ver.feasible else checked.u_max
        out = _Outcome(alpha, float(np.arctan2(np.sin(yaw), np.cos(yaw))), u, checked, cost, value, status, iters,
                       ver, len(active))
        return out, StartReport(start.label, status, ver.feasible, cost, ver.max_wrench_residual, iters,
                                time.perf_counter() - t0, *self.split, self.nlp.build_s - built)


def confirmed(values: list[float], started: int, min_starts: int, opts: SolverOptions) -> bool:
    """The multi-start's stopping rule: ``started`` starts have run, at least ``min_starts``, and of their
    feasible ``values`` ``opts.confirmations`` reached the least."""
    _, hits = _optima(values, opts.same_optimum_rtol)
    return started >= min_starts and hits >= opts.confirmations


def _optima(values: list[float], rtol: float) -> tuple[tuple[float, ...], int]:
    """Distinct local optima among ``values`` (ascending) and how many values reached the least."""
    distinct: list[float] = []
    for c in sorted(values):
        if not distinct or c > distinct[-1] * (1 + rtol):
            distinct.append(c)
    best_hits = sum(c <= distinct[0] * (1 + rtol) for c in values) if distinct else 0
    return tuple(distinct), best_hits


def _best(outcomes: list[_Outcome], rtol: float) -> _Outcome:
    """The feasible outcome of least value; of starts at the same optimum (within ``rtol``), one Ipopt fully
    converged (their values differ by rounding, 1e-10 relative in the toy case, so which of them is least is an
    accident of summation order, and an "acceptable level" stop is the weaker certificate). Without a feasible
    outcome: the least value, then the least wrench residual (as before)."""
    feasible = [o for o in outcomes if o.verification.feasible]
    if not feasible:
        return min(outcomes, key=lambda o: (o.value, o.verification.max_wrench_residual))
    least = min(o.value for o in feasible)
    return min((o for o in feasible if o.value <= least * (1 + rtol)), key=lambda o: (o.status != SUCCEEDED, o.value))


def optimize(topo: Topology, params: ModuleParams, wrenches: np.ndarray, weights: np.ndarray | None = None,
             opts: SolverOptions | None = None) -> Design:
    """Optimize connector angles and inputs of ``topo`` for the wrench set; multi-start, verified in numpy."""
    return _multistart(topo, params, wrenches, weights, opts or SolverOptions(), COST)


def least_bound(topo: Topology, params: ModuleParams, wrenches: np.ndarray, weights: np.ndarray | None = None,
                opts: SolverOptions | None = None) -> Design:
    """The least input bound at which ``topo`` meets the wrench set, as the design that needs it: a design
    verified at its own ``params.u_max`` (rad^2/s^2), the least bound any start reached (a local optimum, like
    every cost, so an upper bound of the true least). Infeasible: with a ``force-span`` certificate no bound can
    work; without one, no start met the wrenches. Same starts and budget as :func:`optimize`."""
    return _multistart(topo, params, wrenches, weights, opts or SolverOptions(), BOUND)


def _multistart(topo: Topology, params: ModuleParams, wrenches: np.ndarray, weights: np.ndarray | None,
                opts: SolverOptions, objective: str) -> Design:
    """The multi-start of :func:`optimize` (``objective`` ``cost``) and :func:`least_bound` (``bound``)."""
    wrenches = np.atleast_2d(np.asarray(wrenches, dtype=float))
    weights = np.ones(len(wrenches)) if weights is None else np.asarray(weights, dtype=float)
    t_start = time.perf_counter()
    # The thrust-capacity proof is about the nominal bound; only the span proof holds whatever the bound.
    certificate = infeasibility_certificate(topo, params, wrenches) if objective == COST else \
        force_span_certificate(topo, wrenches)
    if certificate is not None:
        alpha = np.zeros(topo.n + 1)
        u = np.zeros((len(wrenches), 4 * topo.n))
        return Design(topology=topo, params=params, wrenches=wrenches, weights=weights, alpha=alpha, yaw=0.0, u=u,
                      cost=float("inf"), status="Infeasible_Certified", iterations=0,
                      wall_s=time.perf_counter() - t_start,
                      verification=verify(Assembly(topo, params, alpha), u, wrenches), certificate=certificate,
                      stop_reason="certificate", objective=objective)
    lo, hi = start_budget(topo.n)
    min_starts = min(opts.min_starts or lo, opts.max_starts or hi)
    max_starts = opts.max_starts or hi
    turns = opts.yaw_turns if opts.free_yaw else (0,)
    plan = st.plan(opts.rim_tilts_deg or default_rim_tilts(topo.n), turns, opts.random_starts, opts.seed)[:max_starts]
    outcomes: list[_Outcome] = []
    reports: list[StartReport] = []
    stop_reason = "budget"
    first_cap = max(opts.min_iter, opts.iter_per_module * topo.n)
    with interruptible() as stop:
        runs = _MultiStart(topo, params, wrenches, weights, opts, stop)
        for i, start in enumerate(plan):
            out, rep = runs.run(start, first_cap, objective)
            outcomes.append(out)
            reports.append(rep)
            if confirmed([o.value for o in outcomes if o.verification.feasible], i + 1, min_starts, opts):
                stop_reason = "confirmed"
                break
        if not any(o.verification.feasible for o in outcomes) and opts.max_iter > first_cap:
            for start, rep in list(zip(plan, reports, strict=False)):
                if rep.status == "Maximum_Iterations_Exceeded":
                    out, rep2 = runs.run(start, opts.max_iter, objective)
                    outcomes.append(out)
                    reports.append(rep2)
    optima, best_hits = _optima([o.value for o in outcomes if o.verification.feasible], opts.same_optimum_rtol)
    best = _best(outcomes, opts.same_optimum_rtol)
    return Design(topology=topo, params=best.params, wrenches=wrenches, weights=weights, alpha=np.asarray(best.alpha),
                  yaw=best.yaw, u=best.u, cost=best.cost, status=best.status, iterations=best.iterations,
                  wall_s=time.perf_counter() - t_start, verification=best.verification, starts=tuple(reports),
                  active_pairs=best.active_pairs, stop_reason=stop_reason, optima=optima, best_hits=best_hits,
                  objective=objective)
