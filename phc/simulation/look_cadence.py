"""How often the singularity monitor looks inside IDA's step loop (:class:`phc.simulation.ida._StepHook`).

The monitor (:mod:`phc.simulation.monitor`) looks every `cadence` steps. What it finds sets the
cadence, as before: back to the base cadence (10 or 20 steps) as soon as the conditioning ratio
moves, stretched up to :data:`LOOK_STRETCH`-fold while it stays flat and far above the threshold.

What a look costs sets it too (issue 38). A look at a model above the monitor's dense size is a
sparse LU, a condition estimate and an inverse iteration; at the 1000-element Euler–Bernoulli beam
(8007 unknowns) one look cost what some 30 of IDA's steps cost, and looking every 20 steps more
than doubled the run. The hook counts the work of its looks and of IDA's steps between them
(:class:`LookBudget`) and looks no more often than keeps the looks at :data:`LOOK_SHARE` of the
integration — unless the ratio is falling toward the threshold: then it looks at least
:data:`APPROACH_LOOKS` times before the ratio, falling as fast as it fell since the last look,
would reach the threshold (but never more often than the base cadence), and within
:data:`NEAR_DECADES` of the threshold at the base cadence, whatever a look costs. The threshold
itself (what a look decides) does not change; only when looks happen.

The work is counted, not timed (issue 38/34). A look's work comes from what it did: a sparse
look's from its matrix's nonzeros, its LU's (:func:`sparse_lu_flops`, the factors' nonzeros) and
the solves and products it made; a dense look's from N. IDA's work between two looks comes from
IDA's own counters: its residual evaluations (each a Newton iteration: a residual and a solve with
the factors), its Jacobian evaluations (each a factorization, of the fill the monitor's LU of the
same matrix found) and its steps. Both are weighed by a fixed work model in nominal nanoseconds
(:class:`LookWork`, :func:`integration_work`), so the cadence is a function of the run's own
counters: the same run looks at the same steps on any machine and under any load. The timed
cadence did not: on a busy machine a slow look made the next ones rarer (on the N = 1 four-bar at
rtol = atol = 1e-6 a stretched cadence moved the bridges and IDA's error from 6.2e-5 to 2.1e-4
rad). The work bound still applies to sparse looks only (above the monitor's ``DENSE_SIZE``): a
dense look weighs one or two of IDA's steps, and stretching the base cadence of 10 there moved
that run's bridges as well.
"""

from __future__ import annotations

import math
import sys
from typing import Optional

LOOK_STRETCH = 32
"""Most the singularity monitor's cadence is stretched where the conditioning is flat."""
FLAT_DECADES = 0.1
"""Change of the conditioning ratio between two looks (decades) below which it counts as flat."""
FAR_RATIO = 1e-6
"""Conditioning ratio above which the monitor may look less often (its threshold is 1e-11)."""
LOOK_SHARE = 0.1
"""Share of the integration's work (:func:`integration_work`) the monitor's looks may take where
the conditioning ratio is not falling toward the threshold."""
APPROACH_LOOKS = 4
"""Looks at least this many before a falling ratio, at the rate it fell since the last look, would
reach the threshold (a falling ratio brings the cadence back toward its base)."""
NEAR_DECADES = 2.0
"""Within this many decades of the threshold the monitor looks at the base cadence, whatever a
look costs."""


def next_cadence(cadence: int, base: int, before: Optional[float], ratio: Optional[float]) -> int:
    """Steps until the monitor's next look by what it found: 1.5× longer (up to
    :data:`LOOK_STRETCH`× `base`) when the ratio moved less than :data:`FLAT_DECADES` since the
    last look and stays above :data:`FAR_RATIO`, else back to `base` at once (:func:`cadence_after`;
    None: no look yet)."""
    return cadence_after(cadence, base, math.nan if before is None else float(before),
                         math.nan if ratio is None else float(ratio))


