"""Enumeration of non-isomorphic configurations (paper §III): exhaustive, and sampled (Algorithm 1).

Level ``n + 1`` is grown from level ``n`` by attaching a module at every free connector of every configuration
kept at level ``n`` and keeping one representative per isomorphism class. The paper's "available
configurations" is the number of such attachments. With sampling, when a level has more than ``N_n`` classes,
``N_n`` of them are drawn without replacement and only those grow further.
"""

from __future__ import annotations

import resource
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from groundstation.assembly.lattice import group_matrices
from groundstation.assembly.topology import Topology
from groundstation.choices import SAMPLING_SCHEMES
from groundstation.design import kernels
from groundstation.design.interrupt import run_interruptible
from groundstation.errors import UsageError

Scheme = Literal["compact", "uniform", "spread"]
SCHEMES = SAMPLING_SCHEMES


@dataclass(frozen=True)
class SamplingPolicy:
    """How to thin a level that has more than ``keep`` classes (paper §III-B, Algorithm 1)."""

    keep: int
    """``N_n``: configurations kept per level, at least 1."""
    sigma: float = 1.0
    """``sigma_n`` of the Gaussian weight on the radius of gyration, lattice units (module pitch, ``2 l_c``)."""
    scheme: Scheme = "compact"
    """``compact`` favours small radius of gyration (the paper's choice), ``spread`` large ones (the paper's
    reversed scheme, ``g_0 = max g``), ``uniform`` weighs all equally."""
    seed: int = 0
    """Seed of the random generator; the same seed gives the same draw."""

    def __post_init__(self) -> None:
        if self.keep < 1:
            raise UsageError(f"sample size N_n must be at least 1, got {self.keep}")
        if not self.sigma > 0:
            raise UsageError(f"sigma must be positive, got {self.sigma}")
        if self.scheme not in SCHEMES:
            raise UsageError(f"unknown sampling scheme {self.scheme!r}; choose one of {', '.join(SCHEMES)}")


@dataclass(frozen=True, eq=False)
class Level:
    """The configurations of one level ``n`` and what it cost to find them."""

    n: int
    """Number of modules."""
    available: int
    """Candidates generated (attachments at free connectors of the previous level's kept configurations)."""
    non_isomorphic: int
    """Distinct isomorphism classes found among the candidates (before any sampling)."""
    cpu_s: float
    """Process CPU time spent on this level, seconds."""
    peak_rss_mb: float
    """Peak resident memory of the process so far, MiB."""
    cells_x: np.ndarray = field(repr=False)
    """``(kept, n)`` lattice x of each module, canonical placement."""
    cells_y: np.ndarray = field(repr=False)
    """``(kept, n)`` lattice y of each module, canonical placement."""
    parent: np.ndarray = field(repr=False)
    """``(kept, n)`` parent module index (``-1`` for module 0); the tree's edges are ``(parent[k], k)``."""

    @property
    def kept(self) -> int:
        """Configurations kept at this level (``non_isomorphic`` unless sampled)."""
        return int(self.cells_x.shape[0])

    def topology(self, index: int) -> Topology:
        return Topology.from_arrays(self.cells_x[index], self.cells_y[index], self.parent[index])

    def topologies(self) -> list[Topology]:
        return [self.topology(i) for i in range(self.kept)]

    def radii_of_gyration(self) -> np.ndarray:
        """Radius of gyration of every kept configuration, lattice units."""
        return radii_of_gyration(self.cells_x, self.cells_y)


def radii_of_gyration(cells_x: np.ndarray, cells_y: np.ndarray) -> np.ndarray:
    """Radius of gyration ``g_m`` of each row of module centres (paper §III-B), lattice units."""
    x = cells_x.astype(float)
    y = cells_y.astype(float)
    dx = x - x.mean(axis=1, keepdims=True)
    dy = y - y.mean(axis=1, keepdims=True)
    return np.sqrt(np.mean(dx * dx + dy * dy, axis=1))


