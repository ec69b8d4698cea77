"""SUNDIALS IDA backend (variable-order BDF) through scikit-sundae's public interface.

Index-2 systems (GGL-stabilized position constraints, velocity constraints through port
couplings) are integrated with all algebraic variables excluded from the local error
test — the effect of IDA's ``IDASetSuppressAlg``, which scikit-sundae does not expose;
we get it with a very large absolute tolerance on algebraic components. Accuracy is
controlled on the differential (energy) states, which determine the algebraic ones.

IDA runs in its normal mode, in C, from one output time to the next (its own
interpolation gives the outputs), with the run's end as its stop time. phc sees every step
through a root function that never vanishes (:class:`_StepHook`): the step count and size,
which scikit-sundae does not report otherwise, are exact; the singularity monitor looks at
the states every few steps; `max_steps` is honoured exactly; progress is reported. Ctrl-C
(a ``KeyboardInterrupt`` raised in a callback or between calls) and any failure keep the
outputs computed before it.

What this costs: scikit-sundae builds a result object and copies the state after each
call, and wraps IDA's vectors in NumPy arrays at each residual, Jacobian and root-function
call — a few microseconds a call, on the smallest models more than the residual itself
(``benchmarks/bench_ida_callbacks.py`` measures it). Earlier
versions called SUNDIALS' C functions directly through ``ctypes`` at byte offsets inside
scikit-sundae's extension object and replaced its callbacks; a dependency upgrade could
turn that into a memory error, so phc now uses only what scikit-sundae documents.
"""

from __future__ import annotations

import math
import time
import warnings
from typing import Optional

import numpy as np
import scipy.sparse as sps

from phc.errors import SimulationSetupError
from phc.simulation.backend import BackendRun
from phc.simulation.guard import CATCH, GuardedModule, ModelEvaluationError
from phc.simulation.monitor import SingularityMonitor, check_scales, diagnose_failure

LOCAL_TOLERANCE = 0.005
"""IDA runs at ``rtol · LOCAL_TOLERANCE`` and ``atol · LOCAL_TOLERANCE`` (but see
:data:`TIGHTEST_LOCAL`): its error test bounds the error made in one step, and what a user
reads is the error of the outputs, which accumulates over the run — most of all as a phase
error in undamped oscillations (a pendulum over 8 periods, the high modes of a beam). At a
tenth, ``rtol = 1e-6`` gave 2.7e-4 on the shipped pendulum and 3.4e-4 on the Timoshenko
beam. The global error of both grows like the local tolerance to the power ~0.6, and runs
that differ only in rounding (the NumPy and the numba backend) differ by ±30 %: at a
hundredth the beam was at 8.2e-5 on one backend and 1.1e-4 on the other; at 1/200 every
shipped and test model is within 1e-4 on both (at most 7.2e-5). What it gives on the
shipped models, in steps and in errors: ``benchmarks/bench_accuracy.py``
(``benchmarks/results/accuracy.md``, docs/tolerances.md)."""

TIGHTEST_LOCAL = 1e-13
"""IDA's local relative tolerance is not set below this (the factor :func:`local_fraction`
gives then rises above :data:`LOCAL_TOLERANCE`): a step's residual is evaluated to a few ε
times its largest terms, BDF's error estimate is a difference of predicted and corrected
values, and over the 10⁴–10⁵ steps of such a run the round-off that accumulates is of
order 1e-14; a local tolerance below ~1e-13 buys steps, not accuracy."""


ABSOLUTE_DEPTH = 100.0
"""IDA's absolute tolerance is at least ``rtol / ABSOLUTE_DEPTH`` (:func:`applied_atol`)."""


def applied_atol(rtol: float, atol: float) -> float:
    """The `atol` IDA applies (relative to the nominal scales, before :func:`local_fraction`):
    the user's, but no finer than ``rtol / ABSOLUTE_DEPTH``.

    A variable's tolerance ``rtol·|y| + atol·s`` dips from ``rtol·s`` to ``atol·s`` where y
    crosses 0, by the factor ``rtol/atol``; loosening rtol alone deepens the dip. IDA comes
    to it on the long steps and high order a loose rtol allows, cuts its step by as much,
    and climbs back one order and a doubling at a time: the rigid slider–crank (atol 1e-12
    in the file) took 691 steps for 20 ms at rtol 1e-6 and 432 at 1e-7, each time its rod's
    angular momentum crossed 0 (the step fell from 3e-5 s to 6e-8 s). Where the variable is
    an index-1 one IDA does not climb back at all (:func:`determined_scales`). An absolute
    part finer than a hundredth of the relative part at the variable's nominal size buys no
    accuracy — the errors the run makes elsewhere, at ``rtol·|y|``, reach the variable
    through the dynamics — and 100 is the ratio of phc's default tolerances (1e-8, 1e-10)
    and of the shipped models' own but three (the Euler–Bernoulli and Timoshenko beams,
    the RLC filter: 1e3–1e4)."""
    # (the ratio itself keeps the user's atol: 1e-9 / 100 rounds above 1e-11)
    return atol if rtol <= ABSOLUTE_DEPTH * atol * (1 + 1e-12) else rtol / ABSOLUTE_DEPTH


def local_fraction(rtol: float) -> float:
    """The factor between the tolerances asked for and those IDA's error test applies:
    :data:`LOCAL_TOLERANCE`, raised so that ``rtol`` times it is no tighter than
    :data:`TIGHTEST_LOCAL` (and never above 1)."""
    rtol = float(rtol)
    if not rtol > 0:
        return LOCAL_TOLERANCE
    return min(1.0, max(LOCAL_TOLERANCE, TIGHTEST_LOCAL / rtol))


ALGEBRAIC_ATOL = 1e8
"""Absolute tolerance on algebraic variables: effectively removes them from the error test."""