# The functions below are what the native IDA driver's routine look decides in C (phc/codegen/c_runtime/
# ida_driver.c: phc.codegen.c_ida translates them with phc.codegen.c_translate, in the subset it reads;
# NaN stands for "no look yet"); the Python step hook (phc.simulation.ida._StepHook) and the
# monitor (phc.simulation.monitor.SingularityMonitor.watch) call them too.

C_SIGNATURES = {"cadence_after": (("i", "i", "f", "f"), ("i",)),
                "brackets_minimum": (("f", "f", "f", "f", "f", "f"), ("b",)),
                "crawls": (("f", "f", "f", "i", "i", "i"), ("b",)),
                "hermite": (("f", "v", "v", "f", "v", "v", "f", "v", "v"), ()),
                "golden_search": (("ws", "f", "f", "f", "i", "f", "f", "b"), ("i", "f", "f"))}
"""The C kinds of the translated functions' arguments and results (:mod:`phc.codegen.c_translate`)."""

GOLDEN = 0.5 * (math.sqrt(5.0) - 1.0)
"""The golden section's ratio (:func:`golden_search`)."""
EPSILON = sys.float_info.epsilon
"""Double precision's machine epsilon."""
MINIMUM_XTOL = 1e-4
"""Relative width of the bracket at which :func:`golden_search` with `minimum` stops."""
SEARCH_ITERATIONS = 80
"""Most iterations of the monitor's search for a minimum between its looks."""


def cadence_after(cadence: int, base: int, before: float, ratio: float) -> int:
    """:func:`next_cadence` on numbers: `before` and `ratio` NaN where there is no look."""
    if not (ratio > FAR_RATIO and before > FAR_RATIO):
        return base
    if abs(math.log10(ratio / before)) >= FLAT_DECADES:
        return base
    return min(LOOK_STRETCH * base, max(cadence + 1, int(1.5 * cadence)))


def brackets_minimum(t0: float, r0: float, t1: float, r1: float, t2: float, r2: float) -> bool:
    """Whether the monitor's last three looks, at times t0, t1, t2 with conditioning ratios r0, r1,
    r2, bracket a local minimum of the conditioning (the middle one the lowest, the times
    increasing): the monitor then searches between them
    (:meth:`~phc.simulation.monitor.SingularityMonitor.watch`). False where a ratio is NaN."""
    return r1 < r0 and r1 < r2 and t0 < t1 and t1 < t2


def crawls(h: float, t: float, t_end: float, steps: int, max_steps: int, next_check: int) -> bool:
    """Whether IDA, at `steps` steps at t with steps of h, crawls: at this step size it cannot
    reach `t_end` within `max_steps`; asked from the step `next_check` on (the IDA step hook's
    crawl check, :class:`phc.simulation.ida._StepHook`)."""
    return steps >= next_check and h * (max_steps - steps) < t_end - t


def affordable_cadence(cadence: int, base: int, *, look_work: float, step_work: float, before: Optional[float],
                       ratio: Optional[float], steps: int, threshold: float) -> int:
    """`cadence` (from :func:`next_cadence`) lengthened so that a look costing `look_work` takes at
    most :data:`LOOK_SHARE` of the integration of the steps between two looks (`step_work` a step),
    while the ratio cannot reach `threshold` before the next look: at least
    :data:`APPROACH_LOOKS` looks before a ratio falling as from `before` to `ratio` over the last
    `steps` steps would reach it; none of this within :data:`NEAR_DECADES` of it, nor before the
    second look (`before` None)."""
    if ratio is None or before is None or not (look_work > 0 and step_work > 0) or not ratio > 0:
        return cadence  # (two looks at least: how the ratio moves is known)
    afford = math.ceil(look_work / (LOOK_SHARE * step_work))
    if afford <= cadence:
        return cadence
    decades = math.log10(ratio / threshold)  # how far the ratio is from the threshold
    if decades <= NEAR_DECADES:
        return cadence
    if before is not None and before > ratio and steps > 0:
        fall = math.log10(before / ratio) / steps  # decades a step, at the last interval's rate
        afford = min(afford, int(decades / (APPROACH_LOOKS * fall)))
    return max(cadence, base, afford)


