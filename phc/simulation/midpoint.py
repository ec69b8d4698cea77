"""Implicit midpoint rule for the pH-DAE ``F(t, y, ẏ) = 0`` (structure preserving).

One step solves ``F(t_n + h/2, (y_n + y_{n+1})/2, (y_{n+1} − y_n)/h) = 0`` for ``y_{n+1}``.
For a quadratic Hamiltonian the discrete energy balance
``H(y_{n+1}) − H(y_n) + h·(P_ports + P_diss)(midpoint) = 0`` holds exactly (to the Newton
tolerance), for any step size: ``H(y_{n+1}) − H(y_n) = ∇H(y_mid)·(y_{n+1} − y_n)`` for
quadratic H, and power-isotropy of the Dirac structure (the paper's Definition 1; the
balance is its Remark 3 "Energy balance") at the one point ``y_mid`` where every
row of F is evaluated — modulations, constraints and multipliers included — does the rest.
The energy accumulator of the DAE is integrated by the same rule, so the reported balance
residual is the discrete one. Velocity-level constraints are imposed at the midpoints, the
position constraints ``g(q) = 0`` of the GGL formulation (of the paper's rigid multibody
DAE, eq. (3)) at the step ends, so they do not drift (:class:`StageSolver`);
invariants that are not rows of F are projected back at the step ends (:class:`Projector`).
Non-quadratic Hamiltonians: see :mod:`phc.simulation.discrete_gradient`.

Linear algebra (why it is cheap)
--------------------------------
The Newton matrix of a step evaluated at ``s`` along the segment is
``s·F_y + F_ẏ/h = s·(F_y + c_j F_ẏ)`` with ``c_j = 1/(s h)``, i.e. the generated
``jacobian`` scaled by ``s``. It is factorized by sparse LU and *reused* across Newton
iterations and steps (simplified Newton, as in Radau IIA codes): a fresh Jacobian is
factorized only when the contraction rate of the iteration degrades
(:data:`REFACTOR_RATE`), when the step size changes, or after :data:`MAX_AGE` steps.
Exactness is unaffected: the residual is always evaluated exactly, so the converged step
is the same — only the iteration count changes.

The module is over 800 lines because the Python loop and what it does after each step
(:func:`finish_step`: a retry, a split, the singularity monitor's look, a passage of a rank
drop) are one piece, which the compiled loops' driver calls for the steps it hands back; the
passage logic is the part to move out when it gains the velocity projection that
``docs/hard-cases.md`` describes as still open.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sps

from phc.simulation import step_logic, undetermined
from phc.simulation.backend import BackendRun
from phc.simulation.chord import ChordIteration, max_norm
from phc.simulation.guard import ModelEvaluationError
from phc.simulation.monitor import SingularityMonitor, unbounded_growth
from phc.simulation.sparse_lu import csc_structure, sparse_lu

NEWTON_TOL = 1e-14
"""Newton stops when the estimated error ``θ/(1−θ)·|Δ|`` of the iterate is below this, in
the scaled variables ``y_j / s_j`` (:mod:`phc.simulation.scaling`; without scales,
relative to ``|y| + 1``); stagnation at round-off level is accepted as well."""
MAX_NEWTON = 30
"""Iterations of one step (refactorizations included) before the step is declared failed."""
REFACTOR_RATE = 0.25
"""Contraction rate θ = |Δ_k|/|Δ_{k−1}| above which the Newton matrix is refreshed."""
ROUNDOFF_FLOOR = 1e-9
"""A correction of the states this small (in the scaled variables) that a freshly factorized
matrix cannot reduce is round-off amplified by the matrix's conditioning: the iterate is
accepted, and the driver asks the singularity monitor. Only the states count here: near a
singular configuration the constraint forces are determined far worse than the motion (a
four-bar near its change point: the coupler's angle to 4e-11, its pin forces to much less),
and they are recomputed at the output times anyway."""
MAX_AGE = 200
"""Steps after which the Newton matrix is refreshed regardless (state-dependent Jacobians)."""
ROUNDOFF_ZONE = 1e3
"""Corrections below this many times the Newton tolerance (relative) can be at the round-off
level of stiff rows: the constraint forces of a mechanism are determined only to ~1e-12 of
their size (their last digits are round-off amplified like 1/h). There a stagnating
iteration is accepted (:data:`STAGNATION_JUMP`)."""
STAGNATION_JUMP = 10.0
"""In the round-off zone, the iteration stagnates when its rate θ = |Δ_k|/|Δ_{k−1}| reaches
0.5, or jumps to this many times the smallest rate of this solve with this matrix: so close
to the solution the iteration is linear and keeps its rate, unless round-off makes the
corrections random (then a refactorization, which the jump would trigger, cannot help).
The iterate is accepted; its correction is below ``ROUNDOFF_ZONE·NEWTON_TOL``, as the
stagnation test at θ ≥ 0.5 alone required."""
PREDICTOR_ORDER = 2
"""Degree of the polynomial through the last step midpoints ``m = (y_n + y_{n+1})/2`` that
predicts the next midpoint of a differential variable, the start of Newton
(:func:`predict_midpoint`); 1 is the linear extrapolation. Only the start changes, not the
converged step. On smooth solutions it saves iterations (the mass–spring–damper at h = 0.01:
2.68 residual evaluations a step instead of 2.98); on the flexible slider–crank, whose rod
modes up to 4e5 rad/s the step does not resolve, it saves refactorizations (the linear
predictor's error there makes the first contraction rates poor, which refreshes the matrix:
0.03 instead of 0.05 factorizations a step, for a few more iterations with the older matrix;
the pendulum at h = 1e-3 likewise refactorizes every tenth step instead of every step).
Where a factorization costs less than an iteration or two, that trade can cost time."""
PREDICTOR_ORDER_ALGEBRAIC = 1
"""The same for the algebraic variables (0: the last midpoint). Their midpoints are not
smooth (constraint forces follow the unresolved modes): a quadratic extrapolation doubled
the first correction of the rigid slider–crank's joint force."""
MAX_PREDICTOR_ORDER = 4


def predict_midpoint(times, mids, t_new, order=None):
    """The polynomial of degree ``min(order, len(times) − 1)`` through the last midpoints
    ``mids`` (newest last) at the times ``times``, evaluated at ``t_new``
    (:func:`phc.simulation.step_logic.polynomial`, what both loops' predictor evaluates)."""
    order = PREDICTOR_ORDER if order is None else order
    k = min(int(order) + 1, len(times))
    ts = np.array([float(x) for x in times[len(times) - k:]][::-1])  # newest first
    ms = np.array(list(mids[len(mids) - k:])[::-1], dtype=float)
    return step_logic.polynomial(ts, ms, k, t_new)


def driver_constants(c=None) -> np.ndarray:
    """The constants vector of :mod:`phc.simulation.step_logic` (a new one, or `c` filled in) with
    the driver's numbers: the predictor's degrees and the monitor's period, this module's
    constants as they are at the call."""
    c = np.zeros(step_logic._NC) if c is None else c
    c[step_logic._EVERY] = MONITOR_EVERY
    c[step_logic._ORDER] = min(max(int(PREDICTOR_ORDER), 0), MAX_PREDICTOR_ORDER)
    c[step_logic._ORDER_ALG] = min(max(int(PREDICTOR_ORDER_ALGEBRAIC), 0), MAX_PREDICTOR_ORDER)
    return c


class NewtonMatrix:
    """Sparse LU of the Newton matrix of a step, cached between steps.

    Rows ``F_i`` evaluated at the stage point contribute ``s·(F_y + c_j F_ẏ)`` with
    ``c_j = 1/(s h)``; the position-constraint rows ``end_rows``, imposed at the step end,
    contribute ``g_y(y_{n+1})``."""

    def __init__(self, mod, p, end_rows=(), nominal=None):
        self.mod, self.p, self.n = mod, p, mod.N
        self.nominal = None if nominal is None else np.asarray(nominal, dtype=float)
        """Scales of the unknowns in which the Newton test measures corrections (0: none)."""
        rows = np.asarray(mod.JAC_ROWS)
        # JAC_ROWS/JAC_COLS are in CSC order: the structure is built once
        self.indices, self.indptr, self.col_of = csc_structure(rows, mod.JAC_COLS, self.n)
        self.buf = np.zeros(len(rows))
        self.end_mask = np.isin(rows, np.asarray(end_rows, dtype=int))
        self.end_buf = np.zeros(len(rows)) if self.end_mask.any() else None
        """The Jacobian at the step's end, for the position-constraint rows (None without any)."""
        self.lu = None
        self.h = self.s = None
        self.age = 0
        self.factorizations = 0
        self.pinv = None
        self.pseudo_inverses = 0
        """Factorizations that took the least-norm correction (at a rank drop)."""
        self.least_norm = False
        """Factorize for the least-norm correction (:meth:`_least_norm`), not by LU."""
        self.end_rows_index = np.asarray(end_rows, dtype=int)

    def factor(self, t, h, y, y1, s=0.5) -> bool:
        """Factorize for the iterate ``y1`` of the step from ``(t, y)``; False if singular."""
        d = y1 - y
        self.mod.jacobian(t + s * h, y + s * d, d / h, self.p, 1.0 / (s * h), self.buf)
        data = self.buf  # scaled in place: J's data (the next factorization writes it afresh)
        data *= s
        if self.end_buf is not None:
            self.mod.jacobian(t + h, y1, d / h, self.p, 1.0 / (s * h), self.end_buf)
            data[self.end_mask] = self.end_buf[self.end_mask]
        J = sps.csc_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))
        self.factorizations += 1
        self.row_scale, self.col_scale = equilibration(J, self.nominal, col_of=self.col_of)
        # D_r J D_c on J's own data (the scales are powers of two: exact in any order), without
        # the stored zeros, as the sparse products D_r @ J @ D_c left it; no copies of the
        # matrix beside its LU (a mesh of 10⁵ elements: 5·10⁶ entries)
        data *= self.row_scale[self.indices]
        data *= self.col_scale[self.col_of]
        J = sps.csc_matrix((data, self.indices.copy(), self.indptr.copy()), shape=(self.n, self.n))
        J.eliminate_zeros()
        self.pinv = None
        self.lu = None  # the last factors freed before the new ones are made (a mesh's run peaks here)
        if self.least_norm:
            return self._least_norm(J, h, s)
        try:
            self.lu = sparse_lu(J)
        except RuntimeError:
            self.lu = None
            return False
        self.h, self.s, self.age = h, s, 0
        return True

    def _least_norm(self, J, h, s) -> bool:
        """The least-norm inverse of the equilibrated matrix J at a rank drop of the position
        constraints: from its SVD ``U Σ Vᵀ``, the directions with ``σ_i`` below
        :data:`LEAST_NORM_RTOL` of the largest whose left singular vector lies mostly (more than
        half its square) in the position-constraint rows are dropped; every other direction is
        inverted as the LU would. False (a singular step, as before) when there is none to drop,
        or the matrix is too large for a dense SVD."""
        if self.n > LEAST_NORM_LIMIT:
            self.lu = None
            return False
        dense = J.toarray()
        if not np.all(np.isfinite(dense)):
            self.lu = None
            return False
        u, sigma, vt = np.linalg.svd(dense)
        in_rows = (u[self.end_rows_index] ** 2).sum(axis=0) if len(self.end_rows_index) else np.zeros(len(sigma))
        weak = (sigma <= LEAST_NORM_RTOL * sigma[0]) & (in_rows > 0.5)
        if not weak.any() or (sigma[~weak] <= 0.0).any():
            self.lu = None
            return False
        keep = ~weak
        self.pinv = (vt[keep].T / sigma[keep]) @ u[:, keep].T
        self.lu = True  # factorized (the pseudo-inverse stands in for the LU)
        self.pseudo_inverses += 1
        self.h, self.s, self.age = h, s, 0
        return True

    def solve(self, rhs):
        """``J⁻¹ rhs`` through the LU of the equilibrated ``D_r J D_c``: ``D_c (D_r J D_c)⁻¹ D_r rhs``;
        in least-norm mode ``D_c (D_r J D_c)⁺ D_r rhs`` (:meth:`_least_norm`)."""
        if self.pinv is not None:
            return self.col_scale * (self.pinv @ (self.row_scale * rhs))
        return self.col_scale * self.lu.solve(self.row_scale * rhs)


