"""The kernel of the compiled fixed-step loop: numba nopython code, plain Python until
:func:`phc.simulation.compiled_steps._compile` jits it. It is the numba back end's part of
the loop (it calls LAPACK/BLAS through NumPy arrays' ``.ctypes`` pointers), so it lives in
:mod:`phc.codegen` beside the C back end's port (:mod:`phc.codegen.c_steps`); it imports no
numba itself, so reading its layout constants costs nothing on other paths.

:mod:`phc.simulation.compiled_steps` says what the compiled loop does and holds its Python
side (whether a run uses it, building and caching it, the driver between chunks); this module
holds only the code numba compiles — the chunk's workspace (:func:`_chunk`, which runs
:func:`phc.simulation.step_logic.chunk`) and the operations only it has: one step of the run's
method (:func:`_advance`), the singularity monitor's routine look (:func:`_far_from_singular`,
:func:`_monitor_ratio`), the switching functions of a run with events (:func:`_watch`), the dense
LU / inverse / mixed-precision products.

The step logic itself — the stage's Newton iteration, the discrete-gradient and midpoint4
steps — and the chunk loop with its bookkeeping of a routine step (``chunk``) — the output grid and
its substeps (``next_step``), the predictor (``predict``), when the monitor looks (``looks``), the
acceptance (``accept``), with the layout of the state arrays they work on — are not written here: they are
:mod:`phc.simulation.step_logic`, the code the Python loop runs as well. Its functions are
rebound to this module's globals (:func:`_here`), where the operations they call by name are
the compiled loop's, on the workspace tuple ``ws`` that :func:`_chunk` builds (:func:`_begin`,
:func:`_refactor`, :func:`_correct`, :func:`_add`, :func:`_copy`, :func:`_precision`,
:func:`_stage`, :func:`_consistent`, :func:`_advance`, :func:`_far_from_singular`); :func:`~phc.simulation.compiled_steps._compile` jits them with the rest.

The LAPACK/BLAS entry points the kernel calls (``_dgetrf``, ``_dgetri``, ``_dgecon``,
``_dgesdd``, ``_dgemv``, ``_sgemv``) are not defined here: :func:`~phc.simulation.compiled_steps._kernel_namespace`
binds them into this module's globals, the namespace the kernel is jitted in, before it is
compiled; :func:`~phc.simulation.compiled_steps._compile` then replaces each function here by its
jitted version. The text of this module and of :mod:`phc.simulation.step_logic` is part of the
stamp of the compiled loop in phc's signed cache (:func:`~phc.simulation.compiled_steps._kernel_source`).
"""

from __future__ import annotations

import math
import types

import numpy as np

# the step logic both loops run (its functions are rebound to this module's globals below), its
# outcome codes and the layout of its constants vector c
from phc.simulation import step_logic
from phc.simulation.step_logic import (  # noqa: F401 — the rebound step logic reads them here
    _BAL_TOL, _EVAL, _EVERY, _FAIL, _FLOOR, _G1, _G2, _M0, _M1, _M2, _MAX_AGE, _MAX_NEWTON, _MAX_SECANT, _OK, _ONE,
    _ORDER, _ORDER_ALG, _PASSIVITY, _RATE, _RUN_ENERGY, _S_MAX, _S_MIN, _SINGULAR, _STAGNATION, _STRIKES_C,
    _THRESHOLD, _TOL, _ZERO, _ZONE, DOUBLE_NEXT, STRIKE)

# the state arrays shared with the driver (phc.simulation.compiled_steps.integrate); their layout is
# the step logic's (the Python loop keeps the same state)
from phc.simulation.step_logic import (  # noqa: F401,E402
    _CODE, _E, _H, _H_PREV, _HAS_MID, _HIST, _ILL, _J, _K, _LAST_LOOK, _LOWP, _MAX_STEPS, _METHOD, _MONITOR, _NEND,
    _NF, _NFACT, _NFEV, _NI, _NMID, _STATUS, _STEP, _STEPS, _STRIKES, _SUBSTEPS, _T, LOOK_GAP)

# status of a chunk (step_logic.chunk sets it; the driver reads it)
from phc.simulation.step_logic import _BUDGET, _DONE, _EVENT, _HARD, _LOOK, _MAXSTEPS  # noqa: F401,E402

