"""The fixed-step methods' step logic, written once for the Python loop and the compiled loop.

The implicit midpoint rule (:mod:`phc.simulation.midpoint`), the discrete-gradient step
(:mod:`phc.simulation.discrete_gradient`) and the fourth-order composition
(:mod:`phc.simulation.midpoint4`) run in two loops: the Python loop
(:func:`~phc.simulation.midpoint.integrate_fixed_step`: sparse LU, events, any size) and the
compiled loop (:mod:`phc.simulation.compiled_steps`: numba, dense inverse, small systems). What
a step *does* is written here, once, as plain Python that numba can compile:

* :func:`newton` — the simplified Newton iteration of one stage (its stopping rules, the
  refresh of the Newton matrix on poor contraction, a changed step size or evaluation point,
  or age; the round-off acceptance; the mixed-precision watch of the compiled loop);
* :func:`discrete_gradient` — the secant iteration on the mean-value point ``s`` that makes
  the discrete energy balance of the paper's Remark 3 "Energy balance" hold for a
  non-quadratic Hamiltonian (T. Berger, R. Hochdahl, T. Reis, R. Seifried, "Port-Hamiltonian
  modelling of coupled rigid/flexible multibody systems");
* :func:`midpoint4` — the triple-jump composition of three midpoint substeps with its
  predictor and its passivity guard;
* :func:`predictor_nodes` and :func:`lagrange_weights` — how the start of Newton is
  extrapolated from the last step midpoints (the last one, the line through two, or the
  polynomial through more) and that polynomial's weights;
* the driver's routine bookkeeping around a step, on the state arrays ``ist``/``fst`` (layout
  ``_K`` … ``_STRIKES``, ``_T`` … ``_STEP``) both loops keep: :func:`next_step` (the output grid
  and its equal :func:`substeps`), :func:`predict` (the predicted midpoint, per variable by
  :func:`extrapolate`/:func:`polynomial`), :func:`looks` (whether the singularity monitor looks:
  a hard step, the routine period) and :func:`accept` (the midpoints' history, the time, the step
  count, ``max_steps``, the output at the end of an interval). These are written with whole-array
  NumPy expressions and the ``_copy`` operation, so that the Python loop runs them at NumPy speed
  and numba compiles the same text into the compiled loop's chunk;
* :func:`chunk` — the compiled loops' chunk of routine steps (those functions in turn, until a
  budget of steps, the end, or a step the Python driver must take), which the numba kernel runs
  and the C loop gets translated; the Python loop takes its steps itself.

The C back end's step loop (``phc/codegen/c_runtime/steps.c``, :mod:`phc.codegen.c_steps`)
cannot run Python: it gets :func:`newton`, :func:`discrete_gradient`, :func:`midpoint4`, the
driver's bookkeeping (:func:`next_step`, :func:`substeps`, :func:`predict` with the predictor's
functions, :func:`looks`, :func:`accept`) and :func:`chunk` translated to C from this text by :mod:`phc.codegen.c_translate`,
with the C types of :data:`C_SIGNATURES`; keep those functions within the translator's subset
(its docstring; a function outside it is refused with its line, in
``tests/codegen/test_c_translate.py``).

What stays each loop's own is what is not routine: the Python loop's
:func:`~phc.simulation.midpoint.integrate_fixed_step` handles events, projection, retries and
splits and the singularity monitor's full look and messages
(:func:`~phc.simulation.midpoint.finish_step`); the compiled loops' :func:`chunk` runs the
routine steps with the functions above and hands every other step back to that same Python code
(:func:`phc.simulation.compiled_steps.integrate`). The routine look's screen, σ_min/σ_max of the
equilibrated iteration matrix, is each back end's linear algebra (SciPy's LAPACK in
:class:`~phc.simulation.monitor.SingularityMonitor`, LAPACK through pointers in
:func:`phc.codegen.numba_steps_kernel._monitor_ratio`, steps.c's condition estimate in the C
loop: the operation ``_far_from_singular``), as the Newton matrix's LU is.

Neither loop's data structures appear here. What touches them are a few operations, called
by name: ``ws`` is the loop's workspace, passed through to them untouched. The Python loop's
operations are defined at the end of this module: they call the methods of its workspace
object (a :class:`~phc.simulation.midpoint.StageSolver`, whose operations are its sparse LU
and NumPy vector arithmetic, or :class:`~phc.simulation.midpoint.Stages`). The compiled loop
runs copies of these functions whose globals are its kernel module
(:func:`phc.codegen.numba_steps_kernel._here`), where the same names are its own
operations on a tuple of arrays (LAPACK/BLAS calls and element loops), and numba compiles
them with the rest of the kernel. The operations (what they do and return):

``_begin(ws, m) -> (factorized, h, s, age)``
    Start a solve with Newton matrix ``m``: its age counts up by one; returns whether it is
    factorized and the step size and evaluation point it was factorized for.
``_refactor(ws, m, t, h, y, y1, s) -> code``
    Factorize matrix ``m`` for the iterate ``y1`` (:data:`_OK`, :data:`_SINGULAR`, :data:`_EVAL`).
``_correct(ws, m, t, h, y, y1, s) -> (code, delta, size, states, scale, finite, low)``
    The correction ``Δ = −J⁻¹F`` at ``y1`` and its size in the Newton test's units (``size``:
    all unknowns, ``states``: the states alone, both measured against ``scale``), whether it
    is finite, and whether it was computed with the single-precision copy of the matrix.
``_add(y1, delta)``, ``_copy(src, dst)``
    ``y1 += delta``, ``dst[:] = src``.
``_precision(ws, event)``
    :data:`DOUBLE_NEXT`: the rest of this solve in double precision; :data:`STRIKE`: double
    precision contracted where single did not (the Python loop has no single precision).
``_stage(ws, m, t, h, y, y1in, s, out) -> (code, ill_conditioned)``
    One stage solve (:func:`newton` with matrix ``m``) into ``out``.
``_consistent(ws, t, y)``
    The velocities of ``y`` that H is written in, made consistent with its states at ``t``
    (the rows ``M(q) v = p``; :class:`phc.simulation.discrete_gradient.EndVelocities`). The
    compiled loops do not run models that have such rows with the discrete gradient (their
    ``_consistent`` does nothing).

:func:`chunk`, which only the compiled loops run, calls two more, defined by those loops alone:

``_advance(ws, t, h, y, guess, out) -> (code, ill_conditioned)``
    One step of the run's method (``ist[_METHOD]``: 0 :func:`newton` of the midpoint stage,
    1 :func:`discrete_gradient`, 2 :func:`midpoint4`) from ``guess`` into ``out``, with the
    model's Hamiltonian, energy scale and port powers the loop holds.
``_far_from_singular(ws, t, y, yp, hm) -> bool``
    The routine look's screen of the singularity monitor: whether the equilibrated iteration
    matrix ``F_y + F_ẏ/hm`` at ``(t, y, yp)`` (:meth:`~phc.simulation.monitor.SingularityMonitor.ratio`)
    is clearly far from singular. Its linear algebra is the loop's: LAPACK's 1-norm condition
    estimate (``dgecon`` on ``dgetrf``'s LU, then ``dgesdd``'s σ_min/σ_max where the estimate is
    not conclusive) in the numba kernel (``_monitor_ratio``); the same estimate on steps.c's own
    LU in the C loop (``far_from_singular``), which hands an inconclusive look to Python's
    monitor. False: the driver looks with the Python monitor and decides.
``_watch(ws, t, h, y, y_new) -> bool``
    The switching functions of a run with events (:class:`phc.simulation.events.Watch`, the
    modes' ``w = mode·g`` and a sticking sign's ``1 ∓ s``) at the step's end ``(t + h, y_new)``
    with the step's slope: True when one has fallen from above zero to zero or below, or is not
    finite (the driver then evaluates them itself and locates the event with the Python loop's
    code, :func:`phc.simulation.midpoint._locate`); False (the values kept as the next step's
    start) otherwise, and always in a run without events. The numba kernel evaluates the model's
    ``events`` compiled; the C loop the model library's ``phc_events`` (steps.c's ``op_watch``).

The numbers the logic uses come in the vector ``c`` (its layout: ``_TOL`` … ``_RUN_ENERGY``),
filled from the constants of the methods' modules (:func:`phc.simulation.midpoint.newton_constants`,
:func:`phc.simulation.discrete_gradient.secant_constants`,
:func:`phc.simulation.midpoint4.composition_constants`); ``c[_RUN_ENERGY]`` is the run's energy
scale (:func:`phc.simulation.scaling.run_energy`, set per run; 0 where none is known).
"""