LEAST_NORM_RTOL = 1e-6
"""At a rank drop of the position constraints' Jacobian (a mechanism passing a singular
configuration: the N four-bar with all bars horizontal), a Newton iteration that failed is
retried with the directions of the equilibrated Newton matrix that are weaker than this
fraction of the strongest, and lie in the position-constraint rows, dropped: the least-norm
correction, whose multipliers are the minimal-norm ones (J. García de Jalón, E. Bayo,
"Kinematic and Dynamic Simulation of Multibody Systems", Springer 1994, ch. on redundant
constraints). The value is the singularity monitor's threshold for a hard step
(:data:`HARD_STEP_THRESHOLD`): what it would call singular is not solved for."""
LEAST_NORM_LIMIT = 2000
"""Newton matrices with more unknowns than this get no dense SVD at a rank drop (the step
fails as before)."""


def _power_of_two_below(big: np.ndarray) -> np.ndarray:
    """1/2^e with 2^e ≤ big < 2^(e+1) (1 where big is 0): an exact scaling to [1, 2)."""
    exponent = np.frexp(np.where(big > 0.0, big, 1.0))[1] - 1
    return np.ldexp(1.0, -exponent)


def equilibration(J: sps.spmatrix, nominal=None, col_of=None) -> tuple[np.ndarray, np.ndarray]:
    """Column scales ``D_c`` and row scales ``D_r`` (powers of two, so scaling is exact) for the
    LU of ``D_r J D_c``.

    The columns are the unknowns in the units the Newton test measures them in: ``D_c`` is the
    nominal scale ``s_j`` of unknown j where ``nominal[j] > 0``; the other columns are brought
    to a largest entry in [1, 2) (as LAPACK's ``dgeequ`` does). Then every row's largest entry
    is brought into [1, 2).

    Why: LU with partial pivoting is normwise backward stable, so the error of a correction is
    small relative to the largest correction *in the columns' units*. On the unscaled matrix
    that unit is the model's: a state with an exponential energy puts entries of 1e24 in the
    energy accumulator's row, that row takes the pivot of every column it touches, and the
    correction of a state is a difference of two numbers of the accumulator's size — it came
    out exactly 0 with one BLAS kernel and not with another, and Newton, which measures the
    state in its own scale, saw no correction and accepted a step that was off by 15. Measured
    in the Newton test's units, the pivots compare like with like.

    Not :func:`phc.simulation.equilibrate.equilibrate` (the dense alternating scaling): the
    columns are the Newton test's units rather than a balance of the matrix, the pass is one,
    columns first, with scales rounded down to a power of two, on the sparse matrix, and the
    numba and C step kernels repeat exactly this arithmetic so that their LU matches."""
    J = J.tocsc(copy=False) if sps.issparse(J) else sps.csc_matrix(J)
    m, n = J.shape
    # on the CSC arrays (scipy's max(axis=...) and a scaled copy cost ~0.2 ms a factorization,
    # more than the LU of a small model); duplicate entries count as their largest part
    size = np.abs(J.data)
    if col_of is None:  # each entry's column (the caller's, where it keeps J's structure)
        col_of = np.repeat(np.arange(n), np.diff(J.indptr))
    col_max = np.zeros(n)
    np.maximum.at(col_max, col_of, size)
    cols = _power_of_two_below(col_max)
    if nominal is not None:
        nominal = np.asarray(nominal, dtype=float)
        given = (nominal > 0) & np.isfinite(nominal)
        cols[given] = 1.0 / _power_of_two_below(nominal[given])
    row_max = np.zeros(m)
    size *= cols[col_of]
    np.maximum.at(row_max, J.indices, size)
    rows = _power_of_two_below(row_max)
    return rows, cols


