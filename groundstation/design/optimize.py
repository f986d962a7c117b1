"""Downwash-aware optimization of one configuration (paper §IV-B, eq. opti), solved with Ipopt via CasADi.

    min  sum_k lambda_k ||u_k||^2
    s.t. A(alpha, yaw) u_k = b_k,  0 <= u_k <= u_max,  -pi/2 <= alpha <= pi/2,
         dist(capsule axis i, capsule axis j) >= 2 r   for all module pairs i < j.

Reformulations (the returned design always satisfies the original constraints, checked in numpy afterwards):

* Inputs are scaled, ``v = u / u_max`` in [0, 1], and wrench rows by ``n m g`` (forces) and ``n m g l_c``
  (torques), which cuts Ipopt iterations about tenfold.
* The clearance between two segments is non-smooth (and degenerate for parallel capsules, the flat start).
  It is replaced by an exact smooth equivalent from the separating-hyperplane theorem: segments S_i, S_j are at
  least 2r apart iff some ``w`` with ``|w| <= 1`` and ``c`` put both end points of S_i on ``w.x >= c + r``
  and both of S_j on ``w.x <= c - r``. Four linear-in-endpoint constraints and one norm constraint per pair.
* Pairs are activated lazily: the NLP starts with the pairs within ``pair_margin`` of touching at the start,
  every pair is checked in numpy after each solve, and pairs that came close are added before re-solving from
  the previous solution. Far pairs never enter the NLP.
* A free body yaw lets one representative of a C4 class face the task in any heading (see kinematics).
* Multi-start over "bowl-up" folds: each child module raised and tilted toward its parent by the fold angle,
  the root levelled so the mean thrust axis is vertical, inputs from the least-squares allocation. A flat start
  (fold 0) is the paper's naive start and is reported for comparison.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import casadi as ca
import numpy as np

from groundstation.assembly import kinematics as kin
from groundstation.assembly.assembly import Assembly
from groundstation.assembly.assembly_file import assembly_record
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.design.task import GRAVITY


@dataclass(frozen=True)
class SolverOptions:
    """Knobs of :func:`optimize`."""

    rim_tilts_deg: tuple[float, ...] | None = None
    """Starts of the multi-start, tried in order: tilt of the outermost module of the starting bowl, degrees.
    The fold per connection is this tilt divided by the lattice radius of the assembly (at least 1/2), so a
    90-module assembly starts as shallow a bowl as a two-module V; a fixed fold compounds with distance and
    starts large assemblies nearly inverted (n = 90: 85 Ipopt iterations at a 3 degree fold, 994 at 20).
    ``None`` picks the order by size (:func:`default_rim_tilts`)."""
    max_starts_feasible: int = 2
    """Stop after this many starts have produced a verified feasible design."""
    pair_margin: float = 0.15
    """A module pair enters the NLP when its capsules are closer than ``2 r + pair_margin``, m."""
    max_rounds: int = 6
    """Re-solves allowed for activating pairs that came close."""
    max_iter: int = 3000
    """Ipopt iteration limit per solve."""
    first_pass_max_iter: int = 200
    first_pass_iter_per_module: int = 4
    """Every start first runs with at most ``max(first_pass_max_iter, first_pass_iter_per_module * n)``
    iterations; only if no start is feasible are the starts run again up to ``max_iter``. A start that converges
    slowly (n = 30: 486 iterations from one start, 61 from another) then cannot eat the time another start
    needs. Successful starts took about 3.5 n iterations in the benchmark (n = 90: 323), hence 4 per module."""
    tol: float = 1e-8
    """Ipopt convergence tolerance (scaled problem)."""
    free_yaw: bool = True
    """Optimize the body yaw (``False``: the paper's formulation, yaw fixed at 0)."""


@dataclass(frozen=True)
class Verification:
    """Checks made after the solve, in numpy, independently of the solver, over ALL module pairs."""

    max_wrench_residual: float
    """max_k |A u_k - b_k|_inf, N or N m."""
    max_bound_violation: float
    """Largest violation of 0 <= u <= u_max, rad^2/s^2."""
    max_angle_violation: float
    """Largest violation of |alpha| <= pi/2, rad."""
    min_capsule_distance: float
    """Smallest distance between any two capsule axes, m (``inf`` for one module)."""
    required_distance: float
    """2 r, m."""
    feasible: bool
    """All checks within tolerance: residual <= 1e-6 max(1, |b|), bounds <= 1e-6 u_max, distance >= 2r - 1e-6."""


@dataclass(frozen=True)
class StartReport:
    """What one start of the multi-start did."""

    rim_tilt_deg: float
    fold_deg: float
    status: str
    feasible: bool
    cost: float
    iterations: int
    wall_s: float


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
    """sum_k lambda_k |u_k|^2, (rad^2/s^2)^2."""
    status: str
    """Ipopt's return status of the chosen start, or why nothing was solved."""
    iterations: int
    """Ipopt iterations over all rounds of the chosen start."""
    wall_s: float
    """Wall time of the whole multi-start, s."""
    verification: Verification
    starts: tuple[StartReport, ...] = ()
    active_pairs: int = 0
    """Capsule pairs that entered the NLP for the chosen start."""

    @property
    def feasible(self) -> bool:
        return self.verification.feasible

    @property
    def n(self) -> int:
        return self.topology.n

    @property
    def assembly(self) -> Assembly:
        """The designed assembly (geometry only)."""
        return Assembly(self.topology, self.params, self.alpha, self.yaw)

    def record(self, task_name: str = "") -> dict:
        """Assembly-file record: the geometry plus the design's wrenches, inputs, cost, statistics, checks."""
        rec = assembly_record(self.assembly)
        rec.update({
            "status": self.status,
            "feasible": self.feasible,
            "cost": self.cost,
            "task": task_name,
            "wrenches": self.wrenches.tolist(),
            "weights": self.weights.tolist(),
            "u": self.u.tolist(),
            "solver": {"iterations": self.iterations, "wall_s": self.wall_s, "active_pairs": self.active_pairs,
                       "starts": [asdict(s) for s in self.starts]},
            "verification": asdict(self.verification),
        })
        return rec


def verify(topo: Topology, params: ModuleParams, alpha, yaw: float, u: np.ndarray,
           wrenches: np.ndarray) -> Verification:
    """Check a candidate design against the original constraints of eq. (opti), in numpy."""
    pos, rot = kin.module_frames(topo, np.asarray(alpha, float), params.l_c, yaw)
    a = kin.allocation_matrix(pos, rot, params)
    residual = float(np.max(np.abs(u @ a.T - wrenches))) if len(wrenches) else 0.0
    bound = float(max(0.0, -u.min(), u.max() - params.u_max))
    angle = float(max(0.0, np.max(np.abs(alpha)) - np.pi / 2))
    dist = kin.pairwise_capsule_distances(pos, rot, params)
    dmin = float(dist.min()) if topo.n > 1 else float("inf")
    scale = max(1.0, float(np.max(np.abs(wrenches)))) if len(wrenches) else 1.0
    ok = (residual <= 1e-6 * scale and bound <= 1e-6 * params.u_max and angle <= 1e-9
          and dmin >= 2 * params.r - 1e-6 and bool(np.all(np.isfinite(u))))
    return Verification(residual, bound, angle, dmin, 2 * params.r, ok)


# ---------------------------------------------------------------------------------------------------------------
# initial guesses

def fold_angles(topo: Topology, fold: float) -> np.ndarray:
    """Angles that raise every child module and tilt it toward its parent by ``fold`` rad, root levelled."""
    alpha = np.zeros(topo.n + 1)
    for k, (_child, _parent, connector) in enumerate(topo.bfs_tree()):
        t = kin.connector_vector(connector)
        probe = kin.rot_x(1.0) if kin.hinge_axis(connector) == "x" else kin.rot_y(1.0)
        # Positive angle tilts the child's axis along +(probe e3); "toward the parent" is along -t.
        sign = -np.sign((probe @ kin.E3) @ t)
        alpha[2 + k] = sign * fold
    pos, rot = kin.module_frames(topo, alpha, 1.0)
    m = np.mean([r @ kin.E3 for r in rot], axis=0)
    a1 = np.arctan2(-m[0], m[2])
    m2 = kin.rot_y(a1) @ m
    a0 = np.arctan2(m2[1], m2[2])
    alpha[0], alpha[1] = np.clip([a0, a1], -np.pi / 2, np.pi / 2)
    return alpha


def _principal_angle(points: np.ndarray) -> float | None:
    """Direction (rad, mod pi) of the largest spread of 2-D points about the origin; None when isotropic."""
    if len(points) == 0:
        return None
    cov = points.T @ points
    vals, vecs = np.linalg.eigh(cov)
    if vals[1] - vals[0] <= 1e-9 * max(vals[1], 1e-12):
        return None
    return float(np.arctan2(vecs[1, 1], vecs[0, 1]))


def task_yaw(topo: Topology, wrenches: np.ndarray) -> float:
    """Starting yaw that turns the assembly's long lattice axis toward the task's main lateral force direction.

    A fold only creates lateral force along the connections, so a task pushing along y needs the long axis of
    the assembly along y. The yaw gradient vanishes at a 90 degree mismatch, hence this initialization.
    """
    cells = np.asarray(topo.cells, dtype=float)
    structure = _principal_angle(cells - cells.mean(axis=0))
    lateral = _principal_angle(wrenches[:, :2])
    if structure is None or lateral is None:
        return 0.0
    return lateral - structure


def least_squares_inputs(a: np.ndarray, wrenches: np.ndarray, u_max: float) -> np.ndarray:
    """Minimum-norm inputs for every wrench, clipped to the bounds: the starting inputs."""
    return np.clip(wrenches @ np.linalg.pinv(a).T, 0.0, u_max)


# ---------------------------------------------------------------------------------------------------------------
# the NLP

class _Problem:
    """Symbolic model of eq. (opti) for one topology, lifted for a sparse Hessian.

    Module orientations ``R_i`` and positions ``p_i`` are variables tied by one kinematic equality per
    connection (``R_child = R_parent R_rel(alpha_e)``, ``p_child`` from :func:`kin.child_position`), like
    multiple shooting: every second derivative then couples only neighbouring modules, where the chained
    products of the direct formulation couple every angle with every other and make the Hessian dense and
    slow to build. The solution's angles are verified with the direct kinematics afterwards.
    """

    def __init__(self, topo: Topology, params: ModuleParams, wrenches: np.ndarray, weights: np.ndarray,
                 opts: SolverOptions) -> None:
        self.topo, self.params, self.opts = topo, params, opts
        n, k = topo.n, len(wrenches)
        self.n, self.k = n, k
        nmg = n * params.mass * GRAVITY
        row_scale = np.array([nmg] * 3 + [nmg * params.l_c] * 3)
        self.alpha = ca.SX.sym("alpha", n + 1)
        self.yaw = ca.SX.sym("yaw", 1 if opts.free_yaw else 0)
        self.rot = [ca.SX.sym(f"R{i}", 3, 3) for i in range(n)]
        self.pos = [ca.SX.sym(f"p{i}", 3) for i in range(n)]
        self.v = ca.SX.sym("v", 4 * n, k)
        yaw = self.yaw[0] if opts.free_yaw else 0.0
        kinematic = [ca.vec(self.rot[0] - kin.root_rotation(self.alpha[0], self.alpha[1], yaw, kin.CASADI)),
                     self.pos[0]]
        for e, (child, parent, connector) in enumerate(topo.bfs_tree()):
            rel = kin.relative_rotation(connector, self.alpha[2 + e], kin.CASADI)
            kinematic.append(ca.vec(self.rot[child] - self.rot[parent] @ rel))
            kinematic.append(self.pos[child] - kin.child_position(self.pos[parent], self.rot[parent],
                                                                  self.rot[child], connector, params.l_c, kin.CASADI))
        # The centroid is a variable of its own: substituting mean(p) would couple every module's position with
        # every other module's inputs and fill the Hessian.
        self.centroid = ca.SX.sym("centroid", 3)
        kinematic.append(self.centroid - sum(self.pos[1:], self.pos[0]) / n)
        offsets = [p - self.centroid for p in self.pos]
        moments = ca.DM(kin.module_moment_matrix(params))
        wrench_rows = []
        for j in range(k):
            force, torque = 0, 0
            for i in range(n):
                u_i = params.u_max * self.v[4 * i:4 * i + 4, j]
                z = self.rot[i][:, 2]
                thrust = params.c_f * ca.sum1(u_i)
                force = force + thrust * z
                torque = torque + thrust * ca.cross(offsets[i], z) + self.rot[i] @ (moments @ u_i)
            wrench_rows.append((ca.vertcat(force, torque) - wrenches[j]) / row_scale)
        self.g_eq = ca.vertcat(*kinematic, *wrench_rows)
        self.ends = [(o - params.capsule_a * r[:, 2], o - params.capsule_b * r[:, 2])
                     for o, r in zip(offsets, self.rot, strict=True)]
        self.cost = sum(float(weights[j]) * ca.sumsqr(self.v[:, j]) for j in range(k))

    def solve(self, alpha0, yaw0, v0, pairs, planes0, max_iter: int):
        """Solve with the given active pairs; ``planes0`` holds (w, c) starting values per pair."""
        r = self.params.r
        w = ca.SX.sym("w", 3, len(pairs))
        c = ca.SX.sym("c", len(pairs))
        g_pairs = []
        for idx, (i, j) in enumerate(pairs):
            wi, ci = w[:, idx], c[idx]
            for e in self.ends[i]:
                g_pairs.append(ca.dot(wi, e) - ci - r)
            for e in self.ends[j]:
                g_pairs.append(ci - ca.dot(wi, e) - r)
            g_pairs.append(1.0 - ca.sumsqr(wi))
        frames = [ca.vertcat(ca.vec(rr), pp) for rr, pp in zip(self.rot, self.pos, strict=True)]
        x = ca.vertcat(self.alpha, self.yaw, ca.vec(self.v), *frames, self.centroid, ca.vec(w), c)
        g = ca.vertcat(self.g_eq, *g_pairs)
        n_eq = self.g_eq.shape[0]
        lbg = np.zeros(n_eq + len(g_pairs))
        ubg = np.concatenate([np.zeros(n_eq), np.full(len(g_pairs), np.inf)])
        n_a, n_y, n_v = self.n + 1, self.yaw.shape[0], 4 * self.n * self.k
        # Natural bounds on the lifted variables keep Ipopt's steps sane: rotation entries lie in [-1, 1],
        # positions (relative to the root) within the chain's reach, plane normals in the unit ball and plane
        # offsets within reach of any capsule end.
        reach = 2.0 * self.params.l_c * self.n
        frame_hi = np.tile(np.concatenate([np.ones(9), np.full(3, reach)]), self.n)
        plane_hi = np.concatenate([np.ones(3 * len(pairs)), np.full(len(pairs), reach + self.params.capsule_b)])
        lbx = np.concatenate([np.full(n_a, -np.pi / 2), np.full(n_y, -4 * np.pi), np.zeros(n_v), -frame_hi,
                              np.full(3, -reach), -plane_hi])
        ubx = np.concatenate([np.full(n_a, np.pi / 2), np.full(n_y, 4 * np.pi), np.ones(n_v), frame_hi,
                              np.full(3, reach), plane_hi])
        pos, rot = kin.module_frames(self.topo, alpha0, self.params.l_c, yaw0)
        # Lifted positions are relative to the root module, not the centroid.
        frames0 = np.concatenate([np.concatenate([rr.ravel(order="F"), pp - pos[0]]) for rr, pp in zip(rot, pos,
                                                                                                       strict=True)])
        x0 = np.concatenate([alpha0, [yaw0][:n_y], np.ravel(v0, order="F"), frames0, -pos[0],
                             np.ravel(planes0[0], order="F"), planes0[1]])
        solver = ca.nlpsol("opti", "ipopt", {"x": x, "f": self.cost, "g": g}, {
            "ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
            "ipopt.max_iter": max_iter, "ipopt.tol": self.opts.tol,
            "ipopt.constr_viol_tol": 1e-9, "ipopt.mu_strategy": "adaptive",
        })
        sol = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        stats = solver.stats()
        xs = np.array(sol["x"]).ravel()
        alpha = xs[:n_a]
        yaw = float(xs[n_a]) if n_y else 0.0
        v = xs[n_a + n_y:n_a + n_y + n_v].reshape((4 * self.n, self.k), order="F")
        return alpha, yaw, v, stats["return_status"], int(stats["iter_count"])

    def endpoints(self, alpha, yaw) -> np.ndarray:
        """(3, 2n) numeric capsule end points for the angles (direct kinematics)."""
        pos, rot = kin.module_frames(self.topo, alpha, self.params.l_c, yaw)
        ends = kin.capsule_endpoints(pos, rot, self.params)
        return np.column_stack([e for pair in ends for e in pair])


def _planes(ends: np.ndarray, pairs, r: float):
    """Separating plane (w, c) starting values from the closest points of each pair's segments."""
    w = np.zeros((3, len(pairs)))
    c = np.zeros(len(pairs))
    for idx, (i, j) in enumerate(pairs):
        p0, p1, q0, q1 = ends[:, 2 * i], ends[:, 2 * i + 1], ends[:, 2 * j], ends[:, 2 * j + 1]
        _, s, t = kin.segment_distance(p0, p1, q0, q1)
        a, b = p0 + s * (p1 - p0), q0 + t * (q1 - q0)
        d = a - b
        if np.linalg.norm(d) < 1e-9:  # touching axes: separate along the line between module centres
            d = (p0 + p1) / 2 - (q0 + q1) / 2
            d[2] = 0.0
        d = d / max(np.linalg.norm(d), 1e-12)
        w[:, idx] = d
        c[idx] = d @ (a + b) / 2
    return w, c


def _close_pairs(ends: np.ndarray, n: int, threshold: float) -> set[tuple[int, int]]:
    out = set()
    for i in range(n):
        for j in range(i + 1, n):
            d = kin.segment_distance(ends[:, 2 * i], ends[:, 2 * i + 1], ends[:, 2 * j], ends[:, 2 * j + 1])[0]
            if d < threshold:
                out.add((i, j))
    return out


def _run_start(problem: _Problem, topo: Topology, params: ModuleParams, wrenches: np.ndarray, weights: np.ndarray,
               opts: SolverOptions, rim: float, radius: float, max_iter: int):
    """One start of the multi-start: bowl of rim tilt ``rim`` (deg), solve with pair activation rounds, verify."""
    t0 = time.perf_counter()
    threshold = 2 * params.r + opts.pair_margin
    fold = rim / radius
    alpha = fold_angles(topo, np.radians(fold))
    yaw = task_yaw(topo, wrenches) if opts.free_yaw else 0.0
    pos, rot = kin.module_frames(topo, alpha, params.l_c, yaw)
    v = least_squares_inputs(kin.allocation_matrix(pos, rot, params), wrenches, params.u_max).T / params.u_max
    ends = problem.endpoints(alpha, yaw)
    pairs = _close_pairs(ends, topo.n, threshold)
    iters, status = 0, "not solved"
    # unknowns: angles, yaw, inputs, lifted frames (R, p per module) and the centroid
    n_var = (topo.n + 1) + int(opts.free_yaw) + 4 * topo.n * len(wrenches) + 12 * topo.n + 3
    if problem.g_eq.shape[0] > n_var:
        # More equalities than unknowns (one module, several distinct wrenches): Ipopt refuses such
        # problems; the least-squares start is verified instead and is reported infeasible unless it fits.
        pairs, status, rounds = set(), "Not_Enough_Degrees_Of_Freedom", 0
    else:
        rounds = opts.max_rounds
    for _ in range(rounds):
        ordered = sorted(pairs)
        alpha, yaw, v, status, it = problem.solve(alpha, yaw, v, ordered, _planes(ends, ordered, params.r), max_iter)
        iters += it
        ends = problem.endpoints(alpha, yaw)
        new = _close_pairs(ends, topo.n, 2 * params.r + 0.5 * opts.pair_margin) - pairs
        if not new:
            break
        pairs |= new
    u = np.clip(v.T * params.u_max, 0.0, params.u_max)
    ver = verify(topo, params, alpha, yaw, u, wrenches)
    cost = float(np.sum(weights * np.sum(u * u, axis=1)))
    report = StartReport(rim, fold, status, ver.feasible, cost, iters, time.perf_counter() - t0)
    return (ver.feasible, -cost, alpha, yaw, u, status, iters, ver, len(pairs)), report


def default_rim_tilts(n: int) -> tuple[float, ...]:
    """Start order measured on the random-wrench sets (wall time of the whole multi-start, one core):
    20 degrees first for n = 30 took 2.9 / 8.1 / 6.5 s on three topologies against 23.8 / 5.7 / 5.5 s with
    10 first, and 20.5 vs 25.5 s at n = 60; at n = 90, 10 first took 76 s against 150 s. Larger assemblies
    want the shallower first bowl."""
    return (20.0, 10.0, 30.0, 5.0) if n <= 60 else (10.0, 20.0, 30.0, 5.0)


def lattice_radius(topo: Topology) -> float:
    """Largest distance of a module from the centroid, lattice units, at least 1/2."""
    cells = np.asarray(topo.cells, dtype=float)
    return max(0.5, float(np.max(np.linalg.norm(cells - cells.mean(axis=0), axis=1))))


def optimize(topo: Topology, params: ModuleParams, wrenches: np.ndarray, weights: np.ndarray | None = None,
             opts: SolverOptions | None = None) -> Design:
    """Optimize connector angles and inputs of ``topo`` for the wrench set; multi-start, verified in numpy."""
    opts = opts or SolverOptions()
    radius = lattice_radius(topo)
    wrenches = np.atleast_2d(np.asarray(wrenches, dtype=float))
    weights = np.ones(len(wrenches)) if weights is None else np.asarray(weights, dtype=float)
    t_start = time.perf_counter()
    problem = _Problem(topo, params, wrenches, weights, opts)
    best: tuple | None = None
    reports: list[StartReport] = []
    first_pass = max(opts.first_pass_max_iter, opts.first_pass_iter_per_module * topo.n)
    for max_iter in (min(first_pass, opts.max_iter), opts.max_iter):
        for rim in opts.rim_tilts_deg or default_rim_tilts(topo.n):
            candidate, report = _run_start(problem, topo, params, wrenches, weights, opts, rim, radius, max_iter)
            reports.append(report)
            if best is None or (candidate[0], candidate[1]) > (best[0], best[1]):
                best = candidate
            if sum(r.feasible for r in reports) >= opts.max_starts_feasible:
                break
        if any(r.feasible for r in reports) or max_iter >= opts.max_iter:
            break
    assert best is not None
    feasible, neg_cost, alpha, yaw, u, status, iters, ver, n_pairs = best
    return Design(topology=topo, params=params, wrenches=wrenches, weights=weights, alpha=np.asarray(alpha),
                  yaw=float(np.arctan2(np.sin(yaw), np.cos(yaw))), u=u, cost=-neg_cost, status=status,
                  iterations=iters, wall_s=time.perf_counter() - t_start, verification=ver,
                  starts=tuple(reports), active_pairs=n_pairs)