_RCOND_MARGIN = 1e3
"""The routine look of the singularity monitor computes singular values only when LAPACK's
1-norm condition estimate is within this factor (times N) of the monitor's threshold."""


def _no_invariants(t, y, p):
    return np.zeros(0)


def _no_events(t, y, yp, p, out):
    """The switching functions of a run without events (never called: nothing is watched)."""


def _watch(ws, t, h, y, y_new):
    """step_logic's operation ``_watch``: the watched switching functions at the step's end,
    ``w_i = a_i + b_i·v[k_i]`` with ``v`` the model's ``events(t + h, y_new, (y_new − y)/h)``
    (the rows of ``wmap``: a, b, k; :func:`phc.simulation.compiled_steps.watch_map` writes them
    from the run's :class:`~phc.simulation.events.Watch`). True when one falls from above zero
    (``wprev``, the values at the step's start) to zero or below, or a value is not finite: the
    step is handed back. Else the values become the next step's start."""
    wmap, wprev, wnew, vbuf, slope = ws[32], ws[33], ws[34], ws[35], ws[36]
    nw = wprev.shape[0]
    if nw == 0:
        return False
    for i in range(y.shape[0]):
        slope[i] = (y_new[i] - y[i]) / h
    ws[31](t + h, y_new, slope, ws[3], vbuf)
    if not _all_finite(vbuf):
        return True
    crossed = False
    for i in range(nw):
        w = wmap[0, i] + wmap[1, i] * vbuf[int(wmap[2, i])]
        wnew[i] = w
        if wprev[i] > 0.0 and w <= 0.0:
            crossed = True
    if crossed:
        return True
    for i in range(nw):
        wprev[i] = wnew[i]
    return False


def _copy(a, b):
    """b ← a (a loop: a slice assignment compiles numba's shape-mismatch message, seconds of compile time)."""
    for i in range(a.shape[0]):
        b[i] = a[i]


def _all_finite(v):
    for i in range(v.shape[0]):
        if not np.isfinite(v[i]):
            return False
    return True


def _factor(A, ipiv, ints):
    """LU of the column-major matrix in A (C array holding Aᵀ row by row); the LAPACK info."""
    _dgetrf(ints[0:].ctypes, ints[0:].ctypes, A.ctypes, ints[0:].ctypes, ipiv.ctypes, ints[2:].ctypes)
    return ints[2]


def _invert(A, ipiv, ints):
    """A ← A⁻¹ from the LU of :func:`_factor` (LAPACK ``dgetri``); the LAPACK info. A simplified
    Newton iteration solves with one matrix many times: a product with the inverse (``dgemv``)
    costs half the two triangular solves (``dtrsv`` runs its n² operations in sequence)."""
    n = A.shape[0]
    lwork = np.empty(1, np.int32)
    lwork[0] = 64 * n
    work = np.empty(64 * n)
    _dgetri(ints[0:].ctypes, A.ctypes, ints[0:].ctypes, ipiv.ctypes, work.ctypes, lwork.ctypes, ints[2:].ctypes)
    return ints[2]


def _solve(A, ints, chars, c, x, tmp):
    """x ← A⁻¹x with the inverse of :func:`_invert` in A (column-major); `tmp` is scratch."""
    # ints: n, 1 (incx), info, -; chars: 'L', 'N', 'U'; c[_ONE], c[_ZERO]: 1.0, 0.0
    for i in range(x.shape[0]):
        tmp[i] = x[i]
    _dgemv(chars[1:].ctypes, ints[0:].ctypes, ints[0:].ctypes, c[_ONE:].ctypes, A.ctypes, ints[0:].ctypes,
           tmp.ctypes, ints[1:].ctypes, c[_ZERO:].ctypes, x.ctypes, ints[1:].ctypes)