def newton_weights_of(scales, mod=None):
    """Weights of the Newton test from nominal scales `s` (:mod:`phc.simulation.scaling`), or
    None without them: ``1/s`` on differential variables, 0 on algebraic ones (:func:`phc.
    simulation.scaling.newton_weights`)."""
    if scales is None:
        return None
    from phc.simulation.scaling import weights_from_scales

    return weights_from_scales(scales, None if mod is None else mod.DIFFERENTIAL)


def constraint_rows(mod) -> np.ndarray:
    """Rows of F that are position invariants g(y) = 0 (GGL formulation), in INVARIANTS order."""
    eqs = list(mod.EQUATIONS)
    labels = list(getattr(mod, "INVARIANTS", ()))
    if not labels or not all(label in eqs for label in labels):
        return np.array([], dtype=int)
    return np.array([eqs.index(label) for label in labels], dtype=int)


class StageSolver:
    """Solves ``F(t + s h, y + s (y1 − y), (y1 − y)/h) = 0`` for ``y1`` by simplified Newton,
    with the position-constraint rows replaced by ``g(t + h, y1) = 0``.

    ``s = 1/2`` is the implicit midpoint rule; the discrete-gradient step moves ``s``.
    Imposing the position constraints at the step ends (and the velocity constraints and
    everything else at the stage point) keeps them drift-free to the Newton tolerance; for
    constraints quadratic in the positions (a Cartesian pendulum, a chord length)
    ``g(q_{n+1}) − g(q_n) = G(q_mid)(q_{n+1} − q_n)`` makes the GGL multiplier η vanish, so
    it does no work and the midpoint energy balance stays exact.

    The iteration is :func:`phc.simulation.step_logic.newton`, the code the compiled loop runs as
    well; this class gives it its operations on the sparse LU of :class:`NewtonMatrix`.
    """

    def __init__(self, mod, p, end_constraints=True, weights=None):
        self.mod, self.p = mod, p
        self.weights = None if weights is None else np.asarray(weights, dtype=float)
        # algebraic variables tested as before (relative to |y| + 1), except the GGL multipliers:
        # zero on exact solutions, their values and corrections are round-off amplified like 1/h
        algebraic = np.flatnonzero(~np.asarray(mod.DIFFERENTIAL, dtype=bool))
        if "\nggl." in "\n" + "\n".join(map(str, mod.VARIABLES)):  # names looked at only then
            algebraic = algebraic[[not str(mod.VARIABLES[j]).startswith("ggl.") for j in algebraic]]
        self.algebraic = algebraic.astype(np.int64)
        """``1/s``: the Newton test runs on the scaled variables (:mod:`phc.simulation.scaling`)."""
        self.end_rows = constraint_rows(mod) if end_constraints else np.array([], dtype=int)
        nominal = None
        if self.weights is not None:
            nominal = np.where(self.weights > 0, 1.0 / np.where(self.weights > 0, self.weights, 1.0), 0.0)
        self.matrix = NewtonMatrix(mod, p, self.end_rows, nominal)
        self.res = np.zeros(mod.N)
        self.nfev = 0
        self.singular = False
        self.refreshed = False
        self.ill_conditioned = False
        self.evaluation_error = None
        """The :class:`~phc.errors.ModelEvaluationError` that stopped the last solve, if any."""
        self.constants = newton_constants()
        self.least_norm_steps = 0
        """Solves that needed the least-norm correction (a rank drop of the position constraints)."""
        self.completed_steps = 0
        """Least-norm solves whose result the full iteration improved (:meth:`_complete`)."""
        self.restart_near = False
        """Whether the least-norm retry may start from the failed iteration's last iterate
        (:meth:`_closer_start`): set by the `midpoint`, `discrete_gradient` and `midpoint4` runs and
        the IDA bridge (:mod:`phc.simulation.ida_bridge`; with the predictor its steps at the N = 10
        four-bar's passages failed the step-doubling check at the step the tolerance asks)."""

    def residual(self, t, h, y, y1, s):
        d = y1 - y
        self.mod.residual(t + s * h, y + s * d, d / h, self.p, self.res)
        if len(self.end_rows):
            self.res[self.end_rows] = self.mod.invariants(t + h, y1, self.p)
        self.nfev += 1
        return self.res

    def solve(self, t, h, y, y1, s=0.5):
        """Return ``(y1, converged)``; ``self.singular`` tells a singular Newton matrix,
        ``self.evaluation_error`` a model function that could not be evaluated at an iterate
        (outside its domain: a shorter step may stay inside)."""
        out = np.array(y1, dtype=float)
        return out, self.solve_into(t, h, y, y1, s, out) == step_logic._OK

    def solve_into(self, t, h, y, y1, s, out) -> int:
        """The solve of :meth:`solve` into `out` (the start `y1` where a model function could not
        be evaluated): the outcome code of :func:`phc.simulation.step_logic.newton`."""
        self.evaluation_error = None
        self.singular = self.refreshed = self.ill_conditioned = False
        try:
            code, self.ill_conditioned = step_logic.newton(self, 0, self.constants, t, h, y, y1, s, out)
            if code in (step_logic._FAIL, step_logic._SINGULAR) and len(self.end_rows):
                code = self._least_norm_retry(t, h, y, y1, s, out, code)
        except ModelEvaluationError as err:
            self.evaluation_error = err
            out[...] = y1
            return step_logic._EVAL
        return code

    def _least_norm_retry(self, t, h, y, y1, s, out, code) -> int:
        """The solve again from `y1`, with the least-norm correction at a rank drop of the position
        constraints (:meth:`NewtonMatrix._least_norm`); `code` if that finds nothing to drop or
        fails too. A step so solved is flagged ill-conditioned: the driver asks the singularity
        monitor, which lets the run go on only if the motion through it is determined
        (:func:`passes_rank_drop`)."""
        matrix = self.matrix
        start = self._closer_start(t, h, y, y1, s, out)
        matrix.least_norm, matrix.lu = True, None
        try:
            retry, _ = step_logic.newton(self, 0, self.constants, t, h, y, start, s, out)
        finally:
            matrix.least_norm, matrix.lu, matrix.pinv = False, None, None
        if retry != step_logic._OK:
            return code
        self._complete(t, h, y, s, out)
        self.singular = False
        self.ill_conditioned = True
        self.least_norm_steps += 1
        return retry

    def _closer_start(self, t, h, y, y1, s, last) -> np.ndarray:
        """Where the least-norm iteration starts: the failed iteration's last iterate `last` where
        it leaves a smaller residual of the step's equations (rows scaled as in the Newton
        matrix) than the start `y1`, and one at round-off (:data:`ROUNDOFF_ZONE` times
        :data:`NEWTON_TOL`), else `y1`. At a passage the full iteration typically
        stagnates next to the solution — residual at round-off, the states' corrections a few
        times :data:`ROUNDOFF_FLOOR`, amplified by the near rank drop — and in the directions the
        least-norm correction drops, the iterate keeps what its start put there: from the
        predictor (the constant one for a step the compiled loops hand back), the N four-bar
        with ten loops ended up a tenth of the step's change away from the solution the full
        iteration then found, and the step was left to the monitor, which stopped the run."""
        if not self.restart_near or not np.all(np.isfinite(last)):
            return y1
        scale = getattr(self.matrix, "row_scale", None)
        scale = 1.0 if scale is None else scale
        try:
            at_last = float(np.abs(scale * self.residual(t, h, y, last, s)).max())
            at_start = float(np.abs(scale * self.residual(t, h, y, y1, s)).max())
        except ModelEvaluationError:
            return y1
        # only an iterate at round-off (a stagnation next to the solution): elsewhere a failed
        # iteration's iterate is no better a start than the predictor (an IDA bridge at IDA's
        # collapsed step went astray from such starts)
        near = at_last <= ROUNDOFF_ZONE * NEWTON_TOL
        return last.copy() if np.isfinite(at_last) and at_last < at_start and near else y1

    def _complete(self, t, h, y, s, out) -> None:
        """Solve the rows the least-norm iteration left out: the full Newton iteration (LU of the
        whole matrix) from its result `out`, taken when it leaves a smaller residual of the step's
        equations (rows scaled as in the Newton matrix) than the least-norm result.

        Why: the least-norm correction drops the weak directions, and with them the part of the
        position constraints' residual along them; in those directions the iterate keeps what
        its start put there. At the N four-bar's passage these are the relative turns of
        neighbouring cranks (the null directions of the end constraints' Jacobian): with N = 10
        the least-norm steps ended with the constraints violated by 3e-10 to 3e-8 and the cranks
        up to 7e-6 rad apart — a value set by the start (the predictor in the Python loop, the
        constant predictor of a step the compiled loops hand back, round-off) — and the next
        regular step pulled them back together with a constraint impulse that changed the
        energy and so the phase (crank 0 off the exact motion by 3e-4 rad with NumPy, 2.4e-2 rad
        with C). Started there, the full iteration reaches the step's solution on the branch
        (residual ~1e-12, the cranks together to round-off) even where its stopping test,
        spoiled by the weakly determined multipliers, does not say so; hence the residual
        decides. It must also agree with the least-norm result on the states to the fraction
        :data:`RANK_DROP_AGREEMENT` of the step's change, the agreement that tells one motion
        through a rank drop (N = 10: it moves them by 2e-3 to 2e-2 of the change, the impulse
        of the constraint forces the least-norm step left out); a larger move would be another
        motion, and the least-norm result is kept for the monitor to judge. Where the
        least-norm result already solves every row (the one passage step of the N = 1
        four-bar), nothing changes."""
        matrix = self.matrix
        start = out.copy()
        before = self.residual(t, h, y, start, s).copy()
        trial = start.copy()
        matrix.lu, matrix.pinv = None, None
        try:
            step_logic.newton(self, 0, self.constants, t, h, y, start, s, trial)
            after = self.residual(t, h, y, trial, s)
        except ModelEvaluationError:
            return
        finally:
            matrix.lu, matrix.pinv = None, None  # the next step factorizes afresh
        scale = matrix.row_scale
        if not (np.all(np.isfinite(after)) and np.abs(scale * after).max() < np.abs(scale * before).max()):
            return
        diff = np.asarray(self.mod.DIFFERENTIAL, dtype=bool)
        change = float(np.abs(start - y)[diff].max(initial=0.0))
        if float(np.abs(trial - start)[diff].max(initial=0.0)) > RANK_DROP_AGREEMENT * change:
            return  # another motion, not the same one with other constraint forces: left to the monitor
        out[...] = trial
        self.completed_steps += 1

    # the operations of phc.simulation.step_logic.newton on this solver (its only Newton matrix: m = 0)

    def begin(self, m):
        matrix = self.matrix
        matrix.age += 1
        return matrix.lu is not None, matrix.h, matrix.s, matrix.age

    def refactor(self, m, t, h, y, y1, s) -> int:
        self.refreshed = True  # set when the matrix is factorized in this step
        ok = self.matrix.factor(t, h, y, y1, s)
        self.singular = not ok
        return step_logic._OK if ok else step_logic._SINGULAR

    def correct(self, m, t, h, y, y1, s):
        """The correction and its size: without weights, max |Δ| against 1 + max |y|; with
        them, the differential variables scaled (a state against its scale or its size,
        whichever is larger) and the algebraic ones as before, relative to |y| + 1."""
        delta = self.matrix.solve(-self.residual(t, h, y, y1, s))
        if self.weights is None:
            size, scale = float(np.abs(delta).max()), 1.0 + float(np.abs(y1).max())
            states = size
        else:
            algebraic = float(np.abs(delta[self.algebraic]).max(initial=0.0)) / (1.0 + float(np.abs(y1).max()))
            w = self.weights / (1.0 + np.abs(y1) * self.weights)
            states = float(np.abs(delta * w).max())
            size, scale = max(states, algebraic), 1.0
        return step_logic._OK, delta, size, states, scale, bool(np.isfinite(size)), False