def _copy(src, dst):
    dst[...] = src


def hermite(ta, ya, ypa, tb, yb, ypb, t, y, yp) -> None:
    """(y, ẏ) at t on the cubic Hermite interpolant through the looks (ta, ya, ẏa) and (tb, yb, ẏb),
    into y and yp: the states the monitor's search between its looks looks at
    (:meth:`phc.simulation.monitor.SingularityMonitor._state_at`)."""
    d = tb - ta
    s = (t - ta) / d
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    _copy(h00 * ya + h10 * d * ypa + h01 * yb + h11 * d * ypb, y)
    dh00 = 6 * s**2 - 6 * s
    dh10 = 3 * s**2 - 4 * s + 1
    dh01 = -6 * s**2 + 6 * s
    dh11 = 3 * s**2 - 2 * s
    _copy((dh00 * ya + dh01 * yb) / d + dh10 * ypa + dh11 * ypb, yp)


def golden_search(ws, a, b, threshold, iterations, fa, fb, minimum):
    """``(found, t, ratio)``: where the monitor's conditioning ratio falls below `threshold` on
    [a, b], by golden-section search for its minimum — found 1 at the first point found below (with
    `minimum`: the least point found once the bracket is :data:`MINIMUM_XTOL` of its place), 0 where
    it stays above, -1 where the operation ``_ratio_at_time(ws, t) -> (ratio, below, unknown)``
    cannot tell (the native IDA driver's estimate, which does not clear a point: Python's monitor
    then searches itself). `fa`, `fb`: the ratios at a and b (NaN: unknown). What it stops at:
    :func:`phc.simulation.monitor._search_below`, which runs it with the monitor's ratio."""
    g = GOLDEN
    c = b - g * (b - a)
    d = a + g * (b - a)
    fc, bc, xc = _ratio_at_time(ws, c)  # noqa: F821 — the caller's operation
    if xc:
        return -1, 0.0, 0.0
    fd, bd, xd = _ratio_at_time(ws, d)  # noqa: F821
    if xd:
        return -1, 0.0, 0.0
    found = False
    best_t = 0.0
    best_r = 0.0
    for k in range(iterations):
        if bc:
            if not minimum:
                return 1, c, fc
            if not found or fc < best_r:
                found = True
                best_t = c
                best_r = fc
        if bd:
            if not minimum:
                return 1, d, fd
            if not found or fd < best_r:
                found = True
                best_t = d
                best_r = fd
        if b - a <= 4 * EPSILON * max(abs(a), abs(b)):
            break
        if found and b - a <= MINIMUM_XTOL * max(abs(a), abs(b)):
            break
        if k >= 4 and fa == fa and fb == fb and a < c and c < d and d < b:  # (NaN: fa, fb unknown)
            slope = max(abs(fc - fa) / (c - a), abs(fd - fc) / (d - c), abs(fb - fd) / (b - d))
            if min(fc, fd) - 2.0 * slope * (b - a) > threshold:
                break
        if fc < fd:
            fb = fd
            b = d
            d = c
            fd = fc
            bd = bc
            c = b - g * (b - a)
            fc, bc, xc = _ratio_at_time(ws, c)  # noqa: F821
            if xc:
                return -1, 0.0, 0.0
        else:
            fa = fc
            a = c
            c = d
            fc = fd
            bc = bd
            d = a + g * (b - a)
            fd, bd, xd = _ratio_at_time(ws, d)  # noqa: F821
            if xd:
                return -1, 0.0, 0.0
    return (1 if found else 0), best_t, best_r


def run_golden_search(ratio_at_time, a, b, threshold, iterations, fa, fb, minimum):
    """:func:`golden_search` in Python, its operation ``_ratio_at_time`` the callable `ratio_at_time`."""
    import types

    search = types.FunctionType(golden_search.__code__, {**globals(), "_ratio_at_time": ratio_at_time},
                                golden_search.__name__)
    return search(None, a, b, threshold, iterations, fa, fb, minimum)