def _lowprec(Am, lp, m):
    """The single-precision copy of the inverse Newton matrix in Am (column-major) into lp:
    equilibrated by powers of two (M = R·M̃·C with the row scales R and then the column scales
    C: every column of M̃ has its largest entry in [1, 2), no entry is larger), so that no entry
    that matters is out of single precision's range whatever the units; the scales are exact
    and kept in double (lp[1][m]: R, C, 1/R)."""
    A32, eq = lp[0], lp[1]
    n = Am.shape[0]
    for i in range(n):
        eq[m, 0, i] = 0.0
    for j in range(n):  # Am[j, :] is column j of M: the rows' largest entries, in one pass
        for i in range(n):
            a = abs(Am[j, i])
            if a > eq[m, 0, i]:
                eq[m, 0, i] = a
    for i in range(n):
        big = eq[m, 0, i]
        eq[m, 0, i] = math.ldexp(1.0, math.frexp(big)[1] - 1) if big > 0.0 else 1.0
        eq[m, 2, i] = 1.0 / eq[m, 0, i]  # exact: a power of two
    for j in range(n):
        big = 0.0
        for i in range(n):
            big = max(big, abs(Am[j, i]) * eq[m, 2, i])
        cj = math.ldexp(1.0, math.frexp(big)[1] - 1) if big > 0.0 else 1.0
        eq[m, 1, j] = cj
        cinv = 1.0 / cj
        for i in range(n):
            A32[m, j, i] = Am[j, i] * eq[m, 2, i] * cinv


def _solve32(lp, m, ints, chars, x):
    """x ← M x with the single-precision copy of :func:`_lowprec` (``sgemv``): the vector C x is
    brought to a largest entry of 1 by a power of two before it is rounded to single precision,
    the product scaled back by R in double. The iteration converges to the solution of F = 0 all
    the same (the residual is in double): only its rate can suffer, which :func:`_stage` watches."""
    A32, eq, v = lp[0], lp[1], lp[2]
    n = x.shape[0]
    big = 0.0
    for j in range(n):
        big = max(big, abs(eq[m, 1, j] * x[j]))
    if big == 0.0:
        return
    k = math.ldexp(1.0, math.frexp(big)[1])
    kinv = 1.0 / k  # exact: a power of two
    for j in range(n):
        v[j] = (eq[m, 1, j] * x[j]) * kinv
    # v[n:2n] the product; v[2n], v[2n + 1]: 1.0, 0.0
    _sgemv(chars[1:].ctypes, ints[0:].ctypes, ints[0:].ctypes, v[2 * n:].ctypes, A32[m].ctypes, ints[0:].ctypes,
           v.ctypes, ints[1:].ctypes, v[2 * n + 1:].ctypes, v[n:].ctypes, ints[1:].ctypes)
    for i in range(n):
        x[i] = eq[m, 0, i] * (k * np.float64(v[n + i]))


def _fill(A, jbuf, ebuf, jrows, jcols, emask, s, nend):
    """The Newton matrix s·(F_y + c_j F_ẏ) with the end-constraint rows from `ebuf`, column-major in A."""
    A[:, :] = 0.0
    for k in range(jrows.shape[0]):
        v = ebuf[k] if (nend > 0 and emask[k] != 0) else s * jbuf[k]
        A[jcols[k], jrows[k]] += v


def _stage_residual(res, inv, t, h, y, y1, s, p, out, end_rows, nend, xs, d):
    for i in range(y.shape[0]):
        d[i] = (y1[i] - y[i]) / h
        xs[i] = y[i] + s * (y1[i] - y[i])
    res(t + s * h, xs, d, p, out)
    if nend > 0:
        g = inv(t + h, y1, p)
        for i in range(nend):
            out[end_rows[i]] = g[i]
    return _all_finite(out)


def _refactor_matrix(jac, t, h, y, y1, s, p, A, lp, ipiv, matf, m, jrows, jcols, emask, nend, jbuf, ebuf, xs, d, ints,
                     ist):
    """Factorize the Newton matrix m for the iterate y1; the outcome (_OK, _SINGULAR, _EVAL)."""
    ist[_NFACT] += 1
    n = y.shape[0]
    for i in range(n):
        d[i] = y1[i] - y[i]
        xs[i] = y[i] + s * d[i]
        d[i] = d[i] / h
    cj = 1.0 / (s * h)
    jac(t + s * h, xs, d, p, cj, jbuf)
    if nend > 0:
        jac(t + h, y1, d, p, cj, ebuf)
    matf[m, 2] = 0.0
    if not _all_finite(jbuf) or (nend > 0 and not _all_finite(ebuf)):
        return _EVAL
    _fill(A[m], jbuf, ebuf, jrows, jcols, emask, s, nend)
    info = _factor(A[m], ipiv[m], ints)
    if info != 0:
        return _SINGULAR
    if _invert(A[m], ipiv[m], ints) != 0:
        return _SINGULAR
    if ist[_LOWP] != 0:
        _lowprec(A[m], lp, m)
    matf[m, 0] = h
    matf[m, 1] = s
    matf[m, 2] = 1.0
    ist[_AGE0 + m] = 0
    return _OK