class Stages:
    """The workspace of :func:`phc.simulation.step_logic.discrete_gradient` and
    :func:`~phc.simulation.step_logic.midpoint4` in the Python loop: one :class:`StageSolver`
    per Newton matrix m."""

    def __init__(self, *solvers):
        self.solvers = solvers

    def solve_stage(self, m, t, h, y, y1in, s, out):
        """The stage solve with matrix m into `out`: ``(code, ill_conditioned)``."""
        stage = self.solvers[m]
        return stage.solve_into(t, h, y, y1in, s, out), stage.ill_conditioned


def newton_constants(c=None) -> np.ndarray:
    """The constants vector of :mod:`phc.simulation.step_logic` (a new one, or `c` filled in) with
    the Newton iteration's numbers, this module's constants as they are at the call."""
    c = np.zeros(step_logic._NC) if c is None else c
    c[step_logic._TOL], c[step_logic._RATE], c[step_logic._FLOOR] = NEWTON_TOL, REFACTOR_RATE, ROUNDOFF_FLOOR
    c[step_logic._MAX_AGE], c[step_logic._MAX_NEWTON] = MAX_AGE, MAX_NEWTON
    c[step_logic._ZONE], c[step_logic._STAGNATION] = ROUNDOFF_ZONE, STAGNATION_JUMP
    return c


class Projector:
    """Keeps the position invariants g(y) = 0 at the step ends (the midpoint rule imposes the
    constraints at the midpoints only): a minimum-norm Gauss–Newton correction of the
    differential variables g depends on. The invariant Jacobian G is computed by finite
    differences once and reused (:class:`~phc.simulation.chord.ChordIteration`) until the
    iteration contracts slowly (by less than :data:`CONTRACTION`); a slow step with a fresh
    G means the residual is at round-off, and the projection stops there. Energies that do
    not depend on those variables (kinetic energies, the beam's) are untouched, so the
    discrete energy balance stays exact. Used only when the invariants are not rows of F
    (otherwise :class:`StageSolver` imposes them at the step ends)."""

    TOL = 1e-14
    """The projection stops when max |g| is below this fraction of the size of the
    invariants' terms (:meth:`_size`)."""
    STEPS = 8
    """Most chord steps tried per projection."""
    CONTRACTION = 0.1
    """A step that shrinks max |g| by less than this factor refreshes G (once per projection)."""
    RCOND = 1e-12
    """Singular values of G below this fraction of the largest are dropped (G is a
    finite-difference Jacobian: smaller ones are its truncation error)."""

    def __init__(self, mod, p, y, t=0.0, scales=None):
        self.mod, self.p = mod, p
        # sizes of the variables (the nominal scales, else 1): finite-difference steps and the
        # convergence test are relative to them
        self.scales = None if scales is None else np.asarray(scales, dtype=float)
        size = np.ones(mod.N) if scales is None else self.scales
        self._fd = size
        diff = np.flatnonzero(np.asarray(mod.DIFFERENTIAL))
        g0 = mod.invariants(t, y, p)
        cols = []
        for j in diff:  # the variables the invariants depend on (probe once)
            yh = y.copy()
            yh[j] += 1e-6 * max(size[j], abs(y[j]))
            if np.abs(mod.invariants(t, yh, p) - g0).max() > 0:
                cols.append(j)
        self.cols = np.array(cols, dtype=int)
        self.chord = ChordIteration(rtol=self.RCOND)
        self._g_size = None

    def _size(self, x) -> float:
        """What the invariants' residual is measured against: with nominal scales, the size of
        their terms ``|G| (|y| + s)`` (known once G is), else ``1 + |y|`` (x: y at the
        columns of G)."""
        if self._g_size is None:
            return 1.0 + float(np.abs(x).max())
        return self._g_size

    def _jacobian(self, t, y, x, g):
        """G at y with ``y[cols] = x`` (finite differences from g there)."""
        y = y.copy()
        y[self.cols] = x
        if g is None:
            g = self.mod.invariants(t, y, self.p)
        G = np.empty((len(g), len(self.cols)))
        for c, j in enumerate(self.cols):
            h = 1e-7 * max(self._fd[j], abs(y[j]))
            yh = y.copy()
            yh[j] += h
            G[:, c] = (self.mod.invariants(t, yh, self.p) - g) / h
        if self.scales is not None:
            size = np.abs(G) @ (np.abs(y[self.cols]) + self.scales[self.cols])
            self._g_size = float(size.max()) if size.size and size.max() > 0 else None
        return G

    def project(self, t, y):
        if not len(self.cols):
            return y

        def residual(x):
            yx = y.copy()
            yx[self.cols] = x
            return self.mod.invariants(t, yx, self.p)

        out = self.chord.solve(y[self.cols], residual, lambda x, g: self._jacobian(t, y, x, g),
                               steps=self.STEPS, contraction=self.CONTRACTION, norm=max_norm, slow_stops=True,
                               converged=lambda x, size: size <= self.TOL * self._size(x))
        y = y.copy()
        y[self.cols] = out.x
        return y


