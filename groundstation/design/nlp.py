"""The downwash-aware NLP of one topology (paper §IV-B, eq. opti), in CasADi, solved by Ipopt.

    min  sum_k lambda_k ||u_k||^2
    s.t. A(alpha, yaw) u_k = b_k,  0 <= u_k <= u_max,  -pi/2 <= alpha <= pi/2,
         dist(capsule axis i, capsule axis j) >= 2 r   for all module pairs i < j.

Reformulations (designs are verified against the original constraints in numpy afterwards, see ``optimize``):

* Inputs are scaled, ``v = u / u_max`` in [0, 1], and wrench rows by ``n m g`` (forces) and ``n m g l_c``
  (torques), which cuts Ipopt iterations about tenfold.
* Lifted kinematics: module orientations ``R_i`` and positions ``p_i`` (relative to the root) are variables tied
  by one equality per connection, like multiple shooting. Every second derivative then couples only neighbouring
  modules; the chained products of the direct formulation couple every angle with every other.
* The clearance between two segments is non-smooth (and degenerate for parallel capsules). It is replaced by an
  exact smooth equivalent from the separating-hyperplane theorem: segments S_i, S_j are at least ``d`` apart iff
  some ``w`` with ``|w| <= 1`` and ``c`` put both end points of S_i on ``w.x >= c + d/2`` and both of S_j on
  ``w.x <= c - d/2``. Solved for ``d = 2 r + clearance_margin`` so that the verified distance is at least
  ``2 r`` without a tolerance. The constraints use root-relative positions: separation is invariant under
  translation, and leaving the centroid out keeps every pair row sparse (with it, colouring the constraint
  Jacobian took 8.8 of the 9.6 s that building the n = 90 solver cost).
* Pairs are activated lazily (the ``pairs`` of :meth:`LiftedNlp.solve`; the caller adds pairs that came close
  and solves again): far pairs never enter the NLP.
* Two phases share one solver per pair set, selected by a parameter and the bounds of the wrench slacks ``s``:
  *feasibility* minimises ``|s|^2`` with ``(A u_k - b_k) / scale = s_k`` (constraint violation first, from any
  start), *cost* fixes ``s = 0`` and minimises the paper's cost. Ipopt drops fixed variables.
* A third phase, *bound*, asks for the least actuator bound instead of the least cost (the least-bound search,
  :func:`groundstation.design.optimize.least_bound`): the bound ``rho = u_max / params.u_max`` becomes a variable with
  ``v <= rho`` rows, ``s = 0`` as in the cost phase, and the objective is ``rho`` (plus the paper's cost at
  :data:`BOUND_REGULARIZATION`). Its solver adds only the variable and those rows, so the other two phases are
  untouched by it.
* Solvers are built once per (pair set, iteration cap, phase kind) and reused by every start and phase of the
  topology.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass

# Ipopt factorizes with MUMPS over the OpenBLAS that casadi bundles, loaded with the Ipopt plugin at the first
# solve. Its threads do not pay for these sparse systems: at n = 90 the same start took 10.5 s either way on an
# idle 2-core machine, but 21 s of CPU with threads against 15 s without, and a second core is not idle in a
# design sweep (one candidate per core) or on a shared machine. An explicit setting by the user wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import casadi as ca  # noqa: E402
import numpy as np

from groundstation.assembly import kinematics as kin
from groundstation.assembly.module import GRAVITY, ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.assembly.verification import SOLVER_BOUND_RELAXATION

FEASIBILITY = "feasibility"
COST = "cost"
BOUND = "bound"

Pairs = tuple[tuple[int, int], ...]

PHASE1_REGULARIZATION = 1e-6
"""Weight of the paper's cost in the feasibility phase. Without it the inputs are free along the wrench-meeting
manifold and the Hessian singular there: an n = 30 feasibility phase took 18-30 s at weight 1e-8 / 1e-10 and
1.9 s at 1e-6, whose pull on the inputs leaves a wrench violation of order 1e-6 n m g (the cost phase then
meets the wrenches exactly)."""
BOUND_REGULARIZATION = PHASE1_REGULARIZATION
"""Weight of the paper's cost (in ``v``, against the bound ``rho`` ~ 1) in the bound phase, for the same reason:
the inputs below the bound are otherwise free. Its pull on the bound is below rounding: on §IV-C every least bound
agreed to 7 digits with weight 0 and 1e-9."""


def ipopt_options(tol: float, max_iter: int) -> dict:
    """Options of every solver the NLP builds. ``constr_viol_tol`` is both Ipopt's tolerance on the equality
    constraints and the cap on how far it relaxes the variable bounds: :data:`SOLVER_BOUND_RELAXATION`, a tenth of
    the tolerance the verification accepts on the angle bounds."""
    return {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": max_iter,
            "ipopt.tol": tol, "ipopt.constr_viol_tol": SOLVER_BOUND_RELAXATION, "ipopt.mu_strategy": "adaptive"}


@dataclass(frozen=True)
class Layout:
    """The decision vector: its blocks in order and their sizes (the one place the order is written)."""

    n: int
    k: int
    yaw: int
    """1 with a free yaw, else 0."""
    pairs: int
    """Module pairs under clearance constraints."""
    bound: int
    """1 in the bound phase (the input bound is a variable), else 0."""

    @property
    def sizes(self) -> dict[str, int]:
        """Block sizes in order. ``frames``: per module its rotation (column-major) then its root-relative
        position; ``plane_w``: the separating planes' normals, column-major (3, pairs)."""
        n, k, p = self.n, self.k, self.pairs
        return {"alpha": n + 1, "yaw": self.yaw, "v": 4 * n * k, "slack": 6 * k, "frames": 12 * n, "centroid": 3,
                "plane_w": 3 * p, "plane_c": p, "bound": self.bound}

    def pack(self, **blocks) -> np.ndarray:
        """One vector from every block by name: arrays (flattened column-major) or scalars (repeated)."""
        out = []
        for name, size in self.sizes.items():
            block = np.ravel(blocks[name], order="F").astype(float)
            if np.ndim(blocks[name]) == 0:
                block = np.full(size, block[0])
            if block.size != size:
                raise ValueError(f"{name}: {block.size} values for a block of {size}")
            out.append(block)
        return np.concatenate(out)

    def unpack(self, x: np.ndarray) -> dict[str, np.ndarray]:
        out, at = {}, 0
        for name, size in self.sizes.items():
            out[name] = x[at:at + size]
            at += size
        return out