_AGE0 = _NI  # the ages of the two Newton matrices follow the integer state


# The operations of phc.simulation.step_logic (by their names there) on the compiled loop's workspace: the tuple
# ws = (res, jac, inv, p, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend, weights, algmask, c, jbuf, ebuf,
#       xs, d, r, ints, chars, ist, M, colscale, ham, escale, powers, hist_t, hist_v) that _chunk builds.

def _begin(ws, m):
    matf, ist = ws[7], ws[23]
    if ist[_LOWP] < 0:  # double precision was for the last solve only
        ist[_LOWP] = 1
    ist[_AGE0 + m] += 1
    return matf[m, 2] != 0.0, matf[m, 0], matf[m, 1], ist[_AGE0 + m]


def _refactor(ws, m, t, h, y, y1, s):
    (res, jac, inv, p, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend, weights, algmask, c, jbuf, ebuf, xs, d,
     r, ints, chars, ist, M, colscale, ham, escale, powers, hist_t, hist_v, _ev, _wmap, _wprev, _wnew, _v, _sl) = ws
    return _refactor_matrix(jac, t, h, y, y1, s, p, A, lp, ipiv, matf, m, jrows, jcols, emask, nend, jbuf, ebuf, xs, d,
                            ints, ist)


def _correct(ws, m, t, h, y, y1, s):
    """The correction Δ = −J⁻¹F at y1 (into r) and its size in the Newton test's units: with
    weights, a state against its scale or its size, whichever is larger, and the algebraic
    variables but the GGL multipliers (algmask 1) relative to |y| + 1; else all relative to
    |y| + 1 (:meth:`phc.simulation.midpoint.StageSolver._correct`, on arrays)."""
    (res, jac, inv, p, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend, weights, algmask, c, jbuf, ebuf, xs, d,
     r, ints, chars, ist, M, colscale, ham, escale, powers, hist_t, hist_v, _ev, _wmap, _wprev, _wnew, _v, _sl) = ws
    n = y.shape[0]
    ist[_NFEV] += 1
    if not _stage_residual(res, inv, t, h, y, y1, s, p, r, end_rows, nend, xs, d):
        return _EVAL, r, 0.0, 0.0, 1.0, True, False
    for i in range(n):
        r[i] = -r[i]
    low = ist[_LOWP] > 0
    if low:
        _solve32(lp, m, ints, chars, r)
    else:
        _solve(A[m], ints, chars, c, r, xs)
    size = 0.0
    scale = 1.0
    alg = 0.0
    finite = True
    weighted = weights.shape[0] == n
    for i in range(n):
        a = abs(r[i])
        if not np.isfinite(a):
            finite = False
        if abs(y1[i]) + 1.0 > scale:
            scale = abs(y1[i]) + 1.0
        if weighted:
            if algmask[i] == 1 and a > alg:
                alg = a
            a = a * (weights[i] / (1.0 + abs(y1[i]) * weights[i]))
        if a > size:
            size = a
    states = size
    if weighted:
        size = max(size, alg / scale)
        scale = 1.0
    return _OK, r, size, states, scale, finite, low


def _add(y1, delta):
    for i in range(y1.shape[0]):
        y1[i] += delta[i]


def _precision(ws, event):
    ist, c = ws[23], ws[15]
    if event == DOUBLE_NEXT:
        ist[_LOWP] = -1
    else:  # a strike; after LOW_PRECISION_STRIKES of them the run keeps double precision
        ist[_STRIKES] += 1
        if ist[_STRIKES] >= c[_STRIKES_C]:
            ist[_LOWP] = 0


def _stage(ws, m, t, h, y, y1in, s, out):
    """One stage solve (phc.simulation.step_logic.newton) with the compiled loop's operations."""
    return _newton(ws, m, ws[15], t, h, y, y1in, s, out)


def _consistent(ws, t, y):
    """Nothing: a model whose velocities must be made consistent at the discrete gradient's step
    ends (rows ``M(q) v = p``) runs that method in the Python loop
    (:func:`phc.simulation.compiled_steps.integrate`)."""