DENSE_LIMIT = 120
"""Systems up to this size use the dense linear solver; larger ones the sparse one
(SuperLU_MT, one thread). Measured by ``benchmarks/bench_ida_linsolver.py`` (the flexible
slider–crank at 27–275 unknowns, CPU time per step, ``benchmarks/results/ida_linsolver.md``):
SUNDIALS' dense LU as fast or faster up to 115 unknowns, the sparse solver faster from 131 on."""

DENSE_SOLVER = "dense"
"""scikit-sundae's name of the dense solver: SUNDIALS' own LU (``dense``) or LAPACK's."""

MAX_ORDER = 5
"""Maximum BDF order (5 is IDA's default; 2 is A-stable for undamped stiff oscillations)."""

PROGRESS_STEPS = 50
"""Steps between two progress reports of a run."""

IDA_ROOT_RETURN = 2

_STATUS_HINTS = {
    -1: "the solver took too many steps; raise `max_steps` or shorten the time span",
    -2: "the tolerances are too tight for double precision; loosen `rtol`/`atol`",
}
"""Hints for failures whose cause the status says; error-test (-3) and Newton (-4) failures
are diagnosed at the failure point (:func:`phc.simulation.monitor.diagnose_failure`)."""


def _import_ida():
    """scikit-sundae's IDA class."""
    try:
        from sksundae.ida import IDA

        return IDA
    except ImportError as err:  # pragma: no cover - dependency is required
        raise SimulationSetupError("the IDA backend needs scikit-sundae: pip install scikit-sundae") from err


# ---------------------------------------------------------------------------------------
# Callbacks

class CallbackState:
    """What the callbacks of one run record for the integrator.

    ``cj``: α/h of the step IDA last formed its iteration matrix for. A model that cannot be
    evaluated at a trial point (a :class:`ModelEvaluationError`: outside its domain, an
    overflow) is a *recoverable* failure for IDA: the callback fills its output with NaN,
    IDA's Newton iteration fails to converge, and IDA retries the step shorter, as after any
    failed iteration — a long trial step that overshoots into an overflow does not end the
    run. ``failures`` counts them, ``error`` and ``t_failed`` are the latest one's located
    error and time, and ``failed_last`` says whether the latest evaluation was one: when IDA
    then gives up, the run reports that error (:func:`integrate_ida`)."""

    __slots__ = ("cj", "failures", "error", "t_failed", "failed_last", "evaluations")

    def __init__(self):
        self.cj = 0.0
        self.evaluations = 0  # residual evaluations (to tell :class:`_StepHook` a step from a call's start)
        self.failures = 0
        self.error: Optional[ModelEvaluationError] = None
        self.t_failed = 0.0
        self.failed_last = False

    def fail(self, err: ModelEvaluationError, t: float, out: np.ndarray, *inputs: np.ndarray) -> None:
        """Record `err` at `t` and fill `out` with NaN. At a point that is not finite itself
        (Newton's iterate after a Jacobian this class filled with NaN) the failure counts,
        but the error kept is the earlier one, located where the model left its domain."""
        self.failures += 1
        self.failed_last = True
        if self.error is None or all(math.isfinite(v.dot(v)) for v in inputs):
            self.error, self.t_failed = err, float(t)
        out.fill(np.nan)


def _callbacks(mod, p, n: int, sparse: bool):
    """(resfn, jacfn, state) for scikit-sundae: the raw generated functions (compiled or
    NumPy) into IDA's own arrays, checked for a finite result by one dot product; a
    failure is evaluated again through the guard (:mod:`phc.simulation.guard`), which
    raises the located :class:`ModelEvaluationError`, recorded in `state`
    (:class:`CallbackState`: a recoverable failure for IDA). The dense Jacobian is
    scattered into scikit-sundae's matrix through precomputed flat indices (its zeros are
    written once)."""
    guarded = mod if isinstance(mod, GuardedModule) else None
    raw = mod.module if guarded is not None else mod
    residual, jacobian = raw.residual, raw.jacobian
    check_res = guarded.residual if guarded is not None else None
    check_jac = guarded.jacobian if guarded is not None else None
    rows, cols = np.asarray(mod.JAC_ROWS, dtype=np.intp), np.asarray(mod.JAC_COLS, dtype=np.intp)
    state = CallbackState()
    isfinite, dot = math.isfinite, np.dot

    if check_res is None:
        def resfn(t, y, yp, res):
            state.evaluations += 1
            residual(t, y, yp, p, res)
    else:
        def resfn(t, y, yp, res):
            state.evaluations += 1
            try:
                try:
                    residual(t, y, yp, p, res)
                except CATCH:
                    check_res(t, y, yp, p, res)  # raises the located error
                    raise
                if not isfinite(res.dot(res)):  # (the method: a third of np.dot's call overhead)
                    check_res(t, y, yp, p, res)  # raises if a value is not finite (else an overflow of the check)
            except ModelEvaluationError as err:
                state.fail(err, t, res, y, yp)
                return
            state.failed_last = False

    def evaluate_jacobian(t, y, yp, cj, out):
        state.cj = cj
        try:
            try:
                jacobian(t, y, yp, p, cj, out)
            except CATCH:
                if check_jac is None:
                    raise
                check_jac(t, y, yp, p, cj, out)
                raise
            if not isfinite(dot(out, out)) and check_jac is not None:
                check_jac(t, y, yp, p, cj, out)
        except ModelEvaluationError as err:
            state.fail(err, t, out, y, yp)
            return False
        return True

    if sparse:
        def jacfn(t, y, yp, res, cj, JJ):
            evaluate_jacobian(t, y, yp, cj, JJ)
    else:
        buf = np.zeros(len(rows))
        flat = rows * n + cols
        target = [None, None]  # scikit-sundae's matrix (the same array every call) and its flat view

        def jacfn(t, y, yp, res, cj, JJ):
            if target[0] is not JJ:
                JJ.fill(0.0)
                target[0], target[1] = JJ, JJ.reshape(-1)
            if evaluate_jacobian(t, y, yp, cj, buf):
                target[1][flat] = buf
            else:
                JJ.fill(np.nan)
                target[0] = None  # its zeros are gone: written again at the next call

    return resfn, jacfn, state