from __future__ import annotations

import numpy as np

# outcome of a stage solve / a step
_OK, _FAIL, _SINGULAR, _EVAL, _PASSIVITY = 0, 1, 2, 3, 4
# events of `precision`
DOUBLE_NEXT, STRIKE = 0, 1
# the constants vector c
(_TOL, _RATE, _FLOOR, _MAX_AGE, _MAX_NEWTON, _BAL_TOL, _MAX_SECANT, _S_MIN, _S_MAX, _THRESHOLD, _EVERY,
 _G1, _G2, _M0, _M1, _M2, _ORDER, _ZONE, _STAGNATION, _ONE, _ZERO, _ORDER_ALG, _STRIKES_C, _RUN_ENERGY) = range(24)
_NC = 24
# the loops' state (the Python loop's, the compiled loops' and steps.c's): integer state ist
(_K, _J, _SUBSTEPS, _STEPS, _LAST_LOOK, _HAS_MID, _MAX_STEPS, _STATUS, _NFEV, _NFACT, _HIST, _MONITOR, _METHOD,
 _CODE, _ILL, _E, _NEND, _NMID, _LOWP, _STRIKES) = range(20)
_NI = 20
# float state
_T, _H, _H_PREV, _STEP = range(4)
_NF = 4
# status of a compiled loop's chunk (ist[_STATUS], set by :func:`chunk`)
_BUDGET, _DONE, _HARD, _LOOK, _MAXSTEPS, _EVENT = 0, 1, 2, 3, 4, 5
LOOK_GAP = 10
"""A step Newton found ill-conditioned is looked at by the singularity monitor if the last look
was at least this many steps before (:func:`looks`; why: :data:`phc.simulation.midpoint.LOOK_GAP`)."""