def _advance(ws, t, h, y, guess, out):
    """One step of the method ist[_METHOD] (0 midpoint, 1 discrete gradient, 2 midpoint4) into
    out (step_logic's operation ``_advance``); the outcome and whether a stage was ill-conditioned."""
    ist, c, p = ws[23], ws[15], ws[3]
    ham, escale, powers, hist_t, hist_v = ws[26], ws[27], ws[28], ws[29], ws[30]
    method = ist[_METHOD]
    if method == 0:
        code, ill = _stage(ws, 0, t, h, y, guess, 0.5, out)
    elif method == 1:
        code, ill, y1, best, scale, y_half, secants = _discrete_gradient(ham, escale, ws, c, ist[_E], t, h, y, guess, p,
                                                                        out)
        _copy(y1, out)  # the Python code takes a step no point balances (split, midpoint fallback)
    else:
        code, ill, nhist = _midpoint4_step(powers, escale, ws, c, t, h, y, guess, p, out, hist_t, hist_v, ist[_HIST],
                                           ws[14])
        ist[_HIST] = nhist
    return code, ill


def _far_from_singular(ws, t, y, yp, hm):
    """step_logic's operation ``_far_from_singular``: σ_min/σ_max of the equilibrated iteration
    matrix (:func:`_monitor_ratio`: LAPACK's condition estimate, then its SVD) not below the
    monitor's threshold."""
    jac, p, jrows, jcols, c, jbuf, M, colscale = ws[1], ws[3], ws[8], ws[9], ws[15], ws[16], ws[24], ws[25]
    ratio = _monitor_ratio(jac, t, y, yp, hm, p, jrows, jcols, jbuf, M, colscale, c[_THRESHOLD])
    return not (ratio < c[_THRESHOLD])


def _here(func):
    """`func` of :mod:`phc.simulation.step_logic` with this module's globals: the operations it
    calls by name (``_begin``, ``_refactor``, ``_correct``, ``_add``, ``_copy``, ``_precision``,
    ``_stage``) are then the compiled loop's, defined above, and numba compiles it with them
    (:func:`phc.simulation.compiled_steps._compile`). The code is the Python loop's, unchanged."""
    return types.FunctionType(func.__code__, globals(), func.__name__, func.__defaults__, func.__closure__)


_newton = _here(step_logic.newton)
_discrete_gradient = _here(step_logic.discrete_gradient)
_midpoint4_step = _here(step_logic.midpoint4)
passivity_floor = _here(step_logic.passivity_floor)  # midpoint4 calls it by its step_logic name
# the driver's bookkeeping, called by their step_logic names (they call each other by those names)
lagrange_weights = _here(step_logic.lagrange_weights)
predictor_nodes = _here(step_logic.predictor_nodes)
substeps = _here(step_logic.substeps)
next_step = _here(step_logic.next_step)
polynomial = _here(step_logic.polynomial)
extrapolate = _here(step_logic.extrapolate)
predict = _here(step_logic.predict)
looks = _here(step_logic.looks)
accept = _here(step_logic.accept)
chunk = _here(step_logic.chunk)


