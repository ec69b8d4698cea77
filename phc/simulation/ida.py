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
outputs computed before it. A rank drop IDA stops at is bridged (:mod:`phc.simulation.ida_bridge`).

What this costs: scikit-sundae builds a result object and copies the state after each
call, and wraps IDA's vectors in NumPy arrays at each residual, Jacobian and root-function
call — a few microseconds a call, on the smallest models more than the residual itself
(``benchmarks/bench_ida_callbacks.py`` measures it). Earlier
versions called SUNDIALS' C functions directly, at byte offsets inside scikit-sundae's
extension object, and replaced its callbacks; a dependency upgrade could
turn that into a memory error, so phc now uses only what scikit-sundae documents.
phc's own C driver against the machine's SUNDIALS (:mod:`phc.simulation.ida_native`) takes its
settings and its step hook from here.

The module is over 800 lines because it holds, beside the scikit-sundae run, what both IDA
drivers share: the run's settings (:func:`run_settings`) and the step hook with the monitor's
look cadence (:class:`_StepHook`).
"""

from __future__ import annotations

import math
import time
import warnings
from collections import deque
from typing import Optional

import numpy as np
import scipy.sparse as sps

from phc.errors import SimulationSetupError
from phc.simulation.backend import BackendRun
from phc.simulation.guard import CATCH, GuardedModule, ModelEvaluationError
from phc.simulation.ida_bridge import NEAR_DROP, Bridges, near_rank_drop
from phc.simulation.scaling import promise_scales, remember
from phc.simulation.monitor import DENSE_SIZE, SingularityMonitor, check_scales, diagnose_failure, unbounded_growth
from phc.simulation.look_cadence import (FAR_RATIO, LookBudget, affordable_cadence, crawls, integration_work,
                                       next_cadence)
from phc.simulation.order import RECENT_STEPS, OrderChoice, Switch, after_step
from phc.simulation.tested import (  # noqa: F401  (names of phc.simulation.ida before the split)
    CANCELLATION, SENSITIVITY_DENSE, TERM_FRACTION, algebraic_rates, determined_algebraic, determined_scales,
    source_terms)

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


def promised_atol(atol_j, rtol: float, nominal, promised) -> np.ndarray:
    """IDA's absolute tolerances `atol_j` (``atol · s_j`` at the local fraction) where a state
    can err far beyond its nominal scale s_j before an output or the energy notices (its
    promise scale P_j > s_j, :func:`~phc.simulation.scaling.promise_scales`): raised to
    ``rtol · (P_j − s_j)``, so that at the state's nominal size its tolerance
    ``rtol·|y_j| + atol_j`` is about ``rtol · P_j`` — `rtol` relative to the size at which
    the state's error matters to an output or to the energy, not to the state's own size.
    Continuous in P_j (P_j = s_j leaves ``atol · s_j``), homogeneous in the state's unit.
    Only `atol` loosens this way: IDA has one relative tolerance for all variables.

    The flexible slider–crank driven at 150 rad/s (models/scenes/slider_crank_150rad.yaml)
    had its rod's curvatures tested against their own size, 0.01–0.2: the midspan
    deflection it is asked for moves by 1.2e-4–1.3e-3 m per unit of curvature, the energy
    by 800 J at a curvature of 43; IDA resolved bending modes up to 4.2e5 rad/s that carry
    neither, 450 654 steps for its 0.1 s at rtol 1e-6 (117 277 with this; CHANGELOG)."""
    s = np.asarray(nominal, dtype=float)
    P = np.asarray(promised, dtype=float)
    return np.maximum(atol_j, rtol * np.where(P > s, P - s, 0.0))


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
"""Maximum BDF order (5 is IDA's default; 2 is A-stable for undamped stiff oscillations). Where
the user sets none, phc starts with it and may go on at 2 (:mod:`phc.simulation.order`)."""

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
    then gives up, the run reports that error (:func:`integrate_ida`).

    ``evaluations`` and ``jacobians`` count the residual and Jacobian evaluations IDA asked
    for: the run's statistics, also of a run stopped inside an IDA call (the step hook's
    ``max_steps``, a model error, Ctrl-C), whose counts scikit-sundae does not return."""

    __slots__ = ("cj", "failures", "error", "t_failed", "failed_last", "evaluations", "jacobians")

    def __init__(self):
        self.cj = 0.0
        self.evaluations = 0  # residual evaluations (to tell :class:`_StepHook` a step from a call's start)
        self.jacobians = 0
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
        state.jacobians += 1
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


AHEAD = ("Newton's iteration failed on the round-off that this conditioning amplifies (tighter tolerances fail "
         "earlier and a looser atol only moves the failure closer: IDA cannot pass it; `midpoint` and "
         "`discrete_gradient` integrate through an isolated rank drop of the position constraints)")
"""How a run failed that approached a rank drop of the position constraints without reaching
:data:`FAR_RATIO` (the N four-bar at rtol 1e-10, 0.034 s before its bars are horizontal): the
round-off diagnosis would ask for a larger atol, and following it moves the failure closer."""


def _approaching_singularity(monitor, h, how: str = "Newton's iteration failed before reaching it",
                             far: float = FAR_RATIO, positional: bool = False) -> Optional[str]:
    """The singular configuration a run failed on its way to, or None.

    Close to a singular configuration the iteration matrix is conditioned like the distance
    to it, and IDA's Newton iteration fails (round-off outgrows the tolerances) before the
    conditioning reaches the monitor's threshold — the tighter the tolerances, the earlier:
    the folded slider–crank failed half a degree before its rod stood perpendicular to the guide.
    The conditioning at the monitor's last looks (``monitor.history``) is compared at one
    step size `h` (the ratio depends on it); when it fell steadily, by :data:`APPROACH_FALL`
    or more, to below :data:`FAR_RATIO`, the monitor's message is given for the last look
    (the dependent equations, their connections, the condition). `far` replaces :data:`FAR_RATIO`;
    `positional`: only if the dependent equations are position constraints."""
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
            or ratios[-1] > far:
        return None
    t_last, y_last, yp_last = looks[-1][:3]
    if positional:
        # still short of the rank drop: the monitor's check (singular at this step and at a 1000
        # times longer one) does not fire yet; the weakest direction at this step names it
        look = monitor.weakest(t_last, y_last, yp_last, h, 1.0)
        if look is None or look[1] is None:
            return None
        ratio, u = look
        rows = [c for c in monitor.dependent(u)[0] if c in set(getattr(monitor.mod, "INVARIANTS", ()))]
        if len(rows) < 2:
            return None
        where = sorted({monitor.names[c].split(" row ")[0] for c in rows if c in monitor.names})
        return (f"the conditioning of the iteration matrix fell steadily from {ratios[0]:.1e} at t = "
                f"{looks[0][0]:.6g} to {ratios[-1]:.1e} at t = {t_last:.6g} (estimates; σ_min/σ_max = {ratio:.1e} "
                f"there): the run was approaching a rank drop of the position constraints "
                f"{', '.join(f'`{c}`' for c in rows)}" + (f" at {', '.join(where)}" if where else "") +
                f" (a singular configuration), and {how}")
    else:
        warning = monitor.check(t_last, y_last, yp_last, h, threshold=2.0 * ratios[-1])
    if warning is None:
        return None
    return (f"the conditioning of the iteration matrix fell from {ratios[0]:.1e} at t = {looks[0][0]:.6g} to "
            f"{ratios[-1]:.1e} at t = {t_last:.6g}: the run was approaching a singular configuration, and "
            f"{how}; {warning}")


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

    def __init__(self, message: str, max_steps: bool = False, rank_drop: bool = False):
        super().__init__(message)
        self.message = message
        self.max_steps = max_steps  # the run used up `max_steps`
        self.rank_drop = rank_drop  # crawling near a rank drop of the position constraints (a bridge may pass it)


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

    def __init__(self, t0, y0, yp0, *, t_end, max_steps, monitor, calls, progress, base, order_look=None):
        self.t_last, self.t_end, self.max_steps = float(t0), float(t_end), int(max_steps)
        # phc's choice of the maximum order (phc.simulation.order.after_step; None: the user's),
        # from the sizes of the last steps
        self.order_look = order_look
        self.recent = deque(maxlen=RECENT_STEPS)
        self.monitor, self.calls, self.progress = monitor, calls, progress
        self.steps = 0
        self.h_last = 0.0
        # A failure is diagnosed at the last state reached with a normal step (h > h_ref/10, h_ref
        # the recent largest step, decaying 0.1 % a step): the steps collapse before IDA gives up.
        self.h_ref = self.h_largest = 0.0
        self.normal = (float(t0), np.asarray(y0, dtype=float), np.asarray(yp0, dtype=float))
        # the last step's end when it is not a normal one (a growth without bound is diagnosed there)
        self.collapsed = None
        # the monitor looks every `cadence` steps: `base`, stretched up to LOOK_STRETCH-fold while
        # the conditioning stays flat and far above the threshold, and further where a look's work
        # is more than LOOK_SHARE of the work of the steps between looks while the ratio is not
        # falling toward the threshold (phc.simulation.look_cadence: work counted from IDA's
        # counters and the looks' factorizations, never timed; a minimum of the conditioning
        # between looks is still located by the monitor's golden-section search)
        self.base = self.cadence = int(base)
        self.last_ratio = None
        self.budget = LookBudget()
        self.counted = (calls.evaluations, calls.jacobians)  # IDA's counters at the last look
        self.since_look = self.since_progress = 0
        self.next_crawl_check = 0
        # recoverable model errors seen; (the earliest failed trial time not passed yet, the step size before it)
        self.failures_seen, self.edge = 0, None
        self.target = float(t0)      # the output time of IDA's current call
        self.evaluations_seen = calls.evaluations  # residual evaluations at the hook's last call

    def rewind(self, t0, y0, yp0) -> None:
        """The run starts again at (t0, y0, ẏ0) (another maximum order, phc.simulation.order);
        the steps already taken stay counted."""
        self.t_last, self.h_last, self.h_ref = float(t0), 0.0, 0.0
        self.normal = (float(t0), np.asarray(y0, dtype=float), np.asarray(yp0, dtype=float))
        self.collapsed = None
        self.edge = None
        self.recent.clear()
        self.monitor.forget()

    def latest(self):
        """(t, y, ẏ) of the last step's end the hook kept: the normal one or a collapsed one after it."""
        if self.collapsed is not None and self.collapsed[0] >= self.normal[0]:
            return self.collapsed
        return self.normal

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
                            "or loosen the tolerances", max_steps=True)
            return
        # a step below the resolution of t (IDA crawling into a singular configuration takes
        # steps of 1e-18 s at t = 0.01, which leave t unchanged): its size is at most t's spacing
        h = self.h_last = max(t - self.t_last, math.ulp(t))
        self.t_last = t
        self.h_ref = max(h, 0.999 * self.h_ref)
        self.h_largest = max(h, self.h_largest)  # (kept over restarts: what bounds a bridge's step)
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
        self._keep(t, y, yp, h)
        self.since_look += 1
        if self.since_look >= self.cadence and self.monitor.enabled:
            self._look(t, y, yp, h)
        if self.order_look is not None:
            self.recent.append(h)
            self.order_look(t, y, yp, self.steps, self.recent)  # may raise order.Switch
        self.since_progress += 1
        if self.progress is not None and self.since_progress >= PROGRESS_STEPS:
            self.since_progress = 0
            self.progress(t)
        if self.steps >= self.max_steps and t < self.t_end:
            raise _Stop(f"stopped after {self.steps} steps at t = {t:.6g} (max_steps); raise `max_steps` or "
                        "loosen the tolerances", max_steps=True)

    def _keep(self, t, y, yp, h) -> None:
        """After a step of size h to (t, y, ẏ): the state a failure is diagnosed at — the last one
        reached with a normal step (h > h_ref/10), or the latest of a collapse."""
        if h > 0.1 * self.h_ref:
            self.normal = (t, np.array(y), np.array(yp))
        else:
            self.collapsed = (t, np.array(y), np.array(yp))

    def after_chunk(self, steps: int, t, y, yp, hs, h_ref: float, since_look: Optional[int] = None) -> None:
        """What :meth:`__call__` does after each step, for a chunk of steps of sizes `hs` (oldest
        first) ending at (t, y, ẏ), the run's `steps` in all (phc's native IDA driver,
        :mod:`phc.simulation.ida_native`): `h_ref` (``max(h, 0.999 h_ref)`` step by step, which the
        driver computes), the largest step, the state kept for a diagnosis, and the monitor's look
        where one is due. `since_look`: the steps since the monitor's last look where the driver made
        its routine looks itself."""
        taken = len(hs)
        self.h_ref = float(h_ref)
        h = float(hs[-1])
        self.steps, self.t_last, self.h_last = steps, t, h
        self.h_largest = max(self.h_largest, float(hs.max()))
        self.since_look = self.since_look + taken if since_look is None else since_look
        self._keep(t, y, yp, h)
        if self.since_look >= self.cadence and self.monitor.enabled:
            self._look(t, y, yp, h)

    def _look(self, t, y, yp, h) -> None:
        monitor = self.monitor
        steps, self.since_look = self.since_look, 0
        looked = monitor.tally.work
        warning = monitor.watch(t, np.array(y), np.array(yp), h)
        if warning is None and crawls(h, t, self.t_end, self.steps, self.max_steps, self.next_crawl_check):
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
            elif near_rank_drop(monitor, t, y, yp, self.h_ref):  # no fall to read (a restart cleared the looks)
                monitor.stop_time = t
                named = monitor.check(t, np.array(y), np.array(yp), self.h_ref, threshold=NEAR_DROP)
                raise _Stop(f"IDA's steps shrank to {h:.1e} s" + (f"; {named}" if named else
                            f" at t = {t:.6g}, near a rank drop of the position constraints"), rank_drop=True)
        if warning:
            raise _Stop(warning)
        calls, mod, tally = self.calls, monitor.mod, monitor.tally
        (residuals, jacobians), self.counted = self.counted, (calls.evaluations, calls.jacobians)
        self.budget.add(steps, tally.work - looked, integration_work(
            n=mod.N, nnz=len(monitor.rows), residuals=calls.evaluations - residuals,
            jacobians=calls.jacobians - jacobians, steps=steps, sparse=mod.N > DENSE_LIMIT,
            lu_flops=tally.lu_flops, lu_nnz=tally.lu_nnz))
        ratio = monitor._looks[-1][-1] if monitor._looks else None
        cadence = next_cadence(self.cadence, self.base, self.last_ratio, ratio)
        if monitor.mod.N > DENSE_SIZE:  # a sparse look: its work may be many steps'
            cadence = affordable_cadence(cadence, self.base, look_work=self.budget.look_work,
                                         step_work=self.budget.step_work, before=self.last_ratio, ratio=ratio,
                                         steps=steps, threshold=monitor.threshold)
        self.cadence = cadence
        self.last_ratio = ratio