C_SIGNATURES = {
    # name: (the kinds of its parameters, of its results) for the C back end's translation
    # (phc.codegen.c_translate: f double, i int64, b truth value, v vector of n, V rows of n, M mask of n,
    # F/I double/int64 array indexed by scalars, F3 a double array [*, 3], V3 an array [*, 3, n],
    # ws the loop's workspace)
    "substeps": (("f", "f"), ("i",)),
    "next_step": (("F", "F", "I"), ()),
    "predictor_nodes": (("i", "i"), ("i",)),
    "lagrange_weights": (("F", "i", "f", "F"), ()),
    "polynomial": (("F", "V", "i", "f"), ("v",)),
    "extrapolate": (("i", "v", "v", "F", "V", "f", "f", "f"), ("v",)),
    "predict": (("v", "v", "v", "F", "V", "I", "F", "f", "f", "f", "M", "v"), ()),
    "accept": (("f", "f", "v", "v", "v", "v", "v", "v", "F", "V", "V", "V", "F", "I"), ("b",)),
    "looks": (("I", "F", "b", "b"), ("b", "b")),
    "newton": (("ws", "i", "F", "f", "f", "v", "v", "f", "v"), ("i", "b")),
    # S: the energy scale's C function, P: the port powers' (both the model's)
    "discrete_gradient": (("S", "S", "ws", "F", "i", "f", "f", "v", "v", "F", "v"),
                          ("i", "b", "v", "f", "f", "v", "i")),
    "passivity_floor": (("f", "f"), ("f",)),
    "midpoint4": (("P", "S", "ws", "F", "f", "f", "v", "v", "F", "v", "F3", "V3", "i", "M"), ("i", "b", "i")),
    "chunk": (("ws", "F", "V", "V", "v", "v", "v", "v", "v", "F", "V", "F", "I", "F", "M", "v", "v", "i"), ()),
}
"""The C signatures of the functions the C back end's step loop gets translated from this module
(:func:`phc.codegen.c_steps.source`); a function edited beyond what the translator accepts fails
its build and ``tests/codegen/test_c_translate.py`` with the line named."""


def substeps(interval, step):
    """The number of equal steps an output interval of length `interval` is split into: the
    fewest no longer than `step` (one when `step` is 0, no step set). The 1e-9 keeps an
    interval of a whole number of steps from getting one more for the rounding of
    ``interval / step``. The C step loop (``phc/codegen/c_runtime/steps.c``) computes the same."""
    if step > 0.0:
        return max(1, int(np.ceil(interval / step - 1e-9)))
    return 1


def next_step(t_out, fst, ist):
    """The step the loop takes next on the output grid ``t_out``: at the start of output interval
    ``ist[_K]`` (``ist[_J]`` substeps of it done: none), the interval's :func:`substeps` into
    ``ist[_SUBSTEPS]``, their size into ``fst[_H]`` and the time ``fst[_T]`` back to the interval's
    start (the steps of an interval advance ``fst[_T]`` by ``fst[_H]``: :func:`accept`)."""
    if ist[_J] == 0:
        k = ist[_K]
        interval = t_out[k] - t_out[k - 1]
        sub = substeps(interval, fst[_STEP])
        ist[_SUBSTEPS] = sub
        fst[_H] = interval / sub
        fst[_T] = t_out[k - 1]