def make_projector(mod, p, y, t=0.0, scales=None):
    """The projector for invariants the stage solver does not impose at the step ends, or None."""
    if not len(getattr(mod, "INVARIANTS", ())) or len(constraint_rows(mod)):
        return None
    return Projector(mod, p, y, t, scales)


def integrate_fixed_step(mod, p, t_out, y0, yp0, *, max_steps, progress, step, advance, name, project=True,
                         names=None, events=None, scales=None):
    """Fixed-step driver shared by the structure-preserving backends.

    ``advance(t, h, y, guess) -> (y1, ok, reason)`` takes one step. Output at every
    ``t_out`` (each output interval is split into equal steps no longer than ``step``).
    The :class:`~phc.simulation.monitor.SingularityMonitor` looks at the iteration matrix
    every :data:`MONITOR_EVERY` steps and at every step Newton found hard (a restart, a
    split or a failure): a run through a configuration where an interconnection loses
    surjectivity stops there instead of stepping over it. Returns a
    :class:`~phc.simulation.backend.BackendRun`, as the IDA backend.

    `events` (a :class:`phc.simulation.events.Watch`, optional) are switching functions
    w(t, y, ẏ), positive while the modes hold: a step at whose end one has fallen to zero
    or below is shortened by regula falsi (Illinois) on its length until the crossing is
    located to :data:`EVENT_TOL`; the run then returns with ``event`` = dict(t, y, yp,
    which) and the outputs before it.

    The routine bookkeeping of a step — the output grid and its substeps, the predicted midpoint
    that starts Newton, when the monitor looks, the acceptance — is
    :mod:`phc.simulation.step_logic`'s (``next_step``, ``predict``, ``looks``, ``accept``), the code
    the compiled loop's chunk runs; what is left here is what that chunk hands back.

    A passage of a rank drop is judged by :func:`passes_rank_drop` with the run's rate before the
    step (:func:`finish_step`), in every caller: the fixed-step solvers and the IDA bridge
    (:mod:`phc.simulation.ida_bridge`), which runs this driver."""
    sl = step_logic
    n = mod.N
    t_out = np.asarray(t_out, dtype=float)
    ys, yps = np.empty((len(t_out), n)), np.empty((len(t_out), n))
    ys[0], yps[0] = y0, yp0
    start = time.process_time()
    y = np.array(y0, dtype=float)
    split = 0
    ok, message = True, "integration finished"
    monitor = SingularityMonitor(mod, p, names=names, scales=scales)
    monitor.start = (float(t_out[0]), np.array(y0, dtype=float), np.array(yp0, dtype=float))
    projector = make_projector(mod, p, y, float(t_out[0]), scales) if project else None
    # the state of the step logic's driver (phc.simulation.step_logic: next_step, predict, looks,
    # accept), laid out as the compiled loops keep it
    ist, fst, c = np.zeros(sl._NI, dtype=np.int64), np.zeros(sl._NF), driver_constants()
    ist[sl._K], ist[sl._LAST_LOOK], ist[sl._MAX_STEPS], ist[sl._MONITOR] = 1, -MONITOR_EVERY, max_steps, monitor.enabled
    fst[sl._STEP], fst[sl._H_PREV] = step or 0.0, 1.0
    algmask = (~np.asarray(mod.DIFFERENTIAL, dtype=bool)).astype(np.int8)
    # the last step midpoints (newest first) and their times, the last midpoint and the slope between
    # the last two (ẏ₀ before a second), the step's start before the last
    pt, pm = np.zeros(MAX_PREDICTOR_ORDER + 1), np.zeros((MAX_PREDICTOR_ORDER + 1, n))
    mid, mid_slope, y_prev = np.zeros(n), np.array(yp0, dtype=float), np.zeros(n)
    interrupted = False
    event = None
    rank_drops = []  # [first, last] time of the looks at each rank drop passed
    w_prev = events(float(t_out[0]), y, np.asarray(yp0, dtype=float)) if events is not None else None
    try:
        while ist[sl._K] < len(t_out):
            sl.next_step(t_out, fst, ist)
            t, h = float(fst[sl._T]), float(fst[sl._H])
            guess = np.empty(n)
            sl.predict(y, mid, mid_slope, pt, pm, ist, c, t, h, fst[sl._H_PREV], algmask, guess)
            y_new, converged, reason = advance(t, h, y, guess)
            stage = getattr(advance, "stage", None)
            hard, look = sl.looks(ist, c, converged, stage is not None and stage.ill_conditioned)
            if not converged and events is not None and _crossed(events, t, h, y, y_new, w_prev):
                # a step across a switching surface on the old branch may fail (midpoint4's passivity
                # guard sees the frozen law beyond it): the crossing is before, shorten the step to it
                event = _locate(advance, events, projector, t, h, y, y_new, w_prev,
                                events(t + h, y_new, (y_new - y) / h), None)
                ist[sl._STEPS] += 1
                break
            if look:
                ist[sl._LAST_LOOK] = ist[sl._STEPS]
            y_new, retried, failure, passed = finish_step(advance, monitor, mod, name, t, h, y, y_new, converged,
                                                          reason, hard, look, mid_slope, rank_drops)
            split += retried
            if passed:
                ist[sl._LAST_LOOK] = ist[sl._STEPS] - LOOK_GAP  # look at the passage's next hard step too
            if failure:
                ok, message = False, failure
                break
            y_end = projector.project(t + h, y_new) if projector else y_new
            if events is not None:
                w_new = events(t + h, y_end, (y_end - y) / h)
                crossed = (w_prev > 0) & (w_new <= 0)
                if crossed.any():
                    event = _locate(advance, events, projector, t, h, y, y_end, w_prev, w_new, crossed)
                    ist[sl._STEPS] += 1
                    break
                w_prev = w_new
            k = ist[sl._K]
            if sl.accept(t, h, y, y_new, y_end, y_prev, mid, mid_slope, pt, pm, ys, yps, fst, ist):
                ok, message = False, (f"stopped after {ist[sl._STEPS]} steps at t = {fst[sl._T]:.6g} (max_steps); "
                                      "raise `max_steps` or the step size")
                break
            if progress is not None and ist[sl._K] > k:
                progress(float(fst[sl._T]))
    except ModelEvaluationError as err:
        ok, message = False, f"{name}: {err}; results up to t = {t_out[max(ist[sl._K] - 1, 0)]:.6g} are kept"
    except KeyboardInterrupt:
        ok, interrupted = False, True
        message = f"interrupted at t = {t_out[max(ist[sl._K] - 1, 0)]:.6g}"
    k = max(int(ist[sl._K]) - 1, 0)
    steps = int(ist[sl._STEPS])
    message = closing_message(message, ok, split, rank_drops)
    return BackendRun.from_mapping(dict(t=t_out[:k + 1], y=ys[:k + 1], yp=yps[:k + 1], steps=steps, success=ok,
                                        message=message, cpu=time.process_time() - start, interrupted=interrupted,
                                        event=event, rank_drops=[a for a, _ in rank_drops]))