def sample_indices(g: np.ndarray, policy: SamplingPolicy, rng: np.random.Generator) -> np.ndarray:
    """Draw ``policy.keep`` indices without replacement, ``P_m`` proportional to the Gaussian weight ``w_m``.

    Successive weighted sampling without replacement is done with the Gumbel-top-k trick in log space
    (``argmax`` of ``log w + Gumbel`` noise), which draws from exactly the same distribution as drawing one at a
    time and renormalizing, and never underflows for weights far below ``exp(-745)``.
    """
    if policy.scheme == "uniform":
        log_w = np.zeros_like(g)
    else:
        g0 = g.min() if policy.scheme == "compact" else g.max()
        # Scaled before squaring: sigma**2 overflowed a float from sigma 1e155 (hostile campaign 32). A tiny sigma
        # gives the far ones -inf: drawn last, as their weights say.
        with np.errstate(over="ignore"):
            z = (g - g0) / policy.sigma
            log_w = -0.5 * z * z
    keys = log_w + rng.gumbel(size=g.shape)
    chosen = np.argpartition(-keys, policy.keep - 1)[: policy.keep]
    return np.sort(chosen)


def enumerate_levels(
    n_max: int,
    symmetry: str = "C4",
    sampling: SamplingPolicy | None = None,
    on_level: Callable[[Level], None] | None = None,
) -> Iterator[Level]:
    """Yield levels ``n = 1 .. n_max``; exhaustive unless ``sampling`` is given.

    ``on_level`` is called after each level (for progress display). Memory is that of two levels at a time.
    The kernels run on a worker thread (:func:`~groundstation.design.interrupt.run_interruptible`): Ctrl-C stops
    the enumeration at once with ``KeyboardInterrupt``, the levels yielded before it complete.
    """
    if n_max < 1:
        raise UsageError(f"number of modules must be at least 1, got {n_max}")
    if n_max > 120:
        raise UsageError(f"number of modules must be at most 120 (lattice coordinates are int16), got {n_max}")
    mats = group_matrices(symmetry)
    compile_kernels()
    rng = np.random.default_rng(sampling.seed) if sampling is not None else None

    t0 = time.process_time()
    level = Level(
        n=1, available=1, non_isomorphic=1, cpu_s=time.process_time() - t0, peak_rss_mb=_peak_rss_mb(),
        cells_x=np.zeros((1, 1), np.int16), cells_y=np.zeros((1, 1), np.int16),
        parent=np.full((1, 1), -1, np.int16),
    )
    for n in range(1, n_max + 1):
        if n > 1:
            t0 = time.process_time()
            hint = int(level.kept * 2 * n / len(mats)) + 16
            available, cx, cy, par = run_interruptible(_grow, level.cells_x, level.cells_y, level.parent, mats, hint)
            distinct = cx.shape[0]
            if sampling is not None and distinct > sampling.keep:
                assert rng is not None
                keep = sample_indices(radii_of_gyration(cx, cy), sampling, rng)
                cx, cy, par = cx[keep], cy[keep], par[keep]
            level = Level(
                n=n, available=int(available), non_isomorphic=int(distinct),
                cpu_s=time.process_time() - t0, peak_rss_mb=_peak_rss_mb(),
                cells_x=cx, cells_y=cy, parent=par,
            )
        if on_level is not None:
            on_level(level)
        yield level


def _grow(cells_x: np.ndarray, cells_y: np.ndarray, parent: np.ndarray, mats: np.ndarray, hint: int):
    """The next level of a level's configurations: ``(available, cells_x, cells_y, parent)`` of its distinct
    children, in canonical placement (both kernels, on one worker thread)."""
    available, _codes, src = kernels.expand_level(cells_x, cells_y, parent, mats, hint)
    del _codes
    return (available, *kernels.materialize_children(cells_x, cells_y, parent, src, mats))


_compiled = False


def compile_kernels() -> None:
    """Compile or load the kernels once, outside any timed level. numba caches the machine code on disk next to
    the sources: the first run on a machine compiles (7-12 s), later ones load it (0.3 s); on a worker thread,
    so Ctrl-C stops it at once too."""
    global _compiled
    if not _compiled:
        one = np.zeros((1, 1), np.int16)
        run_interruptible(_grow, one, one, np.full((1, 1), -1, np.int16), group_matrices("C4"), 16)
        _compiled = True


def _peak_rss_mb() -> float:
    # ru_maxrss is in KiB on Linux.
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