def polynomial(pt, pm, k, tn):
    """``Σ w[a]·pm[a]`` over the newest ``k`` step midpoints ``pm[0:k]`` (newest first, at the
    times ``pt[0:k]``): the polynomial through them at ``tn`` (:func:`lagrange_weights`)."""
    w = np.empty(k)
    lagrange_weights(pt, k, tn, w)
    out = w[0] * pm[0]
    for a in range(1, k):
        out = out + w[a] * pm[a]
    return out


def extrapolate(k, mid, mid_slope, pt, pm, tn, h, h_prev):
    """The next step midpoint (at ``tn``, step ``h`` after one of ``h_prev``) by the rule
    :func:`predictor_nodes` returned, ``k``: 0 the last midpoint ``mid``; 1 the line along the last
    slope ``mid_slope``; k ≥ 3 the polynomial through the last k (:func:`polynomial`)."""
    if k == 0:
        return mid
    if k == 1:
        return mid + 0.5 * (h + h_prev) * mid_slope
    return polynomial(pt, pm, k, tn)


def predict(y, mid, mid_slope, pt, pm, ist, c, t, h, h_prev, algmask, guess):
    """The start of Newton into ``guess``: ``2 m − y`` with the predicted midpoint m of the step
    (t, h) from ``y``. Before any step, ``m = y + h/2·ẏ₀`` (``mid_slope`` holds ẏ₀); then per
    variable by its degree — differential variables (``algmask`` 0) ``c[_ORDER]``, algebraic ones
    ``c[_ORDER_ALG]`` — and the ``ist[_NMID]`` midpoints known (:func:`predictor_nodes`,
    :func:`extrapolate`). Predictor of the midpoints, not the step ends: the algebraic variables
    (multipliers) of a midpoint rule oscillate about their midpoint values from step end to step
    end, which ruins an extrapolation of the ends."""
    if ist[_HAS_MID] == 0:
        _copy(2.0 * (y + 0.5 * h * mid_slope) - y, guess)
        return
    tn = t + 0.5 * h
    kd = predictor_nodes(int(c[_ORDER]), ist[_NMID])
    ka = predictor_nodes(int(c[_ORDER_ALG]), ist[_NMID])
    md = extrapolate(kd, mid, mid_slope, pt, pm, tn, h, h_prev)
    ma = extrapolate(ka, mid, mid_slope, pt, pm, tn, h, h_prev)
    _copy(2.0 * np.where(algmask != 0, ma, md) - y, guess)


def looks(ist, c, converged, ill):
    """Whether the singularity monitor looks at the step just solved: ``(hard, look)``. Hard: Newton
    failed, or found the step ill-conditioned at least :data:`LOOK_GAP` steps after the last look;
    a look (with the monitor on, ``ist[_MONITOR]``) at a hard step and every ``c[_EVERY]`` steps."""
    steps = ist[_STEPS]
    hard = (not converged) or (ill and steps - ist[_LAST_LOOK] >= LOOK_GAP)
    return hard, ist[_MONITOR] != 0 and (hard or steps % int(c[_EVERY]) == 0)


def accept(t, h, y, y_new, y_end, y_prev, mid, mid_slope, pt, pm, ys, yps, fst, ist):
    """Take the step (t, h, y) → ``y_new`` (the stage solution; ``y_end`` the step's end, the same
    unless projected): the midpoints' history of the predictor (newest first in ``pt``/``pm``, the
    slope between the last two in ``mid_slope``), ``y_prev`` ← y ← ``y_end``, the time, the step
    counter, the output ``ys``/``yps`` at the end of an output interval. True when ``max_steps`` is
    reached (the interval's output is then not written)."""
    h_prev = fst[_H_PREV]
    kp = pm.shape[0]
    for j in range(kp - 1, 0, -1):
        pt[j] = pt[j - 1]
        _copy(pm[j - 1], pm[j])
    pt[0] = t + 0.5 * h
    nm = 0.5 * (y + y_new)
    if ist[_HAS_MID] != 0:
        _copy((nm - mid) / (0.5 * (h + h_prev)), mid_slope)
    _copy(nm, mid)
    _copy(nm, pm[0])
    _copy(y, y_prev)
    _copy(y_end, y)
    ist[_HAS_MID] = 1
    ist[_NMID] = min(ist[_NMID] + 1, kp)
    fst[_H_PREV] = h
    fst[_T] = t + h
    ist[_STEPS] += 1
    if ist[_STEPS] >= ist[_MAX_STEPS]:
        return True
    ist[_J] += 1
    if ist[_J] >= ist[_SUBSTEPS]:
        k = ist[_K]
        _copy(y, ys[k])
        _copy((y - y_prev) / h, yps[k])
        ist[_K] = k + 1
        ist[_J] = 0
    return False