@dataclass(frozen=True)
class Solution:
    """One Ipopt solve of the lifted NLP, mapped back to the paper's variables."""

    alpha: np.ndarray
    """(n + 1,) root and connector angles, rad."""
    yaw: float
    """Body yaw, rad."""
    v: np.ndarray
    """(4n, K) scaled inputs ``u / u_max``."""
    status: str
    """Ipopt's return status."""
    iterations: int
    wall_s: float
    """Wall time of the solve, s (building the solver not included)."""
    function_s: float
    """Of which evaluating the NLP's functions and derivatives, s; the rest is Ipopt (mostly MUMPS)."""


class _StopCheck(ca.Callback):
    """Ipopt iteration callback: a nonzero return ends the solve with ``User_Requested_Stop``."""

    def __init__(self, sizes: dict[str, int], should_stop: Callable[[], bool]) -> None:
        ca.Callback.__init__(self)
        self.sizes, self.should_stop = sizes, should_stop
        self.construct("stop_check", {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "stop"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.sizes[ca.nlpsol_out(i)], 1)

    def eval(self, arg):
        return [1.0 if self.should_stop() else 0.0]


class LiftedNlp:
    """Symbolic model of eq. (opti) for one topology and wrench set, and its cached Ipopt solvers.

    ``should_stop`` is polled every Ipopt iteration; when it returns True the solve ends with
    ``User_Requested_Stop`` (see :mod:`groundstation.design.interrupt`)."""

    def __init__(self, topo: Topology, params: ModuleParams, wrenches: np.ndarray, weights: np.ndarray, *,
                 free_yaw: bool, clearance: float, tol: float, should_stop: Callable[[], bool] | None = None) -> None:
        self.topo, self.params, self.clearance, self.tol = topo, params, clearance, tol
        self.should_stop = should_stop
        n, k = topo.n, len(wrenches)
        self.n, self.k = n, k
        nmg = n * params.mass * GRAVITY
        row_scale = np.array([nmg] * 3 + [nmg * params.l_c] * 3)
        self.alpha = ca.SX.sym("alpha", n + 1)
        self.yaw = ca.SX.sym("yaw", 1 if free_yaw else 0)
        self.rot = [ca.SX.sym(f"R{i}", 3, 3) for i in range(n)]
        self.pos = [ca.SX.sym(f"p{i}", 3) for i in range(n)]
        self.v = ca.SX.sym("v", 4 * n, k)
        self.slack = ca.SX.sym("s", 6 * k)
        yaw = self.yaw[0] if free_yaw else 0.0
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
        # kin.module_wrench with symbolic inputs, not kin.allocation_matrix(...) @ u: the same numbers, but the
        # per-rotor graph solved the toy case only to Ipopt's acceptable level and took 1.6x the Ipopt time at
        # n = 30 (tried in issue 14).
        offsets = [p - self.centroid for p in self.pos]
        wrench_rows = []
        for j in range(k):
            force, torque = 0, 0
            for i in range(n):
                f, t = kin.module_wrench(offsets[i], self.rot[i], params.u_max * self.v[4 * i:4 * i + 4, j], params,
                                         kin.CASADI)
                force, torque = force + f, torque + t
            wrench_rows.append((ca.vertcat(force, torque) - wrenches[j]) / row_scale - self.slack[6 * j:6 * j + 6])
        self.g_eq = ca.vertcat(*kinematic, *wrench_rows)
        self.ends = kin.capsule_endpoints(self.pos, self.rot, params, kin.CASADI)
        self.phase = ca.SX.sym("phase", 2)
        cost = sum(float(weights[j]) * ca.sumsqr(self.v[:, j]) for j in range(k))
        self.objective = self.phase[0] * cost + self.phase[1] * ca.sumsqr(self.slack)
        self._solvers: dict[tuple[Pairs, int, bool], ca.Function] = {}
        self._callbacks: list[_StopCheck] = []
        self.build_s = 0.0
        """Wall time spent building solvers so far, s."""

    @property
    def unknowns(self) -> int:
        """Variables of the cost phase: angles, yaw, inputs, lifted frames and the centroid."""
        sizes = self._layout((), False).sizes
        return sum(sizes[name] for name in ("alpha", "yaw", "v", "frames", "centroid"))

    @property
    def equalities(self) -> int:
        return int(self.g_eq.shape[0])

    def _solver(self, pairs: Pairs, max_iter: int, bound: bool) -> ca.Function:
        key = (pairs, max_iter, bound)
        if key not in self._solvers:
            t0 = time.perf_counter()
            half = self.clearance / 2
            w = ca.SX.sym("w", 3, len(pairs))
            c = ca.SX.sym("c", len(pairs))
            g_pairs = []
            for idx, (i, j) in enumerate(pairs):
                wi, ci = w[:, idx], c[idx]
                g_pairs += [ca.dot(wi, e) - ci - half for e in self.ends[i]]
                g_pairs += [ci - ca.dot(wi, e) - half for e in self.ends[j]]
                g_pairs.append(1.0 - ca.sumsqr(wi))
            rho = ca.SX.sym("rho", int(bound))
            frames = ca.vertcat(*[ca.vertcat(ca.vec(rr), pp) for rr, pp in zip(self.rot, self.pos, strict=True)])
            symbols = {"alpha": self.alpha, "yaw": self.yaw, "v": ca.vec(self.v), "slack": self.slack,
                       "frames": frames, "centroid": self.centroid, "plane_w": ca.vec(w), "plane_c": c,
                       "bound": rho}
            x = ca.vertcat(*(symbols[name] for name in self._layout(pairs, bound).sizes))
            g_bound = [rho[0] - ca.vec(self.v)] if bound else []
            g = ca.vertcat(self.g_eq, *g_pairs, *g_bound)
            f = self.objective + rho[0] if bound else self.objective
            options = ipopt_options(self.tol, max_iter)
            if self.should_stop is not None:
                sizes = {"x": x.shape[0], "f": 1, "g": g.shape[0], "lam_x": x.shape[0], "lam_g": g.shape[0],
                         "lam_p": self.phase.shape[0]}
                options["iteration_callback"] = _StopCheck(sizes, self.should_stop)
                self._callbacks.append(options["iteration_callback"])  # CasADi does not own Python callbacks
            self._solvers[key] = ca.nlpsol("opti", "ipopt", {"x": x, "f": f, "g": g, "p": self.phase}, options)
            self.build_s += time.perf_counter() - t0
        return self._solvers[key]

    def solve(self, phase: str, alpha0: np.ndarray, yaw0: float, v0: np.ndarray, pairs: Pairs,
              max_iter: int) -> Solution:
        """One solve from the given start, the module ``pairs`` under clearance constraints. The bound phase
        lifts the inputs' upper bound 1 and starts its bound variable at the largest of ``v0``."""
        bound = phase == BOUND
        solver = self._solver(pairs, max_iter, bound)
        layout, n, n_p = self._layout(pairs, bound), self.n, len(pairs)
        # Natural bounds on the lifted variables keep Ipopt's steps sane: rotation entries lie in [-1, 1],
        # positions (relative to the root) within the chain's reach, plane normals in the unit ball and plane
        # offsets within reach of any capsule end.
        reach = 2.0 * self.params.l_c * n
        frame_hi = np.tile(np.concatenate([np.ones(9), np.full(3, reach)]), n)
        slack_hi = np.inf if phase == FEASIBILITY else 0.0
        v_hi = np.inf if bound else 1.0
        lbx = layout.pack(alpha=-np.pi / 2, yaw=-4 * np.pi, v=0.0, slack=-slack_hi, frames=-frame_hi,
                          centroid=-reach, plane_w=-1.0, plane_c=-(reach + self.params.capsule_b), bound=0.0)
        ubx = layout.pack(alpha=np.pi / 2, yaw=4 * np.pi, v=v_hi, slack=slack_hi, frames=frame_hi,
                          centroid=reach, plane_w=1.0, plane_c=reach + self.params.capsule_b, bound=np.inf)
        pos, rot = kin.module_frames(self.topo, alpha0, self.params.l_c, yaw0)
        rel = [p - pos[0] for p in pos]  # the lifted positions are relative to the root module
        frames0 = np.concatenate([np.concatenate([r.ravel(order="F"), p]) for r, p in zip(rot, rel, strict=True)])
        planes_w, planes_c = separating_planes(capsule_ends(rel, rot, self.params), pairs)
        x0 = layout.pack(alpha=alpha0, yaw=np.array([yaw0])[:layout.yaw], v=v0, slack=0.0, frames=frames0,
                         centroid=-pos[0], plane_w=planes_w, plane_c=planes_c, bound=np.max(v0))
        n_eq, n_in = self.equalities, 5 * n_p + (v0.size if bound else 0)
        t0 = time.perf_counter()
        weights = {COST: [1.0, 0.0], FEASIBILITY: [PHASE1_REGULARIZATION, 1.0], BOUND: [BOUND_REGULARIZATION, 0.0]}
        sol = solver(x0=np.clip(x0, lbx, ubx), lbx=lbx, ubx=ubx, p=weights[phase],
                     lbg=np.zeros(n_eq + n_in), ubg=np.concatenate([np.zeros(n_eq), np.full(n_in, np.inf)]))
        wall = time.perf_counter() - t0
        stats = solver.stats()
        xs = layout.unpack(np.array(sol["x"]).ravel())
        return Solution(alpha=xs["alpha"], yaw=float(xs["yaw"][0]) if layout.yaw else 0.0,
                        v=xs["v"].reshape((4 * n, self.k), order="F"),
                        status=str(stats["return_status"]), iterations=int(stats["iter_count"]), wall_s=wall,
                        function_s=sum(v for k, v in stats.items() if k.startswith("t_wall_")))

    def _layout(self, pairs: Pairs, bound: bool) -> Layout:
        return Layout(self.n, self.k, self.yaw.shape[0], len(pairs), int(bound))


def capsule_ends(positions, rotations, params: ModuleParams) -> np.ndarray:
    """(3, 2n) capsule axis end points, columns ``2i`` and ``2i + 1`` for module ``i`` (numpy)."""
    ends = kin.capsule_endpoints(positions, rotations, params)
    return np.column_stack([e for pair in ends for e in pair])


def _pair_segments(ends: np.ndarray, pairs) -> tuple[np.ndarray, ...]:
    """End points ``p0, p1`` (first module) and ``q0, q1`` (second) of each pair's capsule axes, ``(m, 3)`` each."""
    i, j = np.asarray(pairs, dtype=int).reshape(-1, 2).T
    return ends[:, 2 * i].T, ends[:, 2 * i + 1].T, ends[:, 2 * j].T, ends[:, 2 * j + 1].T


def separating_planes(ends: np.ndarray, pairs: Pairs) -> tuple[np.ndarray, np.ndarray]:
    """Separating plane (w, c) starting values from the closest points of each pair's segments."""
    p0, p1, q0, q1 = _pair_segments(ends, pairs)
    _, s, t = kin.segment_distances(p0, p1, q0, q1)
    a, b = p0 + s[:, None] * (p1 - p0), q0 + t[:, None] * (q1 - q0)
    d = a - b
    touching = np.linalg.norm(d, axis=1) < 1e-9  # touching axes: separate along the line between module centres
    d[touching] = ((p0 + p1) / 2 - (q0 + q1) / 2)[touching] * np.array([1.0, 1.0, 0.0])
    d = d / np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]
    return d.T, np.einsum("ij,ij->i", d, (a + b) / 2)


def close_pairs(ends: np.ndarray, threshold: float) -> set[tuple[int, int]]:
    """Module pairs whose capsule axes are closer than ``threshold``, m."""
    pairs = np.column_stack(np.triu_indices(ends.shape[1] // 2, 1))
    dist = kin.segment_distances(*_pair_segments(ends, pairs))[0]
    return {(int(i), int(j)) for (i, j), d in zip(pairs, dist, strict=True) if d < threshold}