def run_settings(mod, p, t0: float, t_end: float, y0, yp0, options, nominal=None):
    """(atol applied, local fraction, IDA's atol vector, ẏ0, OrderChoice, scikit-sundae's keywords, callback
    state): what IDA runs with, here and in the native driver (:mod:`phc.simulation.ida_native`)."""
    rtol = float(options.rtol)
    atol = applied_atol(rtol, float(options.atol))
    # the user's max_order, else phc's choice: IDA's default, and 2 where undamped modes hold its steps
    choice = OrderChoice.fixed(options.max_order) if options.max_order else OrderChoice(order=MAX_ORDER)
    max_order = choice.order
    local = local_fraction(rtol)
    # what the tolerances and the start's rates are made of, computed once for a set of inputs
    # (phc.simulation.scaling.remember: a run repeating another's start, parameters, scales and
    # tolerances gets the same numbers without evaluating the model again)
    nominal_parts = (None, None, None) if nominal is None else (
        np.asarray(nominal, dtype=float), getattr(nominal, "sizes", None), getattr(nominal, "floored", None))
    determined, atol_j, yp0 = remember(
        mod, "ida.run_settings", (np.asarray(p, dtype=float), np.asarray(y0, dtype=float),
                                  np.asarray(yp0, dtype=float), np.array([t0, t_end, rtol, atol]), *nominal_parts),
        lambda: _tolerances(mod, p, t0, t_end, y0, yp0, rtol, atol, local, nominal))
    determined, atol_j, yp0 = determined.copy(), np.array(atol_j, dtype=float), yp0.copy()
    settings, calls = solver_options(mod, p, rtol=rtol * local, atol=atol_j, max_order=max_order,
                                     determined=determined)  # scikit-sundae's keywords
    return atol, local, atol_j, yp0, choice, settings, calls