def chunk(ws, t_out, ys, yps, y, mid, mid_slope, y_prev, y_new, pt, pm, fst, ist, c, algmask, guess, yp, budget):
    """The compiled loops' chunk: routine steps of the output grid ``t_out`` until ``budget`` steps
    are done (``ist[_STATUS]`` ← :data:`_BUDGET`), the grid's end (:data:`_DONE`), ``max_steps``
    (:data:`_MAXSTEPS`), or a step that needs the Python driver: one that failed or that the
    singularity monitor must look at as a hard step (:data:`_HARD`, the outcome in ``ist[_CODE]``
    and ``ist[_ILL]``), a routine look the loop's screen does not pass (:data:`_LOOK`), or a
    step at whose end a watched switching function has fallen to zero or below (:data:`_EVENT`,
    the operation ``_watch``: the driver locates the event). The
    step is not taken then (the driver takes it: :func:`phc.simulation.compiled_steps.integrate`).

    Each step: :func:`next_step`, :func:`predict` into ``guess``, the method's step into ``y_new``
    (the operation ``_advance``), :func:`looks`, and on a routine look the operation
    ``_far_from_singular`` on the step's midpoint slope ``yp`` (the equilibrated iteration matrix
    with c_j = 2/h), then :func:`accept`. The Python loop does not run this function (it takes
    each step itself, with events and projection: :func:`~phc.simulation.midpoint.integrate_fixed_step`);
    the numba kernel runs it (:func:`phc.codegen.numba_steps_kernel._chunk`) and the C loop's
    ``phc_steps_chunk`` is its translation."""
    nout = ys.shape[0]
    done = 0
    while True:
        k = ist[_K]
        if k >= nout:
            ist[_STATUS] = _DONE
            return
        if done >= budget:
            ist[_STATUS] = _BUDGET
            return
        next_step(t_out, fst, ist)
        t = fst[_T]
        h = fst[_H]
        predict(y, mid, mid_slope, pt, pm, ist, c, t, h, fst[_H_PREV], algmask, guess)
        code, ill = _advance(ws, t, h, y, guess, y_new)  # noqa: F821 — a compiled loop's operation
        ist[_CODE] = code
        ist[_ILL] = 1 if ill else 0
        hard, look = looks(ist, c, code == _OK, ill)
        if code != _OK or (hard and look):  # the monitor's look at a hard step: the driver's
            ist[_STATUS] = _HARD
            return
        if look:  # the routine look
            ist[_LAST_LOOK] = ist[_STEPS]
            _copy((y_new - y) / h, yp)
            if not _far_from_singular(ws, t, y, yp, 0.5 * h):  # noqa: F821 — a compiled loop's operation
                ist[_STATUS] = _LOOK
                return
        if _watch(ws, t, h, y, y_new):  # noqa: F821 — a compiled loop's operation: a switching function crossed
            ist[_STATUS] = _EVENT
            return
        done += 1
        if accept(t, h, y, y_new, y_new, y_prev, mid, mid_slope, pt, pm, ys, yps, fst, ist):
            ist[_STATUS] = _MAXSTEPS
            return