LOOK_GAP = step_logic.LOOK_GAP
"""A step Newton found ill-conditioned is looked at by the monitor if the last look was at least
this many steps before (:func:`phc.simulation.step_logic.looks`, in every loop) —
except during a passage of a rank drop: after a look that let the run pass one, the next
ill-conditioned step is looked at as well, so that no step of the passage goes unchecked. With
every tenth only, a step between two looks can take a mechanism onto another branch of its
motion, and the looks after it agree with that branch: the N four-bar's cranks turned opposite
ways after such a step (``midpoint4`` at h = 2.5e-4, in a trial that compared the configuration
alone, docs/hard-cases.md)."""
RANK_DROP_GAP = 100
"""Looks at a rank drop less than this many steps apart are one passage."""
RANK_DROP_JUMP = 10.0
"""A step at a passage (:func:`passes_rank_drop`, given the rate before it) continues the motion
when no differential variable changes by more than this many times the largest change that rate
gives, the momenta along the constraint forces left out where that decides (they alternate,
:func:`_determined_agree`): the state is continuous through a rank drop the motion passes, a
step of it changes by h times the rate and the method's error. The equations of a step next to the singular instant have other solutions,
and a step and its halves can find the same one (in a trial, ``midpoint4`` at h = 1e-4 reversed
the N four-bar's motion, the coupler's vertical momentum −4.95 → +4.95 kg m/s, a change 400 times
the rate's, and its halves agreed on it to 0.05 of that change). The steps the four-bar's runs
keep change by at most 0.8 times that bound."""
RANK_DROP_DETERMINED = 0.01
"""Passing a rank drop on the state the midpoint rule determines (:func:`_determined_agree`): one
step and two half steps must agree on it to this fraction of the step's change there. With the
momenta along the constraint forces left out, the N four-bar's halves agree to 1.8e-3 of the
change or better at its passages (``midpoint4``, h = 1e-4, 10 s: at most 2e-5 but next to the
singular instants), and a step Newton solved onto another solution of its equations there was
0.13 off; the folding slider–crank's halves disagree by 0.2 (``midpoint``, h = 1e-5, in the rod's
bending momenta), a motion that does not continue through its rank drop."""
RANK_DROP_AGREEMENT = 0.1
"""Passing a rank drop: one step and two half steps must agree on the states' change to this
fraction of it. Away from it the midpoint rule's local error is O(h³) against a change O(h)
(the N four-bar at h = 1e-4: 6e-7 of the change); at the singular instant the least-norm
step's error is larger (there: 5e-3 of the change) but stays a fraction of the change; a
step whose halves take another branch of the motion, or fail, differs by O(1)."""


LOOK_BESIDE_FACTORS = 64 * 2 ** 20
"""Bytes of Newton's sparse factors (their nonzeros, 12 bytes each: value and row index) above which
they are freed before the singularity monitor's sparse look makes its own LU; the next step
factorizes again (:func:`release_large_factors`)."""


def release_large_factors(advance) -> None:
    """Free the Newton matrices' sparse factors of `advance` (its :class:`StageSolver`, or the stages
    of :mod:`phc.simulation.midpoint4`) where they hold more than :data:`LOOK_BESIDE_FACTORS`: the monitor's look is
    about to factorize a matrix of the same size, and the two factorizations side by side made the
    peak of a large mesh's run (a 10⁵-element Euler–Bernoulli beam: its look every
    :data:`MONITOR_EVERY` steps). The next step factorizes afresh, as after a step Newton found
    slow; below the size, nothing changes."""
    for stage in (*getattr(advance, "stages", ()), getattr(advance, "stage", None)):
        matrix = getattr(stage, "matrix", None)
        if matrix is not None and 12 * getattr(matrix.lu, "nnz", 0) > LOOK_BESIDE_FACTORS:
            matrix.lu = None


def finish_step(advance, monitor, mod, name, t, h, y, y_new, converged, reason, hard, look, mid_slope,
                rank_drops):
    """What the fixed-step loops (this module's and the compiled loops' driver,
    :func:`phc.simulation.compiled_steps.integrate`, for a step a chunk hands back) do after a
    step from (t, y) of size h to `y_new`, Newton's outcome `converged` (with `reason` when
    not), before accepting it: a failed step is retried from y, then split
    (:func:`_subdivide`); the singularity monitor looks when `look` (`hard`: Newton struggled,
    the looser threshold decides), and a warning stops the run unless the motion passes a rank
    drop of the position constraints (:func:`passed_rank_drop`). Returns ``(y_new, retried,
    failure, passed)``: the step's end, whether a retry or a split solved it, the message that
    ends the run (None: accept the step), and whether the step passed a rank drop (the
    caller then looks at the passage's next hard step too, without the :data:`LOOK_GAP` wait)."""
    retried = passed = False
    if not converged:
        # a step of the order of the period defeats the extrapolation: retry from y,
        # then split the step (any step size keeps the structure-preserving property)
        y_new, converged, reason = _subdivide(advance, t, h, y, MAX_SPLIT)
        if not converged:
            y_new, converged, reason = _uneven(advance, t, h, y, y_new, reason)
        retried = bool(converged)
    if look:
        release_large_factors(advance)
        # a fixed step cannot land on the singular set, only pass it at a distance ~h:
        # where Newton struggled, a looser threshold decides
        limit = HARD_STEP_THRESHOLD if hard else None
        warning = monitor.check(t, y, (y_new - y) / h if converged else mid_slope, 0.5 * h, limit)
        if warning is None and converged and hard:
            warning = monitor.check(t + h, y_new, (y_new - y) / h, 0.5 * h, limit)
        if warning and converged and passed_rank_drop(monitor, advance, mod, t, h, y, y_new, rank_drops, mid_slope):
            warning, passed = None, True  # a rank drop of the position constraints that the motion passes: go on
        elif warning and monitor.positional and (
                again := _least_norm_start_step(advance, mod, t, h, y, mid_slope)) is not None and passed_rank_drop(
                    monitor, advance, mod, t, h, y, again, rank_drops, mid_slope):
            # the step may have converged on another solution of its equations (or failed) from a start
            # that carried the passage's undetermined multiplier: solved again from least-norm multipliers
            y_new, warning, passed = again, None, True
            retried, converged = retried or not converged, True
        elif (warning and converged and hard and monitor.last_ratio >= monitor.threshold
              and passes_rank_drop(advance, mod, t, h, y, y_new)):
            # the looser threshold flagged a step Newton struggled with, but the iteration matrix is
            # not singular by the run's own threshold (at h and at STEP_SPREAD·h) and two half
            # steps reach the same end: a stiff, steep stretch (a transistor switching in SI
            # units), not a singular configuration: go on
            warning = None
        if warning:
            return y_new, retried, f"{name}: {warning}", passed
    if not converged:
        # a solution that grows without bound: no step size follows it (monitor.unbounded_growth)
        grows = unbounded_growth(mod, t, y, mid_slope, start=monitor.start, scales=monitor.scales)
        if grows is not None:
            return y_new, retried, (f"{name}: Newton failed at t = {t:.6g}: {grows}; results up to this time are "
                                    "kept"), passed
        failed = getattr(getattr(advance, "stage", None), "evaluation_error", None)
        if failed is not None:  # not even a split step stays inside the domain
            return y_new, retried, f"{name}: {failed}; results up to t = {t:.6g} are kept", passed
        return y_new, retried, f"{name}: {reason} at t = {t:.6g}; results up to this time are kept", passed
    return y_new, retried, None, passed