def _monitor_ratio(jac, t, y, yp, h, p, jrows, jcols, jbuf, M, colscale, threshold):
    """σ_min/σ_max of the equilibrated iteration matrix (SingularityMonitor.ratio); -1 when it
    cannot be computed here (the Python monitor then looks itself)."""
    n = y.shape[0]
    jac(t, y, yp, p, 1.0 / max(h, 1e-300), jbuf)
    if not _all_finite(jbuf):
        return -1.0
    M[:, :] = 0.0
    for k in range(jrows.shape[0]):
        M[jcols[k], jrows[k]] = jbuf[k]  # column-major: M[col, row]
    if colscale.shape[0] == n:  # scaled variables y/s: columns times s
        for j in range(n):
            for i in range(n):
                M[j, i] *= colscale[j]
    rowmax = np.empty(n)
    for _ in range(2):
        # rows of J (M[j, i] is J[i, j]: the loops run along M's rows, contiguous)
        for i in range(n):
            rowmax[i] = 0.0
        for j in range(n):
            for i in range(n):
                rowmax[i] = max(rowmax[i], abs(M[j, i]))
        for j in range(n):
            for i in range(n):
                if rowmax[i] > 0.0:
                    M[j, i] /= rowmax[i]
        for j in range(n):  # columns of J
            big = 0.0
            for i in range(n):
                big = max(big, abs(M[j, i]))
            if big > 0.0:
                for i in range(n):
                    M[j, i] /= big
    ints = np.zeros(4, np.int32)
    ints[0] = n
    # a cheap look first: the 1-norm condition estimate of LAPACK (dgecon, on an LU) bounds
    # σ_max/σ_min ≤ n·κ₁; an estimate (a lower bound of κ₁, within a small factor in practice)
    # RCOND_MARGIN·n times above the threshold leaves the SVD out
    lu = M.copy()
    anorm = np.zeros(1)
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(M[j, i])
        anorm[0] = max(anorm[0], col)
    ipiv = np.zeros(n, np.int32)
    _dgetrf(ints[0:].ctypes, ints[0:].ctypes, lu.ctypes, ints[0:].ctypes, ipiv.ctypes, ints[2:].ctypes)
    if ints[2] == 0:
        one_norm = np.zeros(1, np.uint8)
        one_norm[0] = 49  # '1'
        rcond = np.zeros(1)
        cwork = np.zeros(4 * n)
        ciwork = np.zeros(n, np.int32)
        _dgecon(one_norm.ctypes, ints[0:].ctypes, lu.ctypes, ints[0:].ctypes, anorm.ctypes, rcond.ctypes,
                cwork.ctypes, ciwork.ctypes, ints[2:].ctypes)
        if ints[2] == 0 and np.isfinite(rcond[0]) and rcond[0] >= threshold * n * _RCOND_MARGIN:
            return rcond[0] / n  # about a lower bound of σ_min/σ_max, far above the threshold
    ints[1] = -1
    ints[2] = 0
    chars = np.zeros(1, np.uint8)
    chars[0] = 78  # 'N'
    s = np.zeros(n)
    dummy = np.zeros(1)
    iwork = np.zeros(8 * n, np.int32)
    query = np.zeros(1)
    one = np.ones(1, np.int32)
    _dgesdd(chars.ctypes, ints[0:].ctypes, ints[0:].ctypes, M.ctypes, ints[0:].ctypes, s.ctypes, dummy.ctypes,
            one.ctypes, dummy.ctypes, one.ctypes, query.ctypes, ints[1:].ctypes, iwork.ctypes, ints[2:].ctypes)
    lwork = max(int(query[0]), 1)
    work = np.zeros(lwork)
    ints[1] = lwork
    _dgesdd(chars.ctypes, ints[0:].ctypes, ints[0:].ctypes, M.ctypes, ints[0:].ctypes, s.ctypes, dummy.ctypes,
            one.ctypes, dummy.ctypes, one.ctypes, work.ctypes, ints[1:].ctypes, iwork.ctypes, ints[2:].ctypes)
    if ints[2] != 0 or not _all_finite(s):
        return -1.0
    return s[n - 1] / s[0] if s[0] > 0 else 0.0


def _chunk(res, jac, inv, ham, escale, powers, events, p, t_out, ys, yps, y, mid, mid_slope, y_prev, fst, ist, c, A,
           lp, ipiv, matf, jrows, jcols, end_rows, emask, weights, algmask, hist_t, hist_v, y_new, jbuf, ebuf, M, colscale,
           pt, pm, wmap, wprev, wnew, vbuf, budget):
    """Steps of integrate_fixed_step until `budget` steps are done, the run ends, or a step needs
    the Python code (see the module docstring); the state is in the arrays, the status in ist.
    The loop is step_logic's :func:`~phc.simulation.step_logic.chunk`; this builds its workspace."""
    n = y.shape[0]
    nend = ist[_NEND]
    ints = np.zeros(4, np.int32)
    ints[0] = n
    ints[1] = 1
    chars = np.zeros(3, np.uint8)
    chars[0] = 76  # 'L'
    chars[1] = 78  # 'N'
    chars[2] = 85  # 'U'
    xs = np.empty(n)
    d = np.empty(n)
    r = np.empty(n)
    guess = np.empty(n)
    yp = np.empty(n)
    ws = (res, jac, inv, p, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend, weights, algmask, c, jbuf, ebuf, xs,
          d, r, ints, chars, ist, M, colscale, ham, escale, powers, hist_t, hist_v, events, wmap, wprev, wnew, vbuf,
          np.empty(n))
    chunk(ws, t_out, ys, yps, y, mid, mid_slope, y_prev, y_new, pt, pm, fst, ist, c, algmask, guess, yp, budget)