def newton(ws, m, c, t, h, y, y1in, s, out):
    """Solve ``F(t + s h, y + s (y1 − y), (y1 − y)/h) = 0`` (the position-constraint rows at the
    step end) for ``y1`` by simplified Newton from ``y1in``, into ``out``; returns
    ``(code, ill_conditioned)``.

    The matrix ``m`` is refreshed before the first correction when it is not factorized, was
    factorized for another step size (by more than 1e-3 relative) or evaluation point (by more
    than 0.2), or is ``c[_MAX_AGE]`` solves old; during the iteration when the contraction rate
    θ = |Δ_k|/|Δ_{k−1}| exceeds ``c[_RATE]`` or the old matrix diverges. Converged: the
    estimated error ``θ/(1−θ)·|Δ|`` or the correction itself (1e-2 of it) below ``c[_TOL]``.
    Accepted at round-off level: a stagnating iteration (θ ≥ 0.5, or ``c[_STAGNATION]`` times
    the smallest rate with this matrix) whose correction is below ``c[_ZONE]·c[_TOL]``; a fresh
    matrix that cannot reduce a states' correction below ``c[_FLOOR]`` (then
    ``ill_conditioned``: the driver asks the singularity monitor)."""
    _copy(y1in, out)
    factorized, h0, s0, age = _begin(ws, m)
    # a fresh matrix before the next correction (set where the iteration asks for one)
    pending = not factorized or abs(h - h0) > 1e-3 * abs(h) or abs(s - s0) > 0.2 or age >= c[_MAX_AGE]
    refreshed = False  # a matrix was factorized in this solve
    since = 1  # iterations since the last factorization (1: not factorized in this solve)
    tol = c[_TOL]
    last = -1.0
    rate = np.inf  # the smallest θ of this solve with this matrix
    suspect = 0.0  # > 0: the rate of the single-precision copy, being compared with double precision
    for _ in range(int(c[_MAX_NEWTON])):
        if pending:
            pending = False
            refreshed = True
            code = _refactor(ws, m, t, h, y, out, s)
            if code != _OK:
                return code, False
            since = 0
            last = -1.0
            rate = np.inf
            suspect = 0.0
        code, delta, size, states, scale, finite, low = _correct(ws, m, t, h, y, out, s)
        if code != _OK:
            return code, False
        if not finite:
            if since == 0:
                return _FAIL, False
            _copy(y1in, out)  # restart from the start with a fresh matrix
            pending = True
            continue
        has_theta = last > 0.0
        theta = size / last if has_theta else 0.0
        if low and refreshed and has_theta and theta > c[_RATE]:
            # a matrix factorized in this solve contracts poorly: its single-precision copy may be
            # to blame (conditioning), or the iteration is far from linear. Redo the correction in
            # double and compare the rates
            _precision(ws, DOUBLE_NEXT)
            suspect = theta
            last = -1.0
            rate = np.inf
            continue
        if suspect > 0.0 and has_theta:
            # double precision with the same matrix: a strike if it contracts where single did not
            if theta <= c[_RATE] and since > 0:
                _precision(ws, STRIKE)
            suspect = 0.0
        if has_theta and (theta >= 0.5 or theta >= c[_STAGNATION] * rate) and size <= c[_ZONE] * tol * scale:
            _add(out, delta)  # stagnating at round-off level: accept
            return _OK, False
        if refreshed and has_theta and theta >= 0.5 and states <= c[_FLOOR] * scale:
            # no progress with a fresh matrix: round-off amplified by its conditioning (a
            # multiplier at rest, say) — the iterate is as good as it gets, but the driver is
            # told (the conditioning may come from a singular configuration)
            _add(out, delta)
            return _OK, True
        if has_theta and theta >= 1.0 and since > 0 and size > 1e3 * tol * scale:
            pending = True  # the old matrix no longer contracts: refresh it here and retry
            continue
        _add(out, delta)
        since += 1
        if size <= 1e-2 * tol * scale:
            return _OK, False
        if has_theta:
            if theta < 1.0 and theta / (1.0 - theta) * size <= tol * scale:
                return _OK, False
            rate = min(rate, theta)
            pending = theta > c[_RATE]
        last = size
    if pending:  # asked for in the last iteration: the next solve (a retry, a split) starts with it
        code = _refactor(ws, m, t, h, y, out, s)
        if code != _OK:
            return code, False
    return _FAIL, False