def _least_norm_start_step(advance, mod, t, h, y, slope):
    """The step from (t, y) of size h solved with Newton started at zero for the algebraic
    variables inside the step (the guess ``−y`` there: a midpoint step's values inside the step are
    the mean of its ends) and along the rate `slope` for the differential ones; None if it fails.

    At a rank drop the least-norm iteration keeps what its start puts in the multiplier directions
    it drops (:meth:`StageSolver._least_norm_retry`); from zero the step's multipliers there are the
    least-norm ones. The run's retry of a failed step starts from the end values (the constant
    predictor), and after a passage those carry the undetermined multiplier in full (±9e8 N after
    the N four-bar's first one, against values of order one inside the steps): from there a
    ``midpoint4`` step at h = 1e-4 converged on a solution that reversed the motion (the coupler's
    vertical momentum −4.95 → +4.95 kg m/s, docs/hard-cases.md)."""
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    if hasattr(advance, "nhist"):
        advance.nhist = 0  # midpoint4: from the guess, not from its substeps' history
    y1, ok, _ = advance(t, h, y, np.where(diff, y + h * np.asarray(slope, dtype=float), -y))
    return y1 if ok and np.all(np.isfinite(y1)) else None


def closing_message(message: str, ok: bool, split: int, rank_drops) -> str:
    """The fixed-step loops' message at the end of a run (this module's and
    :func:`phc.simulation.compiled_steps.integrate`'s): `message` with the steps that needed a
    retry or a split (of a run that succeeded) and the rank drops passed."""
    if ok and split:
        message += (f"; {split} step(s) needed a restart or a split to be solved (the step is long "
                    "for the dynamics)")
    if rank_drops:
        message += "; " + rank_drop_notice([a for a, _ in rank_drops])
    return message


def rank_drop_notice(times) -> str:
    """The run message's note on the rank drops a fixed-step run passed."""
    listed = ", ".join(f"{t:.6g}" for t in times[:6]) + (", …" if len(times) > 6 else "")
    return (f"passed {len(times)} rank drop(s) of the position constraints' Jacobian (t ≈ {listed}): the "
            "constraint forces are not determined there (their least-norm part is taken), the motion is — one "
            "step and two half steps agreed on it")


def passed_rank_drop(monitor, advance, mod, t, h, y, y_new, rank_drops, slope=None) -> bool:
    """Whether the converged step at the monitor's warning passes a rank drop of the position
    constraints (:func:`passes_rank_drop`, `slope` the run's ẏ before the step); if so it is added
    to `rank_drops` (a list of ``[first, last]`` times of the looks at each passage, shared by the
    Python and compiled loops)."""
    if not (monitor.positional and passes_rank_drop(advance, mod, t, h, y, y_new, monitor.p, slope)):
        return False
    if not rank_drops or t - rank_drops[-1][1] > RANK_DROP_GAP * h:
        rank_drops.append([t, t])
    rank_drops[-1][1] = t
    return True


def passes_rank_drop(advance, mod, t, h, y, y_new, p=None, slope=None) -> bool:
    """Whether the converged step ``(t, y) → (t + h, y_new)`` passes a rank drop of the position
    constraints' gradients with a determined motion: two half steps from ``y`` reach the same
    states (the differential variables) to :data:`RANK_DROP_AGREEMENT` of the step's change.

    At an isolated rank drop (the N four-bar mechanism with all bars horizontal) the multipliers
    lose a direction for an instant, the motion does not (J. García de Jalón, E. Bayo,
    "Kinematic and Dynamic Simulation of Multibody Systems", Springer 1994, on redundant and
    singular constraints): the Newton matrix is near singular only in the multiplier
    direction, a converged step is the unique motion at the step size, and halving the step
    changes it by the method's error. Where the motion itself is undetermined or leaves the
    constraint manifold's smooth part, the half steps fail or go elsewhere.

    Given the rate (below), the half steps start their algebraic variables at the step's midpoint
    values (the mean of its ends): a midpoint step's algebraic variables are unknowns inside the step, and their end
    values, which oscillate about the midpoint values, are no start after a passage (they carry
    the undetermined multiplier in full, ±9e8 N after the N four-bar's first one, and from the
    line between the ends the four-bar's first half step converged on another solution of its
    equations, crank 0's momentum −1.652 → −1.872 kg m²/s, docs/hard-cases.md).

    With the parameters `p` and the run's rate before the step, `slope` (ẏ between the last two
    step midpoints), the step must first continue the motion (:data:`RANK_DROP_JUMP`), the halves
    start as said above, and a step whose halves disagree is judged once more on the state the
    midpoint rule determines (:func:`_determined_agree`). That is the one passage check, of the
    fixed-step solvers and of the IDA bridge (:mod:`phc.simulation.ida_bridge`) alike. The bridge
    used to judge without the rate (the plain comparison below), because with it one N = 10 IDA
    run reported a passage 0.025 s before the singular instant. Traced (issue 34): that was not the
    check's doing: the same code and command gave that early event in one run of three (IDA's
    failure point before a passage, and so where a bridge starts, varies from run to run); what
    reports a bridge's shallow minimum as a passage is how bridges are counted
    (:meth:`phc.simulation.ida_bridge.Bridges._same_passage`, docs/hard-cases.md).
    Without `p` and `slope` the comparison is the plain one, from the line between the step's ends:
    :func:`finish_step`'s test of a stiff, steep stretch, which is not a rank drop."""
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    found = None
    if p is None or slope is None:  # the comparison as it was (the IDA bridge's, ida_bridge.bridge)
        y_a, ok, _ = advance(t, 0.5 * h, y, 0.5 * (y + y_new))
        if ok:
            y_b, ok, _ = advance(t + 0.5 * h, 0.5 * h, y_a, y_new.copy())
        change = float(np.abs(y_new - y)[diff].max(initial=0.0))
        gap = float(np.abs(y_b - y_new)[diff].max(initial=0.0)) if ok else np.inf
        return bool(np.isfinite(gap)) and gap <= RANK_DROP_AGREEMENT * change
    rate = float(np.abs(np.asarray(slope, dtype=float))[diff].max(initial=0.0))
    moved = float(np.abs(y_new - y)[diff].max(initial=0.0))
    if rate > 0 and not moved <= RANK_DROP_JUMP * h * rate:  # (at rest before the step: no scale)
        found = undetermined.force_directions(mod, p, t, h, y, y_new, constraint_rows(mod))
        if found is None:
            return False
        moved = float(np.abs(undetermined.without(np.where(diff, y_new - y, 0.0), found)).max(initial=0.0))
        if not (np.isfinite(moved) and moved <= RANK_DROP_JUMP * h * rate):
            return False  # not the motion: the state is continuous through a rank drop it passes
    half = 0.5 * h
    y_a, ok, _ = advance(t, half, y, np.where(diff, 0.5 * (y + y_new), y_new))
    if not ok:
        return False
    y_b, ok, _ = advance(t + half, half, y_a, np.where(diff, y_new, y + y_new - y_a))
    if not ok:
        return False
    change = float(np.abs(y_new - y)[diff].max(initial=0.0))
    gaps = np.where(diff, y_b - y_new, 0.0)
    gap = float(np.abs(gaps).max(initial=0.0))
    if not np.isfinite(gap):
        return False
    if gap <= RANK_DROP_AGREEMENT * change:
        return True
    return p is not None and slope is not None and _determined_agree(mod, p, t, h, y, y_new, gaps, found)


def _determined_agree(mod, p, t, h, y, y_new, gaps, found) -> bool:
    """The comparison of :func:`passes_rank_drop` on what the midpoint rule determines at the step
    ends: the configuration, and the momenta less their components along the constraint forces
    (:func:`phc.simulation.undetermined.force_directions`), which alternate from substep to substep
    about values the steps' means fix (one step of ``midpoint4``, three substeps, flips them; two
    half steps do not). Those components carry the impulse of the redundant multiplier a rank drop
    leaves undetermined, excited at the passage and left there for the rest of the run. The halves
    `gaps` (their end less the step's, zero outside the differential variables) must agree with the
    step on the rest to :data:`RANK_DROP_DETERMINED` of the step's change there (`found`: the
    directions, if computed already)."""
    if found is None:
        found = undetermined.force_directions(mod, p, t, h, y, y_new, constraint_rows(mod))
    if found is None:
        return False
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    moved = float(np.abs(undetermined.without(np.where(diff, y_new - y, 0.0), found)).max(initial=0.0))
    rest = float(np.abs(undetermined.without(gaps, found)).max(initial=0.0))
    return bool(np.isfinite(rest)) and rest <= RANK_DROP_DETERMINED * moved


