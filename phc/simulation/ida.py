"""SUNDIALS IDA backend (variable-order BDF) through scikit-sundae.

Index-2 systems (GGL-stabilized position constraints, velocity constraints through port
couplings) are integrated with all algebraic variables excluded from the local error
test — the effect of IDA's ``IDASetSuppressAlg``, which scikit-sundae does not expose;
we get it with a very large absolute tolerance on algebraic components. Accuracy is
controlled on the differential (energy) states, which determine the algebraic ones.

The solver is advanced one internal step at a time so that a failure keeps the output
computed so far, progress can be reported, and the number of steps is known; output
times inside the last step are filled by IDA's own interpolation.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
import scipy.sparse as sps

from phc.errors import SimulationSetupError
from phc.simulation.guard import ModelEvaluationError
from phc.simulation.monitor import SingularityMonitor, check_scales, diagnose_failure

ALGEBRAIC_ATOL = 1e8
"""Absolute tolerance on algebraic variables: effectively removes them from the error test."""

DENSE_LIMIT = 80

MAX_ORDER = 5
"""Maximum BDF order (5 is IDA's default; 2 is A-stable for undamped stiff oscillations)."""
"""Systems up to this size use the dense linear solver; larger ones the sparse one."""

_STATUS_HINTS = {
    -1: "the solver took too many steps; raise `max_steps` or shorten the time span",
    -2: "the tolerances are too tight for double precision; loosen `rtol`/`atol`",
}
"""Hints for failures whose cause the status says; error-test (-3) and Newton (-4) failures
are diagnosed at the failure point (:func:`phc.simulation.monitor.diagnose_failure`)."""


def _import_ida():
    try:
        from sksundae.ida import IDA
    except ImportError as err:  # pragma: no cover - dependency is required
        raise SimulationSetupError("the IDA backend needs scikit-sundae: pip install scikit-sundae") from err
    return IDA


def integrate_ida(mod, p, t_out, y0, yp0, *, rtol, atol, max_steps, progress=None, max_order=None, names=None,
                  events=None):
    """Integrate from ``t_out[0]`` and return a dict of arrays and statistics.

    `events` (a :class:`phc.simulation.events.Watch`, optional) are switching functions
    w(t, y, ẏ), positive while the modes hold: IDA's root finding (scikit-sundae's
    ``eventsfn``, direction −1, terminal) stops at the first that falls to zero; the run
    then returns with ``event`` = dict(t, y, yp, which) and the outputs before it."""
    IDA = _import_ida()
    n = mod.N
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    buf = np.zeros(len(rows))
    residual, jacobian = mod.residual, mod.jacobian

    def resfn(t, y, yp, res):
        residual(t, y, yp, p, res)

    sparse = n > DENSE_LIMIT
    last_cj = [0.0]  # cj = α/h of the last Jacobian: the step IDA was trying when it failed
    if sparse:
        def jacfn(t, y, yp, res, cj, JJ):
            last_cj[0] = cj
            jacobian(t, y, yp, p, cj, JJ)
    else:
        def jacfn(t, y, yp, res, cj, JJ):
            last_cj[0] = cj
            jacobian(t, y, yp, p, cj, buf)
            JJ.fill(0.0)
            JJ[rows, cols] = buf

    atol_vec = np.where(diff, atol, ALGEBRAIC_ATOL)
    options = dict(rtol=rtol, atol=atol_vec, jacfn=jacfn, algebraic_idx=[int(j) for j in np.flatnonzero(~diff)],
                   max_num_steps=max(10, max_steps), max_order=int(max_order or MAX_ORDER))
    if sparse:
        pattern = sps.csc_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
        options.update(linsolver="sparse", sparsity=pattern)
    with warnings.catch_warnings():
        # scikit-sundae warns that its own sparse approximation is unused: we pass jacfn.
        warnings.filterwarnings("ignore", message="Custom sparse Jacobian approximation")
        if events is not None and events.n:
            def eventsfn(t, y, yp, out):
                out[:] = events(t, y, yp)

            eventsfn.direction = [-1] * events.n   # w falls through 0: the mode no longer holds
            eventsfn.terminal = [True] * events.n
            options.update(eventsfn=eventsfn, num_events=events.n)
        solver = IDA(resfn, **options)
    t_out = np.asarray(t_out, dtype=float)
    def scales(failed, upto=1):  # the states of the run so far (a system at rest at t0 may move later)
        return check_scales(mod, ys[:upto], yps[:upto], float(t_out[-1] - t_out[0]), rtol, atol, failed)

    ys = np.empty((len(t_out), n))
    yps = np.empty((len(t_out), n))
    ys[0], yps[0] = y0, yp0
    start = time.process_time()
    init = solver.init_step(t_out[0], y0, yp0)
    if not init.success:
        return dict(t=t_out[:1], y=ys[:1], yp=yps[:1], steps=0, nfev=0, njev=0, success=False,
                    message=f"IDA could not start: {init.message}" + (f"; {scales(True)}" if scales(True) else ""),
                    cpu=time.process_time() - start)
    k, steps, ok, message = 1, 0, True, "integration finished"
    event = None
    nfev = njev = 0
    t_end = t_out[-1]
    t_last = float(t_out[0])
    h_last = 0.0
    # A failure is diagnosed at the last state reached with a normal step (h > h_ref/10, h_ref
    # the recent largest step, decaying 0.1 % a step): the steps collapse before IDA gives up.
    h_ref = 0.0
    normal = (float(t_out[0]), np.asarray(y0, dtype=float), np.asarray(yp0, dtype=float))
    monitor = SingularityMonitor(mod, p, names=names)
    monitor.h_floor = 1e-6 * float(t_out[-1] - t_out[0])
    monitor_every = 5 if n <= 60 else 20
    interrupted = False
    try:  # a model function outside its domain, or Ctrl-C: keep the outputs filled so far
        while k < len(t_out):
            res = solver.step(t_end, method="onestep", tstop=t_end)
            t_step = float(np.atleast_1d(res.t)[-1])
            if t_step != t_last:  # a onestep call after an interpolation may return without stepping
                steps += 1
                h_last, t_last = t_step - t_last, t_step
                h_ref = max(h_last, 0.999 * h_ref)
            nfev, njev = getattr(res, "nfev", nfev), getattr(res, "njev", njev)
            if not res.success:
                ok = False
                hint = _STATUS_HINTS.get(int(res.status))
                if hint is None:  # diagnose before blaming: is the iteration matrix singular there?
                    hint = diagnose_failure(mod, p, *normal, status=int(res.status), h_typical=h_ref,
                                            h_fail=(1.0 / last_cj[0]) if last_cj[0] > 0 else h_last,
                                            max_order=int(max_order or MAX_ORDER), rtol=rtol, atol=atol, names=names)
                message = f"IDA failed at t = {float(res.t):.6g} (status {res.status}: {res.message}); {hint}"
                break
            t_now = float(np.atleast_1d(res.t)[-1])
            if h_last > 0.1 * h_ref:
                normal = (t_now, np.atleast_2d(res.y)[-1], np.atleast_2d(res.yp)[-1])
            if monitor.enabled and (steps % monitor_every == 0):
                warning = monitor.watch(t_now, np.atleast_2d(res.y)[-1], np.atleast_2d(res.yp)[-1], h_last)
                if warning:
                    ok, message = False, warning
                    # the configuration may lie before outputs already filled in: keep none past it
                    k = max(1, min(k, int(np.searchsorted(t_out, monitor.stop_time, side="right"))))
                    break
            while k < len(t_out) and t_out[k] <= t_now + 1e-14 * max(1.0, abs(t_now)):
                r = solver.step(t_out[k], method="normal")
                ys[k] = np.atleast_2d(r.y)[-1]
                yps[k] = np.atleast_2d(r.yp)[-1]
                k += 1
            if progress is not None:
                progress(t_now)
            if int(res.status) == 2 and res.i_events is not None:  # IDA_ROOT_RETURN: a switching function hit 0
                event = dict(t=t_now, y=np.array(np.atleast_2d(res.y)[-1]), yp=np.array(np.atleast_2d(res.yp)[-1]),
                             which=np.flatnonzero(np.asarray(res.i_events)[-1]).tolist())
                break
            if steps >= max_steps:
                ok = False
                message = (f"stopped after {steps} steps at t = {t_now:.6g} (max_steps); raise `max_steps` or "
                           "loosen the tolerances")
                break
    except ModelEvaluationError as err:
        ok, message = False, f"IDA: {err}; results up to t = {t_out[k - 1]:.6g} are kept"
    except KeyboardInterrupt:
        ok, interrupted = False, True
        message = f"interrupted at t = {t_out[k - 1]:.6g}"
    note = scales(not ok, k) if not message.startswith(("stopped at", "interrupted")) else None
    if note:
        message = f"{message}; {note}"
    extra = {"event": event} if event is not None else {}
    return dict(t=t_out[:k], y=ys[:k], yp=yps[:k], steps=steps, nfev=nfev, njev=njev, success=ok, **extra,
                message=message, cpu=time.process_time() - start, conditioning=monitor.worst, interrupted=interrupted)