def discrete_gradient(ham, escale, ws, c, e, t, h, y, guess, p, out):
    """One discrete-gradient step (:mod:`phc.simulation.discrete_gradient`): the stage equations
    at ``y(s)`` and the energy balance ``r(s) = H(y₁) − H(y) + E₁ − E = 0`` (E: the energy
    accumulator, unknown ``e``), by a safeguarded secant iteration on ``s`` from ``s = 1/2``.

    Returns ``(code, ill_conditioned, y1, best, scale, y_half, secants)``: ``y1`` the step
    (``out`` or the best secant iterate), ``best`` its ``|r|`` and ``scale`` the energy scale
    the tolerance ``c[_BAL_TOL]`` is relative to, ``y_half`` the implicit-midpoint step
    (``s = 1/2``) for the caller's fallback where no point balances the energy."""
    code, ill = _stage(ws, 0, t, h, y, guess, 0.5, out)
    if code != _OK:
        return code, ill, out, 0.0, 0.0, out, 0
    # H of the energy states: the velocities H is written in (H = ½pᵀv + V, M(q) v = p imposed
    # at the stage point) made consistent at the step's ends (phc.simulation.discrete_gradient)
    y0 = y.copy()
    _consistent(ws, t, y0)
    _consistent(ws, t + h, out)
    H0 = ham(t, y0, p)
    bal = ham(t + h, out, p) - H0 + out[e] - y[e]
    # the balance H + E is kept relative to its terms; a body at rest that sticks (docs/events.md)
    # has H ~ 1e-250: below 1e-200 the energy is zero
    scale = max(abs(escale(t, y, p)), abs(escale(t + h, out, p)), abs(y[e]), abs(out[e]), 1e-200)
    if not (np.isfinite(bal) and np.isfinite(scale)):
        return _EVAL, ill, out, 0.0, 0.0, out, 0
    # the stage values are known to c[_TOL] of their nominal sizes; where H is stationary (a body
    # at rest that sticks: H ~ 1e-33 and below) its error is second order in theirs, c[_TOL]²
    # of the run's energy scale c[_RUN_ENERGY] (scaling.run_energy): no secant resolves less
    tol = max(c[_BAL_TOL] * scale, c[_TOL] * c[_TOL] * c[_RUN_ENERGY])
    if abs(bal) <= tol:
        return _OK, ill, out, abs(bal), scale, out, 0
    # first slope from the curvature of φ(σ) = H(y(σ)): r'(s) ≈ −φ''(s)
    curv = 4.0 * (H0 - 2.0 * ham(t + 0.5 * h, y0 + 0.5 * (out - y0), p) + ham(t + h, out, p))
    if not np.isfinite(curv):
        return _EVAL, ill, out, 0.0, 0.0, out, 0
    y_half = out.copy()
    s_prev = 0.5
    r_prev = bal
    y_prev = y_half
    slope = -curv if curv != 0.0 else -abs(bal) * 10.0
    best = abs(bal)
    y_best = y_half
    secants = 0
    for _ in range(int(c[_MAX_SECANT])):
        secants += 1
        s_new = min(max(s_prev - r_prev / slope, c[_S_MIN]), c[_S_MAX]) if slope != 0.0 else 0.5
        if s_new == s_prev:
            break
        code, ill = _stage(ws, 0, t, h, y, y_prev, s_new, out)
        if code != _OK:
            break
        _consistent(ws, t + h, out)
        r_new = ham(t + h, out, p) - H0 + out[e] - y[e]
        if not np.isfinite(r_new):
            return _EVAL, ill, out, 0.0, 0.0, y_half, secants
        if abs(r_new) < best:
            best = abs(r_new)
            y_best = out.copy()
        if abs(r_new) <= tol:
            return _OK, ill, out, abs(r_new), scale, y_half, secants
        if r_new != r_prev:
            slope = (r_new - r_prev) / (s_new - s_prev)
        s_prev = s_new
        r_prev = r_new
        y_prev = out.copy()
    # within the round-off floor of H's evaluation: accept; else no point balances the energy
    # (the constraint projection's work, phc.simulation.discrete_gradient): the step fails
    return (_OK if best <= 1e3 * tol else _FAIL), ill, y_best, best, scale, y_half, secants


def passivity_floor(escale, run_energy):
    """The energy below which a composite step's net dissipation counts as round-off of zero
    (midpoint4's passivity guard): ``1e-13·max(escale, run_energy)`` with ``escale`` the energy
    scale of the step's state and ``run_energy`` the run's (``c[_RUN_ENERGY]``). The state's
    alone vanishes with the state: a driven block that sticks holds H ≈ 1e-73, whose round-off
    power (±4e-54) the guard took for a passivity violation."""
    return 1e-13 * max(escale, run_energy) + 1e-300