# The work model: nominal nanoseconds, fixed numbers (calibrated once, on an x86-64 machine, on the
# N = 10 four-bar and the Euler–Bernoulli beam of 30 and 200 elements: looks of 2–8 ms, steps of
# 0.1–0.3 ms). They only weigh a look against a step; the cadence they give is the same on any
# machine, and a machine twice as fast at factorizations gives the same looks.
LOOK_NS = 2.0e6
"""A sparse look's fixed part: the Python and SciPy calls of its assembly, equilibration, LU and
condition estimate (the look at the N = 10 four-bar, 163 unknowns, took 1.9–3.3 ms)."""
DENSE_LOOK_NS = 1.0e5
"""A dense look's fixed part (NumPy's and LAPACK's calls on a small matrix)."""
ASSEMBLE_NS = 150.0
"""A sparse look's assembly and equilibration, per nonzero of the Jacobian."""
FACTOR_NS = 100.0
"""A sparse LU's analysis (ordering, symbolic work), per nonzero of its factors."""
SOLVE_CALL_NS, SOLVE_NS = 15e3, 10.0
"""A solve with SciPy's sparse LU: its call, and per nonzero of the factors."""
PRODUCT_CALL_NS, PRODUCT_NS = 10e3, 5.0
"""A product with the sparse iteration matrix: its call, and per nonzero."""
FLOP_NS = 1.0
"""A floating-point operation of a factorization (sparse: :func:`sparse_lu_flops`; dense: LAPACK's)."""
STEP_NS = 1.0e5
"""An IDA step's fixed part: the step hook and scikit-sundae's wrapping of the step (the pendulum's
steps took ~0.1 ms in all)."""
VECTOR_NS = 50.0
"""An IDA step's vector work (BDF's history, prediction, error test, norms), per unknown."""
CALLBACK_NS = 2.0e4
"""A residual or Jacobian evaluation IDA asks of phc: the call through scikit-sundae into Python."""
EVALUATION_NS = 2.0
"""The generated residual or Jacobian, per nonzero of the Jacobian."""
C_SOLVE_NS = 2.0
"""A solve with IDA's own factors (in C), per nonzero of the factors (dense: n² of them)."""


def sparse_lu_flops(lu) -> tuple[float, int]:
    """Floating-point operations of a sparse LU (SciPy's ``SuperLU``) whose factors are L (unit
    diagonal stored) and U (CSC), and the factors' nonzeros: a multiplier for each nonzero of L
    below the diagonal, and for pivot k an update of each pair (entry of L's column k below it,
    entry of U's row k right of it), two operations. Each of ``lu.L`` and ``lu.U`` is a copy of
    its factor: they are read one at a time (a mesh's factors are its look's largest arrays)."""
    import numpy as np

    L = lu.L
    below, nnz = np.diff(L.indptr) - 1, int(L.nnz)  # L's column counts below the diagonal
    del L
    U = lu.U
    right = np.bincount(U.indices, minlength=U.shape[0]) - 1  # U's row counts right of the diagonal
    nnz += int(U.nnz)
    del U
    return float(below.sum() + 2.0 * np.dot(below.astype(float), np.maximum(right, 0))), nnz