EVENT_TOL = 1e-12
"""A crossing of a switching function is located to this fraction of max(1, |t|) (or to
1e-9 of the step, if that is longer)."""


def _crossed(events, t, h, y, y_new, w_prev) -> bool:
    """Whether a (failed) step's end lies beyond a switching surface."""
    if not np.all(np.isfinite(y_new)):
        return False
    try:
        w = events(t + h, y_new, (y_new - y) / h)
    except ModelEvaluationError:
        return False
    return bool(np.any((w_prev > 0) & (w <= 0)))


def _locate(advance, events, projector, t, h, y, y_full, w0, w1, crossed):
    """The first zero of the crossed switching functions along the step (t, y) → t + h, by
    regula falsi (Illinois) on the length θh of a shortened step from (t, y): returns
    dict(t, y, yp, which) at the end of the shortest step found past the crossing. A
    shortened step that fails counts as past the crossing (the old branch failed there)."""
    if crossed is None:
        crossed = (w0 > 0) & (w1 <= 0)
    lo, hi = 0.0, 1.0
    f_lo, f_hi = float(w0[crossed].min()), float(w1[crossed].min())
    y_hi, w_hi, y_lo, w_lo, at_hi = y_full, w1, y, w0, 1.0
    tol = max(EVENT_TOL * max(1.0, abs(t)), 1e-9 * h) / h
    side = 0
    guess = y_full
    for _ in range(200):
        if hi - lo <= tol:
            break
        theta = (lo * f_hi - hi * f_lo) / (f_hi - f_lo) if f_hi != f_lo else 0.5 * (lo + hi)
        margin = 1e-3 * (hi - lo)
        theta = min(max(theta, lo + margin), hi - margin)
        y_th, ok, _ = advance(t, theta * h, y, y + theta * (guess - y))
        if not ok:  # beyond the crossing on the old branch: bisect
            hi, f_hi, side = theta, 0.5 * f_hi, 0
            continue
        if projector is not None:
            y_th = projector.project(t + theta * h, y_th)
        w = events(t + theta * h, y_th, (y_th - y) / (theta * h))
        f = float(w[crossed].min())
        if f > 0:
            lo, f_lo, y_lo, w_lo = theta, f, y_th, w
            if side == -1:
                f_hi *= 0.5
            side = -1
        else:
            hi, f_hi, y_hi, w_hi, at_hi = theta, f, y_th, w, theta
            if side == 1:
                f_lo *= 0.5
            side = 1
    if at_hi != hi and lo > 0:  # no converged step ends past the crossing this close: take the one before
        which = np.flatnonzero(crossed & (w_lo <= w_lo[crossed].min()))
        return dict(t=t + lo * h, y=y_lo, yp=(y_lo - y) / (lo * h), which=which.tolist())
    which = np.flatnonzero(crossed & (w_hi <= 0))
    return dict(t=t + at_hi * h, y=y_hi, yp=(y_hi - y) / (at_hi * h), which=which.tolist())


MAX_SPLIT = 4
"""A step whose Newton iteration fails is retried from the constant predictor, then split
in halves up to this depth (at most 2⁴ sub-steps)."""
MONITOR_EVERY = 100
"""Steps between two routine looks of the singularity monitor (a dense SVD)."""
HARD_STEP_THRESHOLD = 1e-6
"""σ_min/σ_max below which a step Newton could not do from the predictor stops the run."""


def _subdivide(advance, t, h, y, depth):
    y1, ok, reason = advance(t, h, y, y.copy())
    if not ok and depth == 0 and hasattr(advance, "fallback"):
        # the discrete gradient's shortest split step: its midpoint step where only the energy
        # balance failed (phc.simulation.discrete_gradient)
        y_mid = advance.fallback()
        if y_mid is not None:
            return y_mid, True, ""
    if ok or depth == 0:
        return y1, ok, reason
    y_half, ok, reason = _subdivide(advance, t, 0.5 * h, y, depth - 1)
    if not ok:
        return y_half, ok, reason
    return _subdivide(advance, t + 0.5 * h, 0.5 * h, y_half, depth - 1)


UNEVEN = (1.0 / 3.0, 2.0 / 3.0)
"""Where the halving of a failed step fails too, the step is taken as two unequal pieces (this
fraction of it, then the rest). Halving keeps every substep's midpoint on the dyadic points of
the step; unequal pieces move the midpoints off that grid. Measured on the N four-bar with ten
loops at h = 1e-3 to 20 s (C back end, two BLAS threads): Newton failed at the passage at
t = 16.412 in the step and every halving of it, and the pieces 1/3, 2/3 passed it; with one
BLAS thread the same run stopped at t = 4.643 whatever the pieces; that was while the monitor
did not look above 120 unknowns and a passage's outcome depended on round-off
(docs/hard-cases.md)."""


def _uneven(advance, t, h, y, y_fail, reason):
    """The step as two unequal pieces (:data:`UNEVEN`); `(y_fail, False, reason)` if none passes."""
    for frac in UNEVEN:
        y_a, ok, _ = advance(t, frac * h, y, y.copy())
        if not ok:
            continue
        y_b, ok, _ = advance(t + frac * h, (1.0 - frac) * h, y_a, y_a.copy())
        if ok:
            return y_b, True, ""
    return y_fail, False, reason


SINGULAR_HINT = ("singular Newton matrix; the model may be at a singular configuration (an interconnection "
                 "losing rank: run `phc check`) or of index > 1 in a way the rule cannot handle; try the `ida` solver")
NEWTON_HINT = "Newton did not converge; reduce `step` (simulation.step)"


def midpoint_advance(mod, p, nominal=None):
    """The midpoint rule's step ``advance(t, h, y, guess) -> (y1, ok, reason)`` on a new
    :class:`StageSolver` (``advance.stage``): what :func:`integrate_fixed_step` takes, and what
    bridges IDA over a rank drop (:mod:`phc.simulation.ida_bridge`)."""
    stage = StageSolver(mod, p, weights=newton_weights_of(nominal, mod))

    def advance(t, h, y, guess):
        y1, ok = stage.solve(t, h, y, guess, 0.5)
        return y1, ok, (SINGULAR_HINT if stage.singular else NEWTON_HINT)

    advance.stage = stage
    return advance


def integrate_midpoint(mod, p, t_out, y0, yp0, options, *, progress=None, names=None, events=None,
                       nominal=None) -> BackendRun:
    """Fixed-step implicit midpoint from ``t_out[0]``; output at every ``t_out`` (each output
    interval is split into equal steps no longer than ``options.step``, a
    :class:`~phc.options.RunOptions`: a fixed-step method's accuracy is set by `step` alone)."""
    step, max_steps = options.step, options.max_steps

    def make_advance():
        advance = midpoint_advance(mod, p, nominal)
        advance.stage.restart_near = True
        return advance

    # the whole step loop compiled, when the model runs on the numba or the C backend
    from phc.simulation import compiled_steps

    out = compiled_steps.integrate("midpoint", mod, p, t_out, y0, yp0, max_steps=max_steps, progress=progress,
                                   step=step, name="implicit midpoint", names=names, python_advance=make_advance,
                                   weights=newton_weights_of(nominal, mod), scales=nominal, events=events)
    if out is not None:
        return out
    advance = make_advance()
    stage = advance.stage
    out = integrate_fixed_step(mod, p, t_out, y0, yp0, max_steps=max_steps, progress=progress, step=step,
                               advance=advance, name="implicit midpoint", names=names, events=events,
                               scales=nominal)
    return out.replace(nfev=stage.nfev, njev=stage.matrix.factorizations)