def midpoint4(powers, escale, ws, c, t, h, y, guess, p, out, hist_t, hist_v, nhist, algmask):
    """One step of the fourth-order composition (:mod:`phc.simulation.midpoint4`): midpoint
    substeps of ``c[_G1]·h, c[_G2]·h, c[_G1]·h`` (matrix 0 for the outer ones, 1 for the middle
    one), each started from its predicted midpoint, then the passivity guard. Returns
    ``(code, ill_conditioned, nhist)``; the step's end is in ``out``.

    Predictor: the midpoint of substep i (at ``t + c[_M0 + i]·h``) extrapolated linearly from
    the same substep of the last two steps (``hist_t[k, i]``, ``hist_v[k, i]``, ``nhist`` of them
    known), else: the differential variables along the slope from ``y`` to the driver's ``guess``,
    the algebraic ones (``algmask`` not 0) at the step's predicted midpoint ``(y + guess)/2``
    (:func:`predict`'s guess is ``2 m − y``). Their values at ``y`` are the end values of the last
    step, which oscillate about the midpoint values; after a passage of a rank drop they carry the
    undetermined multiplier in full (±9e8 N after the N four-bar's first passage, against values
    of order one at the midpoints), and the line from there started the substeps on another
    solution of their equations: at h = 1e-4 a step reversed the four-bar's motion (the
    coupler's vertical momentum −4.95 → +4.95 kg m/s, docs/hard-cases.md). The history is updated
    on success and forgotten (``nhist = 0``) on failure. A composite step whose net dissipated
    energy ``Σ γᵢh·P_diss(midpointᵢ)`` is negative violates passivity: :data:`_PASSIVITY`."""
    fr = (c[_G1], c[_G2], c[_G1])
    mt = (c[_M0], c[_M1], c[_M2])
    ill = False
    start = y.copy()
    tau = t
    dissipated = 0.0
    scale = 0.0
    values = np.empty((3, y.shape[0]))
    for i in range(3):
        m = 0 if i != 1 else 1
        hs = fr[i] * h
        ti = t + mt[i] * h
        if nhist == 2:
            mid = hist_v[1, i] + (ti - hist_t[1, i]) * (hist_v[1, i] - hist_v[0, i]) / (hist_t[1, i] - hist_t[0, i])
        else:
            mid = np.where(algmask != 0, 0.5 * (y + guess), y + mt[i] * h * ((guess - y) / h))
        code, ill_i = _stage(ws, m, tau, hs, start, 2.0 * mid - start, 0.5, out)
        ill = ill or ill_i
        if code != _OK:
            return code, ill, 0
        _copy(0.5 * (start + out), values[i])
        diss = hs * powers(tau + 0.5 * hs, values[i], (out - start) / hs, p)[1]
        if not np.isfinite(diss):
            return _EVAL, ill, 0
        dissipated += diss
        scale += abs(diss)
        _copy(out, start)
        tau = tau + hs
    # round-off of a dissipation that is zero (a body that sticks, docs/events.md) is no violation
    floor = passivity_floor(abs(escale(t, y, p)), c[_RUN_ENERGY])
    if dissipated < -1e-9 * scale - floor:
        return _PASSIVITY, ill, 0
    if nhist == 2:
        for i in range(3):
            hist_t[0, i] = hist_t[1, i]
            _copy(hist_v[1, i], hist_v[0, i])
        k = 1
    else:
        k = nhist
        nhist += 1
    for i in range(3):
        hist_t[k, i] = t + mt[i] * h
        _copy(values[i], hist_v[k, i])
    return _OK, ill, nhist


def lagrange_weights(pt, k, tn, w):
    """w[0:k] ← the Lagrange weights at ``tn`` of the nodes ``pt[0:k]``: the predictor's
    polynomial through the last step midpoints is ``Σ w[a]·m_a``."""
    for a in range(k):
        wa = 1.0
        for b in range(k):
            if b != a:
                wa *= (tn - pt[b]) / (pt[a] - pt[b])
        w[a] = wa


def predictor_nodes(order, known):
    """How the predictor extrapolates a variable whose polynomial degree is ``order`` when
    ``known`` step midpoints are known: 0, the last midpoint (degree 0); 1, the line through
    the last midpoint along the last slope (degree 1, or while fewer than three midpoints are
    known); k ≥ 3, the polynomial through the last k midpoints (:func:`lagrange_weights`)."""
    if order == 0:
        return 0
    k = min(order + 1, known)
    return 1 if k < 3 else k


# The operations in the Python loop: the workspace object's methods, NumPy arithmetic.

def _begin(ws, m):
    return ws.begin(m)


def _refactor(ws, m, t, h, y, y1, s):
    return ws.refactor(m, t, h, y, y1, s)


def _correct(ws, m, t, h, y, y1, s):
    return ws.correct(m, t, h, y, y1, s)


def _add(y1, delta):
    y1 += delta


def _copy(src, dst):
    dst[...] = src


def _precision(ws, event):
    """The Python loop solves in double precision only: nothing to switch."""


def _stage(ws, m, t, h, y, y1in, s, out):
    return ws.solve_stage(m, t, h, y, y1in, s, out)


def _consistent(ws, t, y):
    ws.consistent(t, y)