class LookWork:
    """The work of the singularity monitor's looks (:attr:`work`, over the run, in the nominal
    nanoseconds of the work model above: counted, never timed), and the figures of its last
    sparse LU, which stand for IDA's own factorization of the same iteration matrix
    (:attr:`lu_flops`, :attr:`lu_nnz`).

    Only IDA's step hook reads them (:class:`phc.simulation.ida._StepHook`). Without `factors`
    (the fixed-step solvers' monitors) a sparse look's LU is charged as an LU without fill and its
    factors are not read: counting them copies each factor (:func:`sparse_lu_flops`), and at a
    mesh of 10⁵ elements those copies were the largest arrays of the run's peak."""

    def __init__(self, factors: bool = True):
        self.factors = factors
        self.work = 0.0
        self.lu_flops: Optional[float] = None
        self.lu_nnz: Optional[int] = None

    def dense(self, n: int, *, svd: int = 0, vectors: bool = False) -> None:
        """A dense look at n unknowns: the Jacobian, its equilibration, LAPACK's LU and condition
        estimate, and `svd` singular value decompositions (with `vectors`: one of them with them)."""
        flops = 2.0 * n ** 3 / 3 + 30.0 * n * n + svd * 4.0 * n ** 3 + (8.0 * n ** 3 if vectors else 0.0)
        self.work += DENSE_LOOK_NS + FLOP_NS * flops

    def sparse(self, nnz: int, *, lu=None, solves: int = 0, products: int = 0) -> None:
        """A sparse look at a matrix of `nnz` nonzeros: the Jacobian and its equilibration, the LU
        `lu` (SciPy's ``SuperLU``; None where it failed), `solves` solves with it and `products`
        products with the matrix or its transpose."""
        work = LOOK_NS + ASSEMBLE_NS * nnz + products * (PRODUCT_CALL_NS + PRODUCT_NS * nnz)
        if lu is not None:
            flops, factors = sparse_lu_flops(lu) if self.factors else (2.0 * nnz, nnz)
            if self.factors:
                self.lu_flops, self.lu_nnz = flops, factors
            work += FACTOR_NS * factors + FLOP_NS * flops + solves * (SOLVE_CALL_NS + SOLVE_NS * factors)
        self.work += work


def integration_work(*, n: int, nnz: int, residuals: int, jacobians: int, steps: int, sparse: bool,
                     lu_flops: Optional[float] = None, lu_nnz: Optional[int] = None) -> float:
    """The work of IDA's `steps` steps with `residuals` residual evaluations and `jacobians`
    Jacobian evaluations (IDA's counters over them) at n unknowns and a Jacobian of `nnz`
    nonzeros, in the work model's nominal nanoseconds: each residual a Newton iteration (the
    residual and a solve with the factors), each Jacobian a factorization (`sparse`: of
    `lu_flops` operations and `lu_nnz` nonzeros in its factors, the monitor's LU of the same
    matrix (:class:`LookWork`), or without fill while it has made none; dense: LAPACK's), each
    step its fixed part and IDA's vector work."""
    if sparse:
        factors = float(lu_nnz if lu_nnz is not None else nnz)
        factor = FACTOR_NS * factors + FLOP_NS * (lu_flops if lu_flops is not None else 2.0 * nnz)
    else:
        factors, factor = float(n * n), FLOP_NS * 2.0 * n ** 3 / 3
    evaluation = CALLBACK_NS + EVALUATION_NS * nnz
    return (residuals * (evaluation + C_SOLVE_NS * factors) + jacobians * (evaluation + factor)
            + steps * (STEP_NS + VECTOR_NS * n))


class LookBudget:
    """The work of the monitor's looks and of the integration between them, over a run
    (counted: :class:`LookWork`, :func:`integration_work`).

    ``add(steps, look, integration)`` records a look of work `look` after `steps` steps of work
    `integration`; the means (:attr:`look_work`, :attr:`step_work`) are over the run so far, so
    that one look that happened to work hard (a golden-section search) does not swing the
    cadence."""

    def __init__(self):
        self.looks = 0
        self.steps = 0
        self.looking = 0.0      # work of the looks
        self.integrating = 0.0  # work of IDA's steps between them

    def add(self, steps: int, look: float, integration: float) -> None:
        self.looking += max(0.0, float(look))
        self.integrating += max(0.0, float(integration))
        self.steps += int(steps)
        self.looks += 1

    @property
    def look_work(self) -> float:
        """Mean work of a look (0 before the first)."""
        return self.looking / self.looks if self.looks else 0.0

    @property
    def step_work(self) -> float:
        """Mean work of an integration step between looks (0 before the first look)."""
        return self.integrating / self.steps if self.steps else 0.0