def _tolerances(mod, p, t0, t_end, y0, yp0, rtol, atol, local, nominal):
    """(the index-1 algebraic variables, IDA's absolute tolerances, ẏ0 with their rates) of
    :func:`run_settings`."""
    # `nominal`: the variables' nominal scales (phc.simulation.scaling); atol is relative to them.
    # IDA's local tolerances are 1/200 of what the outputs should meet (local_fraction).
    determined = determined_algebraic(mod, p, t0, y0, np.asarray(yp0, dtype=float))
    # the states' scales as far as the requested outputs and the energy need them (promise_scales)
    promised = nominal
    if nominal is not None:
        promised = promise_scales(mod, p, t0, y0, np.asarray(yp0, dtype=float), nominal)
    # an index-1 variable is tested no tighter than its states' tolerances determine it
    tested_scales = determined_scales(mod, p, t0, y0, np.asarray(yp0, dtype=float), determined, promised, rtol, atol,
                                      t_end - t0)
    if tested_scales is None:
        tested_scales = promised
    atol_j = (atol if tested_scales is None else atol * np.asarray(tested_scales, dtype=float)) * local
    if nominal is not None:  # the promise is about the outputs and the energy (promised_atol)
        atol_j = promised_atol(atol_j, rtol * local, nominal, promised)
    yp0 = algebraic_rates(mod, p, t0, y0, yp0, determined)
    return determined, atol_j, yp0


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
    then returns with ``event`` = dict(t, y, yp, which) and the outputs before it.

    Without a `max_order` in `options`, phc chooses it (:mod:`phc.simulation.order`): the
    step hook looks at the modes now and then and may start the run again at order 2 (and
    go on at order 5 if that does not pay); ``extra`` then holds the note that says so
    (``order_note``), the order IDA ended with (``max_order``) and, once the trial settled
    it, the order later pieces of the run keep (``max_order_chosen``)."""
    IDA = _import_ida()
    n = mod.N
    rtol, max_steps = float(options.rtol), int(options.max_steps)
    t_out = np.asarray(t_out, dtype=float)
    t0, t_end = float(t_out[0]), float(t_out[-1])
    y0 = np.asarray(y0, dtype=float)
    atol, local, atol_j, yp0, choice, settings, calls = run_settings(mod, p, t0, t_end, y0, yp0, options, nominal)
    max_order = choice.order
    resfn = settings.pop("resfn")
    monitor = SingularityMonitor(mod, p, names=names, scales=nominal, count_factors=True)
    monitor.h_floor = 1e-6 * (t_end - t0)
    hook = _StepHook(t0, y0, yp0, t_end=t_end, max_steps=max_steps, monitor=monitor, calls=calls, progress=progress,
                     base=10 if n <= 60 else 20,
                     order_look=None if choice.final else (
                         lambda t, y, yp, steps, recent: after_step(choice, mod, p, t, y, yp, steps=steps,
                                                                    recent=recent, t_end=t_end)))
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
    settings.update(eventsfn=eventsfn, num_events=n_switch + 1, max_num_steps=int(max_steps) + 1)
    with warnings.catch_warnings():
        # scikit-sundae warns that its own sparse approximation is unused: we pass jacfn.
        warnings.filterwarnings("ignore", message="Custom sparse Jacobian approximation")
        solver = IDA(resfn, **settings)

    def restart(switch: Switch):
        """A new IDA (scikit-sundae sets the order when it is made) at the order `choice`
        holds now: from the run's start, or from the step's end `switch` with the step it
        was taking."""
        first = {} if switch.rewind else {"first_step": switch.h}
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Custom sparse Jacobian approximation")
            new = IDA(resfn, **{**settings, "max_order": choice.order, **first})
        if switch.rewind:
            hook.rewind(t0, y0, yp0)
            return new, new.init_step(t0, y0, yp0)
        return new, new.init_step(switch.t, switch.y, switch.yp)

    monitor.start = (t0, y0, np.array(yp0, dtype=float))

    def growth():  # a failure's cause when the solution grows without bound (monitor.unbounded_growth)
        return unbounded_growth(mod, *hook.latest(), start=monitor.start, scales=nominal)

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
    interrupted = used_up = False
    bridges = Bridges(mod, p, t_out, names=names, nominal=nominal, events=events, hook=hook, monitor=monitor,
                      rtol=rtol * local, atol=atol_j)

    def bridge_over(before=None, origin=None):
        """The rank drop bridged (:mod:`phc.simulation.ida_bridge`), IDA restarted: the next output index, or None."""
        crossed = bridges.cross(max_steps - hook.steps, before, origin)
        if crossed is None:
            return None
        k_next, t_b, y_b, yp_b = crossed
        for i, (yi, ypi) in enumerate(zip(*bridges.last_outputs[1:]), start=k_next - len(bridges.last_outputs[0])):
            ys[i], yps[i] = yi, ypi
        if t_b < t_end:
            init = solver.init_step(t_b, y_b, yp_b)  # IDAReInit through scikit-sundae's public interface
            if not init.success:
                bridges.note = f"IDA could not restart after the bridge at t = {t_b:.6g}: {init.message}"
                return None
            hook.rewind(t_b, y_b, yp_b)
            hook.evaluations_seen = calls.evaluations
        return k_next

    try:  # a model function outside its domain, a stop, Ctrl-C: keep the outputs filled so far
        while k < len(t_out):
            hook.start_call(t_out[k])
            try:
                res = solver.step(float(t_out[k]), method="normal", tstop=t_end)
            except Switch as switch:  # phc's choice of the maximum order changed (simulation/order.py)
                solver, init = restart(switch)
                max_order = choice.order
                k = 1 if switch.rewind else k
                if switch.rewind:
                    bridges.forget()
                hook.evaluations_seen = calls.evaluations
                if not init.success:
                    ok, message = False, f"IDA could not go on at max_order {choice.order} at t = {switch.t:.6g}: " \
                        f"{init.message}"
                    break
                continue
            except _Stop as stop:  # the monitor's warning: a rank drop of the position constraints is bridged
                if stop.max_steps or not (monitor.positional or stop.rank_drop):
                    raise
                k_next = bridge_over(monitor.stop_time, origin=(k, stop.message))
                if k_next is None:
                    k, given_up = bridges.give_up(k, stop.message)
                    raise _Stop(given_up) from None
                k = k_next
                if bridges.event is not None:
                    event = bridges.event
                    break
                continue
            status, t_now = int(res.status), float(res.t)
            if status < 0:
                if calls.failed_last:  # IDA gave up where the model cannot be evaluated
                    raise calls.error
                ok = False
                monitor.positional = False
                approach = _approaching_singularity(monitor, hook.h_ref)
                positional = approach is not None and monitor.positional
                positional = positional or bridges.restarted_at(hook.normal[0])  # IDA failed restarting after one
                if not positional:  # the looks since a restart, or rare looks, may be too few to show the fall
                    positional = any(near_rank_drop(monitor, *state, hook.h_ref or bridges.h_ida)  # (h_ref 0: restarted)
                                     for state in (hook.latest(), hook.normal))
                # near a rank drop of the position constraints IDA's last steps carry momenta and
                # constraint forces far above their scales: that is the singular configuration, not
                # a solution growing without bound (the N = 8 four-bar was blamed on a coupler's
                # momentum "growing without bound" when the monitor had looked rarely before it)
                hint = None if positional else (growth() or _STATUS_HINTS.get(status))
                if hint is not None:
                    approach = None
                if approach is None and hint is None and not positional:
                    # a rank drop ahead, not yet near: no tolerance is the remedy
                    approach = _approaching_singularity(monitor, hook.h_ref, AHEAD, far=1.0, positional=True)
                    positional = approach is not None
                if approach is not None:
                    hint = approach
                elif hint is None:  # diagnose before blaming: is the iteration matrix singular there?
                    cj = calls.cj
                    hint = diagnose_failure(mod, p, *hook.normal, status=status, h_typical=hook.h_ref,
                                            h_fail=(1.0 / cj) if cj > 0 else hook.h_last,
                                            max_order=max_order, rtol=rtol, atol=atol, names=names,
                                            scales=nominal, local=local)
                message = failure = f"IDA failed at t = {t_now:.6g} (status {status}: {res.message}); {hint}"
                if positional:  # bridged by the midpoint rule when the motion passes it
                    k_next = bridge_over(origin=(k, failure))
                    if k_next is not None:
                        message = "integration finished"
                        ok = True
                        k = k_next
                        if bridges.event is not None:
                            event = bridges.event
                            break
                        continue
                    k, message = bridges.give_up(k, message)
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
        ok, message, used_up = False, stop.message, stop.max_steps
        grows = growth() if stop.max_steps else None
        if grows:
            message = (f"stopped after {hook.steps} steps at t = {hook.t_last:.6g}: {grows}; results up to "
                       f"t = {t_out[k - 1]:.6g} are kept")
        if monitor.stop_time is not None:
            # the configuration may lie before outputs already filled in: keep none past it
            k = max(1, min(k, int(np.searchsorted(t_out, monitor.stop_time, side="right"))))
    except ModelEvaluationError as err:
        grows = growth()
        ok, message = False, (f"IDA: {err}; results up to t = {t_out[k - 1]:.6g} are kept" if grows is None else
                              f"IDA failed at t = {hook.t_last:.6g}: {grows}; then {err}; results up to "
                              f"t = {t_out[k - 1]:.6g} are kept")
    except KeyboardInterrupt:
        ok, interrupted = False, True
        message = f"interrupted at t = {t_out[k - 1]:.6g}"
    note = scales(not ok, k) if not message.startswith(("stopped ", "interrupted")) else None
    if note:
        message = f"{message}; {note}"
    # the callbacks' counts: scikit-sundae's (res.nfev, res.njev) are lost with a call that raises
    if bridges.records:
        message = f"{message}; {bridges.notice()}"
    return BackendRun(t_out[:k], ys[:k], yps[:k], steps=hook.steps, nfev=calls.evaluations + bridges.nfev,
                      njev=calls.jacobians, success=ok, event=event, events=bridges.events(),
                      message=message, cpu=time.process_time() - start, conditioning=monitor.worst,
                      interrupted=interrupted, extra=dict(max_steps_reached=used_up, t_reached=hook.t_last,
                                                          max_order=choice.order, order_note=choice.note(),
                                                          max_order_chosen=choice.order if choice.decided else None))