LOOK_STRETCH = 32
"""Most the singularity monitor's cadence is stretched where the conditioning is flat."""
FLAT_DECADES = 0.1
"""Change of the conditioning ratio between two looks (decades) below which it counts as flat."""
FAR_RATIO = 1e-6
"""Conditioning ratio above which the monitor may look less often (its threshold is 1e-11)."""


EDGE_SHRINK = 1e-6
"""A model that cannot be evaluated at IDA's trial point is a recoverable failure: IDA
retries the step shorter (:class:`CallbackState`). After a long trial step's
overshoot the run passes the failed trial point within a few steps. Where the solution
itself runs into the edge of the model's domain it never does: the steps creep up to the
edge, shorter and shorter (10⁶ steps without reaching it, where the first failure ended
the run before). Once the steps have shrunk by this factor below the step size before the
first failure, without passing the failed trial point, the run stops with the last
failure's located error."""


CRAWL_CHECK_STEPS = 2000
"""Steps between two diagnoses of a crawling run (one whose step size cannot reach the end
of the run within ``max_steps``): each costs a few looks of the monitor."""


APPROACH_FALL = 10.0
"""A run whose conditioning fell by at least this factor over the monitor's last looks, and
further to the failure point, failed approaching a singular configuration."""


def _approaching_singularity(monitor, h, how: str = "Newton's iteration failed before reaching it") -> Optional[str]:
    """The singular configuration a run failed on its way to, or None.

    Close to a singular configuration the iteration matrix is conditioned like the distance
    to it, and IDA's Newton iteration fails (round-off outgrows the tolerances) before the
    conditioning reaches the monitor's threshold — the tighter the tolerances, the earlier:
    the folded slider–crank failed half a degree before its rod stood perpendicular to the guide.
    The conditioning at the monitor's last looks (``monitor.history``) is compared at one
    step size `h` (the ratio depends on it); when it fell steadily, by :data:`APPROACH_FALL`
    or more, to below :data:`FAR_RATIO`, the monitor's message is given for the last look
    (the dependent equations, their connections, the condition)."""
    if not monitor.enabled or h <= 0:
        return None
    h = max(h, monitor.h_floor)
    looks = []  # a tenth of a step apart (while IDA cut its step, its looks repeat the failure point)
    for look in monitor.history:
        if not looks or look[0] > looks[-1][0] + 0.1 * h:
            looks.append(look)
    if len(looks) < 3:
        return None
    picks = sorted({0, len(looks) // 3, 2 * len(looks) // 3, len(looks) - 1})
    try:
        ratios = [monitor.ratio(*looks[i][:3], h)[0] for i in picks]
    except (ModelEvaluationError, *CATCH, np.linalg.LinAlgError):
        return None
    if any(b >= a for a, b in zip(ratios, ratios[1:])) or ratios[0] < APPROACH_FALL * ratios[-1] \
            or ratios[-1] > FAR_RATIO:
        return None
    t_last, y_last, yp_last = looks[-1][:3]
    warning = monitor.check(t_last, y_last, yp_last, h, threshold=2.0 * ratios[-1])
    if warning is None:
        return None
    return (f"the conditioning of the iteration matrix fell from {ratios[0]:.1e} at t = {looks[0][0]:.6g} to "
            f"{ratios[-1]:.1e} at t = {t_last:.6g}: the run was approaching a singular configuration, and "
            f"{how}; {warning}")


def _status_text(res, status: int) -> str:
    """scikit-SUNDAE's text for an IDA return flag."""
    if res is not None:
        return str(res.message)
    try:
        from sksundae._cy_ida import IDAMESSAGES

        return str(IDAMESSAGES.get(status, f"IDA flag {status}"))
    except Exception:  # noqa: BLE001 - only the wording of a message
        return f"IDA flag {status}"


def _next_cadence(cadence: int, base: int, before: Optional[float], ratio: Optional[float]) -> int:
    """Steps until the monitor's next look: 1.5× longer (up to :data:`LOOK_STRETCH`× `base`)
    when the ratio moved less than :data:`FLAT_DECADES` since the last look and stays above
    :data:`FAR_RATIO`, else back to `base` at once."""
    if before is None or ratio is None or not (ratio > FAR_RATIO and before > FAR_RATIO):
        return base
    if abs(math.log10(ratio / before)) >= FLAT_DECADES:
        return base
    return min(LOOK_STRETCH * base, max(cadence + 1, int(1.5 * cadence)))


def determined_algebraic(mod, p, t, y, yp) -> np.ndarray:
    """Mask of the algebraic variables the algebraic rows determine from the states (index 1:
    a junction effort, a resistor's flow), as opposed to those only the derivative of a
    constraint determines (index 2: multipliers, the torque a flow source applies).

    The algebraic rows are those without ẏ (``F_ẏ`` row zero at (t, y, ẏ)); on their pattern
    in the algebraic variables, a maximum matching and the Dulmage–Mendelsohn
    decomposition: a variable an alternating path reaches from an unmatched variable is
    not determined (the rows leave a choice), every other matched variable is. Index-1
    variables go into IDA's Newton and error tests like the states; index-2 ones cannot
    (BDF then cuts its step without end) and are recomputed at the output times instead
    (:mod:`phc.simulation.polish`)."""
    from phc.analysis.matching import bipartite_matching

    n, m = mod.N, len(mod.EQUATIONS)
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    out = np.zeros(n, dtype=bool)
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    if not len(rows) or m != n:
        return out
    # the entries that are nonzero here or at a nearby point: the modes of switches are
    # parameters (a sticking friction law replaces its row), a coefficient may vanish by chance
    rng = np.random.default_rng(0)
    size = np.abs(y) + np.abs(yp) + 1e-3
    nonzero_y = np.zeros(len(rows), dtype=bool)
    nonzero_yp = np.zeros(len(rows), dtype=bool)
    for y_, yp_ in ((y, yp), (y + 1e-3 * size * rng.uniform(0.5, 1.5, n), yp + 1e-3 * size * rng.uniform(0.5, 1.5, n))):
        a, b = np.zeros(len(rows)), np.zeros(len(rows))
        try:
            mod.jacobian(t, y_, yp_, p, 0.0, a)
            mod.jacobian(t, y_, yp_, p, 1.0, b)
        except (ModelEvaluationError, *CATCH):
            return out
        nonzero_y |= (a != 0) | ~np.isfinite(a)
        nonzero_yp |= (b - a != 0) | ~np.isfinite(b)
    dynamic = np.zeros(m, dtype=bool)
    dynamic[rows[nonzero_yp]] = True
    alg_rows = np.flatnonzero(~dynamic)
    alg_cols = np.flatnonzero(~diff & np.array([not str(v).startswith("ggl.") for v in mod.VARIABLES]))
    if not len(alg_rows) or not len(alg_cols):
        return out
    rpos = np.full(m, -1)
    rpos[alg_rows] = np.arange(len(alg_rows))
    cpos = np.full(n, -1)
    cpos[alg_cols] = np.arange(len(alg_cols))
    sel = (rpos[rows] >= 0) & (cpos[cols] >= 0) & nonzero_y
    pattern = sps.csr_matrix((np.ones(int(sel.sum())), (rpos[rows[sel]], cpos[cols[sel]])),
                             shape=(len(alg_rows), len(alg_cols)))
    match = bipartite_matching(pattern)
    row_of = np.full(len(alg_cols), -1)
    matched = np.flatnonzero(match >= 0)
    row_of[match[matched]] = matched
    by_col = pattern.tocsc()
    seen = np.zeros(len(alg_cols), dtype=bool)
    stack = list(np.flatnonzero(row_of < 0))
    seen[stack] = True
    while stack:  # alternating paths: unmatched column → its rows → their matched columns
        c = stack.pop()
        for r in by_col.indices[by_col.indptr[c]:by_col.indptr[c + 1]]:
            c2 = match[r]
            if c2 >= 0 and not seen[c2]:
                seen[c2] = True
                stack.append(c2)
    out[alg_cols[~seen]] = True
    return out


SENSITIVITY_DENSE = 400
"""Up to this many unknowns the scales of the determined algebraic variables are raised to
what the states' tolerances allow them (:func:`determined_scales`); larger models keep theirs."""


CANCELLATION = 10.0
"""An index-1 variable below 1/CANCELLATION of the terms the states put into it is a
difference of those terms (:func:`determined_scales`)."""


TERM_FRACTION = 1e-6
"""A term of an index-1 variable below this fraction of its largest term does not count
(:func:`source_terms`, :func:`determined_scales`): it cannot cancel the largest to a small
difference, and the coefficients a solve for ``∂z/∂x`` gives where they vanish are round-off,
~1e-16 of the others."""


def source_terms(mod, p, t, y, yp, Fz, alg_rows, dz_dx, x_cols, z_cols, span: float) -> np.ndarray:
    """The size of the part of each index-1 variable z that does not come from the states —
    a source —, to first order at (t, y): z minus ``∂z/∂x · x`` (a constant voltage), or the
    change ``|∂z/∂t|·span`` over the run, ``∂z/∂t = −F_z⁺ F_t`` on the algebraic rows (a sine),
    where the model gives ``F_t``."""
    y = np.asarray(y, dtype=float)
    x = np.where(np.isfinite(y[x_cols]), y[x_cols], 0.0)
    z = np.where(np.isfinite(y[z_cols]), y[z_cols], 0.0)
    size = np.abs(z - dz_dx @ x)
    try:
        ft = np.zeros(len(mod.EQUATIONS))
        mod.residual_t(t, y, np.asarray(yp, dtype=float), p, ft)
        ft = ft[alg_rows]
        if np.all(np.isfinite(ft)) and np.any(ft != 0):
            size = np.maximum(size, np.abs(np.linalg.lstsq(Fz, ft, rcond=None)[0]) * abs(span))
    except (ModelEvaluationError, *CATCH, AttributeError, np.linalg.LinAlgError):
        pass
    return size


def determined_scales(mod, p, t, y, yp, determined, scales, rtol: float = 1.0, atol: float = 1.0,
                      span: float = 0.0) -> Optional[np.ndarray]:
    """The nominal `scales` with each index-1 algebraic variable z_j (`determined`) that is a
    small difference of the terms the states put into it raised to ``(1 + rtol/atol) T_j``,
    ``T_j = Σ_k |∂z_j/∂x_k| s_k``: the error the states' own tolerances (``rtol·|x_k| +
    atol·s_k``, |x_k| up to s_k) put into it, over atol. A small difference is one of

    * over the run: ``Σ_k |∂z_j/∂x_k| n_k`` above ``CANCELLATION · n_j``, with ``n`` the sizes
      the variables take (:attr:`phc.simulation.scaling.Scales.sizes`, the scales before
      the round-off floor; a floor that raised z's scale says how finely z can be resolved,
      not how large it is);
    * at the start of this piece (`y`, in the modes of `p`): the error the states'
      tolerances put into z, ``Σ_k |∂z_j/∂x_k| (rtol·|x_k| + atol·s_k)``, above
      ``CANCELLATION`` times z's own ``rtol·|z_j| + atol·s_j``. A switched law makes z
      small in one mode only — a diode's voltage is Ron·i, 0.1 V out of the source's and
      the capacitor's 7 V, while it conducts, and 13 V while it blocks — and a piece that
      begins at an event begins with z on the boundary;
    * at any time of the run: z is a sum of two or more terms — two
      states, or a state and a source (a part of z that does not vanish with the states, or
      that depends on t) — so it passes through 0 wherever its terms cancel, and the start
      and the sizes cannot say whether they will. A loudspeaker's coil voltage
      ``V(t) − R φ/L − Bl p/m`` is 2.83 V at most and 0 at the start, but crosses 0 twice
      a period of its drive while its terms do not; there its test, ``atol·s_z``, was
      ``rtol/atol`` times tighter than what the states' ``rtol·|x|`` put into it (10⁴ at
      rtol 1e-6, atol 1e-10; 100 at rtol 1e-8): IDA, on large steps at a high order,
      collapsed to steps of 3e-8 s at order 1 there and stayed (the trap below), so that
      rtol 1e-6 took 118 784 steps for 0.1 s of a 200 Hz tone and rtol 1e-8 10 983.
      A variable of one term, ``|z| = |∂z/∂x_k| |x_k|`` (a friction element's flow p/m),
      cannot be a small difference and keeps its scale.

    Other index-1 variables keep their scales (one that is a state times a factor, a
    friction element's flow p/m, is tested as tightly as the state determines it).

    The algebraic rows determine z from the states x (and t); to first order
    ``∂z/∂x = −(F_z)⁺ F_x`` on those rows. IDA tests z like a state, at
    ``rtol·|z| + atol·s_z``; where z is the small difference of large terms driven by the
    states — an inductor's voltage ``V(t) − R φ/L`` behind a resistor, 0.04 V out of 10 V,
    with ``∂z/∂φ = −R/L = −25 000`` — an error of the states within their own tolerance
    moves z by far more than z's, and IDA cuts its step to resolve the states far beyond
    what was asked: 556 000 steps for 0.1 s of an RL circuit driven at 100 rad/s, where
    raising the scale of that voltage to the size of the terms it is the difference of
    takes a few hundred: IDA at order 5 fell into runs of error-test and Newton failures,
    every step, while the same model with the voltage left out of the test, or at order 3,
    ran smoothly. At order 1 it does not get out again: z's error estimate is then the
    change of the states' truncation error times ∂z/∂x — ``(h² − h_old²)/2 · v_C''/Ron`` for
    a diode's current behind a capacitor — so a step that doubles fails the test and the
    retry passes at the old size; with a failure every other step BDF never raises its
    order. The rectifier of tests/simulation/test_events.py crawled that way, with steps of
    2.5e-9 s, to 10⁶ steps: its diode's voltage and current had local tolerances of
    1.5e-12 V and 2.1e-12 A while the capacitor's (3.6e-11 V at 7 V) put 3.6e-11 V and
    7e-11 A into them (the round-off floor had raised their scales to 180 V and 167 A,
    hiding the cancellation; the current takes 0.54 A, the voltage 13 V only while the
    diode blocks). Where it fell into the trap depended on round-off: the BLAS kernel
    (Zen, Haswell; SkylakeX passed) or the end time (t_end = 0.0623 s crawled on SkylakeX);
    now about 3 000 steps on each. The user's own scales are kept. Returns None where
    nothing changes (no determined variable, a model above :data:`SENSITIVITY_DENSE`
    unknowns, or a Jacobian that cannot be evaluated)."""
    n, m = mod.N, len(mod.EQUATIONS)
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    z_cols = np.flatnonzero(np.asarray(determined, dtype=bool) & ~diff)
    names = list(mod.VARIABLES)
    x_mask = diff.copy()
    if "energy.supplied" in names:  # it feeds nothing back
        x_mask[names.index("energy.supplied")] = False
    x_cols = np.flatnonzero(x_mask)
    if scales is None or not len(z_cols) or not len(x_cols) or n > SENSITIVITY_DENSE or m != n:
        return None
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    a, b = np.zeros(len(rows)), np.zeros(len(rows))
    try:
        mod.jacobian(t, y, yp, p, 0.0, a)
        mod.jacobian(t, y, yp, p, 1.0, b)
    except (ModelEvaluationError, *CATCH):
        return None
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return None
    Fy = np.zeros((m, n))
    Fyp = np.zeros((m, n))
    np.add.at(Fy, (rows, cols), a)
    np.add.at(Fyp, (rows, cols), b - a)
    alg_rows = np.flatnonzero(~np.any(Fyp != 0, axis=1))
    if not len(alg_rows):
        return None
    Fz = Fy[np.ix_(alg_rows, z_cols)]
    Fx = Fy[np.ix_(alg_rows, x_cols)]
    try:
        dz_dx = -np.linalg.lstsq(Fz, Fx, rcond=None)[0]
    except np.linalg.LinAlgError:
        return None
    s = np.asarray(scales, dtype=float)
    ratio = rtol / atol if atol > 0 and np.isfinite(rtol / atol) else 1.0
    total = np.abs(dz_dx) @ s[x_cols]
    # where z is a small difference of the states' terms, its own rtol·|z| is far tighter than
    # the states' rtol·|x| puts into it: that part goes into the scale too. Judged on the sizes
    # the variables take, before the round-off floor (scaling.Scales.sizes: a floor that raised
    # z's scale above its size says how finely z can be resolved, not how large it is) ...
    size = getattr(scales, "sizes", None)
    size = s if size is None or np.shape(size) != s.shape else np.asarray(size, dtype=float)
    cancels = np.abs(dz_dx) @ size[x_cols] > CANCELLATION * size[z_cols]
    # ... and at the values of the start: in this piece's mode z may be a small difference where
    # its size over the run is not (a diode's voltage: Ron·i, 0.1 V out of the capacitor's 7 V,
    # while it conducts; 13 V blocking), and a piece that starts at an event starts with z on
    # the boundary. There the error the states' tolerances put into z is compared with z's own
    x = np.where(np.isfinite(y), np.abs(np.asarray(y, dtype=float)), 0.0)
    put = np.abs(dz_dx) @ (ratio * x[x_cols] + s[x_cols])
    cancels |= put > CANCELLATION * (ratio * x[z_cols] + s[z_cols])
    # ... and wherever in the run its terms may cancel: a sum of two terms or more
    terms = np.column_stack([np.abs(dz_dx) * s[x_cols],
                             source_terms(mod, p, t, y, yp, Fz, alg_rows, dz_dx, x_cols, z_cols, span)])
    largest = terms.max(axis=1, initial=0.0)
    cancels |= np.sum(terms > TERM_FRACTION * largest[:, None], axis=1) * (largest > 0) >= 2
    need = np.where(cancels, (1.0 + ratio) * total, 0.0)
    out = s.copy()
    user = set(getattr(scales, "user", ()) or ())
    for j, v in zip(z_cols, need):
        if int(j) not in user and np.isfinite(v) and v > out[j]:
            out[j] = v
    return out if np.any(out != s) else None


def algebraic_rates(mod, p, t, y, yp, determined) -> np.ndarray:
    """ẏ with the rates of the `determined` (index-1) algebraic variables filled in: the
    time derivative of their algebraic rows, ``F_y[R, A] ż_A = −(F_y[R, states] ẏ + F_t[R])``
    (least squares). A consistent start leaves them 0, and IDA's first predictor then
    misses by ż·h: a diode voltage that follows V₀ sin(ωt) from 0 at 3 kV/s failed the error
    test at every step size down to 1e-13 s."""
    yp = np.array(yp, dtype=float)
    A = np.flatnonzero(determined)
    if not len(A):
        return yp
    n, m = mod.N, len(mod.EQUATIONS)
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    a, b = np.zeros(len(rows)), np.zeros(len(rows))
    ft = np.zeros(m)
    try:
        mod.jacobian(t, y, yp, p, 0.0, a)
        mod.jacobian(t, y, yp, p, 1.0, b)
        mod.residual_t(t, y, yp, p, ft)
    except (ModelEvaluationError, *CATCH, AttributeError):
        return yp
    algebraic_row = np.ones(m, dtype=bool)
    algebraic_row[rows[b - a != 0]] = False
    R = np.flatnonzero(algebraic_row)
    Fy = sps.csr_matrix((a, (rows, cols)), shape=(m, n))[R]
    known = yp.copy()
    known[~np.asarray(mod.DIFFERENTIAL, dtype=bool)] = 0.0
    rhs = -(Fy @ known + ft[R])
    M = Fy[:, A]
    try:
        if M.shape[0] * M.shape[1] <= 250_000:
            import scipy.linalg as sla

            z = sla.lstsq(M.toarray(), rhs, lapack_driver="gelsy", cond=1e-13)[0]
        else:
            from scipy.sparse.linalg import lsqr

            z = lsqr(M, rhs, atol=1e-14, btol=1e-14)[0]
    except (ValueError, np.linalg.LinAlgError):
        return yp
    if np.all(np.isfinite(z)):
        yp[A] = z
    return yp


def solver_options(mod, p, *, rtol, atol, max_order=None, sparse: Optional[bool] = None, determined=None):
    """(options of scikit-sundae's ``IDA``, callback state) for `mod` at parameters `p`: the
    tolerances (algebraic variables out of the error test), analytic Jacobian, linear solver
    (dense up to :data:`DENSE_LIMIT` unknowns) and maximum order of a phc run."""
    n = mod.N
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    sparse = n > DENSE_LIMIT if sparse is None else bool(sparse)
    resfn, jacfn, state = _callbacks(mod, p, n, sparse)
    # algebraic variables out of the error test, except those the algebraic rows determine
    # (`determined`, index 1): IDA's Newton test ignores what its weights ignore, and a
    # junction flow left out of it drifted from the momentum it equals by 20 %
    tested = diff if determined is None else diff | np.asarray(determined, dtype=bool)
    atol_vec = np.where(tested, atol, ALGEBRAIC_ATOL)
    options = dict(resfn=resfn, rtol=rtol, atol=atol_vec, jacfn=jacfn,
                   algebraic_idx=[int(j) for j in np.flatnonzero(~diff)],
                   max_order=int(max_order or MAX_ORDER))
    if sparse:
        rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
        pattern = sps.csc_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
        options.update(linsolver="sparse", sparsity=pattern)
    else:
        options.update(linsolver=DENSE_SOLVER)
    return options, state


class _Stop(Exception):
    """Raised by :class:`_StepHook` inside IDA's step loop to end a run for a reason phc
    gives (`message`): the monitor's singular configuration, ``max_steps``."""

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message


class _StepHook:
    """phc's look at every step IDA takes, from inside IDA's own loop.

    IDA evaluates its root functions once after each successful step, at the step's end
    (or at the output time inside it, where the call returns). phc passes one root function
    that never vanishes beside a run's switching functions, and this hook runs with it:
    IDA's step loop stays in C from one output time to the next, and phc still sees each
    step — it counts them (scikit-sundae does not report IDA's step count), keeps the step
    size, lets the singularity monitor look every few steps, notices steps creeping up to
    the edge of the model's domain, reports progress and stops the run at ``max_steps``
    exactly (by raising :class:`_Stop`, which scikit-sundae passes on; the outputs before
    it are kept).

    Not every evaluation is a step's end; a step always evaluates the residual, and an
    evaluation with none since the hook's last one is not a step: root finding inside the
    step, or a call's start. Where a call returns at an output time inside the step just
    taken, the evaluation is at that output time (the step is counted there, its size not
    taken), and the next calls begin with one at the next output time inside the same step
    or at the step's real end, which only moves the hook's clock. Steps are not told apart by
    time: IDA crawling into a singular configuration takes steps that leave t unchanged."""

    def __init__(self, t0, y0, yp0, *, t_end, max_steps, monitor, calls, progress, base):
        self.t_last, self.t_end, self.max_steps = float(t0), float(t_end), int(max_steps)
        self.monitor, self.calls, self.progress = monitor, calls, progress
        self.steps = 0
        self.h_last = 0.0
        # A failure is diagnosed at the last state reached with a normal step (h > h_ref/10, h_ref
        # the recent largest step, decaying 0.1 % a step): the steps collapse before IDA gives up.
        self.h_ref = 0.0
        self.normal = (float(t0), np.asarray(y0, dtype=float), np.asarray(yp0, dtype=float))
        # the monitor looks every `cadence` steps: `base`, stretched up to LOOK_STRETCH-fold while
        # the conditioning stays flat and far above the threshold (a look costs about what one IDA
        # step of a small system costs; a minimum of the conditioning between looks is still
        # located by the monitor's golden-section search)
        self.base = self.cadence = int(base)
        self.last_ratio = None
        self.since_look = self.since_progress = 0
        self.next_crawl_check = 0
        # recoverable model errors seen; (the earliest failed trial time not passed yet, the step size before it)
        self.failures_seen, self.edge = 0, None
        self.target = float(t0)      # the output time of IDA's current call
        self.evaluations_seen = calls.evaluations  # residual evaluations at the hook's last call

    def start_call(self, target: float) -> None:
        self.target = float(target)

    def __call__(self, t, y, yp) -> None:
        evaluations = self.calls.evaluations
        if evaluations == self.evaluations_seen:
            # no residual evaluation since the hook's last call, so no step: root finding inside
            # the step, or a call's start (the end of the step counted at the last output time,
            # or another output time inside it), which moves the hook's clock
            self.t_last = max(self.t_last, t)
            return
        self.evaluations_seen = evaluations
        self.steps += 1
        if t == self.target:  # the output time inside the step (or the step's own end)
            self.t_last = max(self.t_last, t)
            if self.steps >= self.max_steps and t < self.t_end:
                raise _Stop(f"stopped after {self.steps} steps at t = {t:.6g} (max_steps); raise `max_steps` "
                            "or loosen the tolerances")
            return
        # a step below the resolution of t (IDA crawling into a singular configuration takes
        # steps of 1e-18 s at t = 0.01, which leave t unchanged): its size is at most t's spacing
        h = self.h_last = max(t - self.t_last, math.ulp(t))
        self.t_last = t
        self.h_ref = max(h, 0.999 * self.h_ref)
        calls = self.calls
        if calls.failures != self.failures_seen:  # a trial point the model could not be evaluated at
            self.failures_seen = calls.failures
            if self.edge is None or calls.t_failed < self.edge[0]:
                self.edge = (calls.t_failed, self.h_ref)
        if self.edge is not None:
            if t > self.edge[0]:
                self.edge = None  # passed: it was a trial step's overshoot
            elif h < EDGE_SHRINK * self.edge[1]:
                raise calls.error  # creeping up to the edge of the model's domain
        if h > 0.1 * self.h_ref:
            self.normal = (t, np.array(y), np.array(yp))
        self.since_look += 1
        if self.since_look >= self.cadence and self.monitor.enabled:
            self._look(t, y, yp, h)
        self.since_progress += 1
        if self.progress is not None and self.since_progress >= PROGRESS_STEPS:
            self.since_progress = 0
            self.progress(t)
        if self.steps >= self.max_steps and t < self.t_end:
            raise _Stop(f"stopped after {self.steps} steps at t = {t:.6g} (max_steps); raise `max_steps` or "
                        "loosen the tolerances")

    def _look(self, t, y, yp, h) -> None:
        monitor = self.monitor
        self.since_look = 0
        warning = monitor.watch(t, np.array(y), np.array(yp), h)
        if warning is None and self.steps >= self.next_crawl_check \
                and h * (self.max_steps - self.steps) < self.t_end - t:
            # crawling: at this step size the run cannot reach its end within max_steps. Close
            # to a singular configuration IDA may crawl instead of failing (which of the two
            # depends on round-off: the BLAS kernels of the CPU); ask the same question as after
            # a failure, at most every CRAWL_CHECK_STEPS steps
            self.next_crawl_check = self.steps + CRAWL_CHECK_STEPS
            approach = _approaching_singularity(monitor, self.h_ref,
                                                f"IDA's steps shrank to {h:.1e} s before reaching it")
            if approach is not None:
                warning = approach
                monitor.stop_time = t
        if warning:
            raise _Stop(warning)
        ratio = monitor._looks[-1][-1] if monitor._looks else None
        self.cadence = _next_cadence(self.cadence, self.base, self.last_ratio, ratio)
        self.last_ratio = ratio


def integrate_ida(mod, p, t_out, y0, yp0, options, *, progress=None, names=None, events=None,
                  nominal=None) -> BackendRun:
    """Integrate from ``t_out[0]`` with the `rtol`, `atol`, `max_order` and `max_steps` of
    `options` (a :class:`~phc.options.RunOptions`); the outputs and statistics as a
    :class:`~phc.simulation.backend.BackendRun`.

    IDA runs in its normal mode from one output time to the next (its own interpolation
    gives the outputs), with the run's end as its stop time; :class:`_StepHook` sees every
    step. `events` (a :class:`phc.simulation.events.Watch`, optional) are switching
    functions w(t, y, ẏ), positive while the modes hold: IDA's root finding (scikit-sundae's
    ``eventsfn``, direction −1, terminal) stops at the first that falls to zero; the run
    then returns with ``event`` = dict(t, y, yp, which) and the outputs before it."""
    IDA = _import_ida()
    n = mod.N
    rtol, max_steps = float(options.rtol), int(options.max_steps)
    atol = applied_atol(rtol, float(options.atol))
    max_order = int(options.max_order or MAX_ORDER)
    t_out = np.asarray(t_out, dtype=float)
    t0, t_end = float(t_out[0]), float(t_out[-1])
    y0 = np.asarray(y0, dtype=float)
    # `nominal`: the variables' nominal scales (phc.simulation.scaling); atol is relative to them.
    # IDA's local tolerances are 1/200 of what the outputs should meet (local_fraction).
    determined = determined_algebraic(mod, p, t0, y0, np.asarray(yp0, dtype=float))
    # an index-1 variable is tested no tighter than its states' tolerances determine it
    tested_scales = determined_scales(mod, p, t0, y0, np.asarray(yp0, dtype=float), determined, nominal, rtol, atol,
                                      t_end - t0)
    if tested_scales is None:
        tested_scales = nominal
    local = local_fraction(rtol)
    atol_j = (atol if tested_scales is None else atol * np.asarray(tested_scales, dtype=float)) * local
    yp0 = algebraic_rates(mod, p, t0, y0, yp0, determined)
    options, calls = solver_options(mod, p, rtol=rtol * local, atol=atol_j, max_order=max_order,
                                    determined=determined)
    resfn = options.pop("resfn")
    monitor = SingularityMonitor(mod, p, names=names, scales=nominal)
    monitor.h_floor = 1e-6 * (t_end - t0)
    hook = _StepHook(t0, y0, yp0, t_end=t_end, max_steps=max_steps, monitor=monitor, calls=calls, progress=progress,
                     base=10 if n <= 60 else 20)
    n_switch = events.n if events is not None else 0

    if n_switch:
        def eventsfn(t, y, yp, out):
            out[:n_switch] = events(t, y, yp)
            out[n_switch] = 1.0
            hook(t, y, yp)
    else:
        def eventsfn(t, y, yp, out):
            out[0] = 1.0
            hook(t, y, yp)

    eventsfn.direction = [-1] * n_switch + [0]   # w falls through 0: the mode no longer holds
    eventsfn.terminal = [True] * n_switch + [False]
    # IDA's per-call step limit: never reached (the hook stops the run at max_steps)
    options.update(eventsfn=eventsfn, num_events=n_switch + 1, max_num_steps=int(max_steps) + 1)
    with warnings.catch_warnings():
        # scikit-sundae warns that its own sparse approximation is unused: we pass jacfn.
        warnings.filterwarnings("ignore", message="Custom sparse Jacobian approximation")
        solver = IDA(resfn, **options)

    def scales(failed, upto=1):  # the states of the run so far (a system at rest at t0 may move later)
        return check_scales(mod, ys[:upto], yps[:upto], t_end - t0, rtol, atol, failed, scales=nominal)

    ys = np.empty((len(t_out), n))
    yps = np.empty((len(t_out), n))
    ys[0], yps[0] = y0, yp0
    start = time.process_time()
    init = solver.init_step(t0, y0, yp0)
    if not init.success:
        return BackendRun(t_out[:1], ys[:1], yps[:1], steps=0, success=False, cpu=time.process_time() - start,
                          message=f"IDA could not start: {init.message}" + (f"; {scales(True)}" if scales(True) else ""))
    hook.evaluations_seen = calls.evaluations  # (any the start made are not a step's)
    k, ok, message = 1, True, "integration finished"
    event = None
    nfev = int(getattr(init, "nfev", 0) or 0)
    njev = int(getattr(init, "njev", 0) or 0)
    interrupted = False
    try:  # a model function outside its domain, a stop, Ctrl-C: keep the outputs filled so far
        while k < len(t_out):
            hook.start_call(t_out[k])
            res = solver.step(float(t_out[k]), method="normal", tstop=t_end)
            status, t_now = int(res.status), float(res.t)
            nfev, njev = int(res.nfev), int(res.njev)
            if status < 0:
                if calls.failed_last:  # IDA gave up where the model cannot be evaluated
                    raise calls.error
                ok = False
                hint = _STATUS_HINTS.get(status)
                approach = _approaching_singularity(monitor, hook.h_ref) if hint is None else None
                if approach is not None:
                    hint = approach
                elif hint is None:  # diagnose before blaming: is the iteration matrix singular there?
                    cj = calls.cj
                    hint = diagnose_failure(mod, p, *hook.normal, status=status, h_typical=hook.h_ref,
                                            h_fail=(1.0 / cj) if cj > 0 else hook.h_last,
                                            max_order=max_order, rtol=rtol, atol=atol, names=names,
                                            scales=nominal, local=local)
                message = f"IDA failed at t = {t_now:.6g} (status {status}: {_status_text(res, status)}); {hint}"
                break
            if status == IDA_ROOT_RETURN and res.i_events is not None:  # a switching function hit 0
                event = dict(t=t_now, y=np.array(res.y), yp=np.array(res.yp),
                             which=np.flatnonzero(np.asarray(res.i_events)[-1][:n_switch]).tolist())
                break
            ys[k], yps[k] = res.y, res.yp
            k += 1
        if progress is not None and k > 1:
            progress(float(t_out[k - 1]))
    except _Stop as stop:
        ok, message = False, stop.message
        if monitor.stop_time is not None:
            # the configuration may lie before outputs already filled in: keep none past it
            k = max(1, min(k, int(np.searchsorted(t_out, monitor.stop_time, side="right"))))
    except ModelEvaluationError as err:
        ok, message = False, f"IDA: {err}; results up to t = {t_out[k - 1]:.6g} are kept"
    except KeyboardInterrupt:
        ok, interrupted = False, True
        message = f"interrupted at t = {t_out[k - 1]:.6g}"
    note = scales(not ok, k) if not message.startswith(("stopped ", "interrupted")) else None
    if note:
        message = f"{message}; {note}"
    return BackendRun(t_out[:k], ys[:k], yps[:k], steps=hook.steps, nfev=nfev, njev=njev, success=ok, event=event,
                      message=message, cpu=time.process_time() - start, conditioning=monitor.worst,
                      interrupted=interrupted)
