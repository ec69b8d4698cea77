"""IDA with the model's compiled functions called from C: the native driver (prototype).

A run of the ``ida`` solver on the C back end (:mod:`phc.codegen.c_backend`) goes through
phc's IDA driver (``phc/codegen/c_runtime/ida_driver.c``, built against the machine's own
SUNDIALS by :mod:`phc.codegen.c_ida`) when it can: IDA calls the model library's
``phc_residual`` and ``phc_jacobian`` through function pointers and takes its steps in a C loop
(``IDA_ONE_STEP`` with the run's end as stop time; the outputs by IDA's own interpolation), and
Python sees the run only between chunks of steps — no Python frame per residual, Jacobian or
step. IDA's settings are :func:`phc.simulation.ida.run_settings`' (the tolerances, the id
vector, the maximum order: the same numbers scikit-sundae is given), the dense linear solver
is SUNDIALS' own, as scikit-sundae's ``dense``.

The singularity monitor's routine looks are the driver's own (:data:`C_LOOKS`): at the
monitor's cadence it looks at the equilibrated iteration matrix in C, with the fixed-step C
loop's routine look (``c_runtime/dense_lu.c``: its LU and 1-norm condition estimate, as LAPACK's
``dgecon`` is in Python's monitor), and a look that finds the matrix clearly far from singular
costs no Python: it is recorded, and replayed into the monitor between chunks
(:meth:`~phc.simulation.monitor.SingularityMonitor.routine_looks`: the worst ratio, the last looks,
the history a diagnosis reads), and the next cadence is set in C
(:func:`phc.simulation.look_cadence.cadence_after`, translated). Every other look ends the chunk
and is Python's monitor's, exactly as :class:`phc.simulation.ida._StepHook` makes it without the
driver (``_StepHook._look``: the look itself, its minimum search, the crawl check, the stops): a
look the condition estimate does not clear; one that brackets a minimum of the conditioning with
the two before it (:func:`~phc.simulation.look_cadence.brackets_minimum`) where the monitor's
search between them (:func:`~phc.simulation.look_cadence.golden_search` along
:func:`~phc.simulation.look_cadence.hermite`, which the driver runs in C first) meets a point the
estimate does not clear; and one where IDA crawls (:func:`~phc.simulation.look_cadence.crawls`).
Python's looks ask the driver's estimate first (``SingularityMonitor.rcond``). Between chunks, this module does what the step hook
does after a step: a chunk ends where phc's choice of the maximum order looks next
(:func:`phc.simulation.order.after_step`; a switch starts a new IDA), at ``max_steps``, at a look
Python makes, and after at most :data:`CHUNK` steps (progress, Ctrl-C).

Not in the native path (the run goes through scikit-sundae, :func:`phc.simulation.ida.integrate_ida`,
and says why once per process): switching conditions (events: IDA's root finding), models
above :data:`~phc.simulation.ida.DENSE_LIMIT` unknowns (the sparse solver), models not on the
C back end, and machines without SUNDIALS' headers. A run IDA fails on, or the monitor stops
(a rank drop phc may bridge, a domain edge), is run again from its start through
scikit-sundae, whose path diagnoses failures and bridges rank drops
(:mod:`phc.simulation.ida_bridge`): the diagnosis is written once.
"""

from __future__ import annotations

import time
import warnings
from collections import deque

import numpy as np

from phc.simulation.backend import BackendRun
from phc.simulation.guard import GuardedModule
from phc.simulation.ida import (DENSE_LIMIT, PROGRESS_STEPS, _Stop, _StepHook, integrate_ida, run_settings)
from phc.simulation.look_cadence import SEARCH_ITERATIONS
from phc.simulation.monitor import SingularityMonitor, check_scales, unbounded_growth
from phc.simulation.order import CHECK_STEPS, DEFAULT_ORDER, RECENT_STEPS, Switch, after_step

CHUNK = 1000
"""Most steps one call of the C driver takes before Python sees the run again (progress,
Ctrl-C): a millisecond or so on small models."""

DONE = 1
"""``PHC_DONE`` of ida_driver.c: the last output time is reached."""

C_LOOKS = True
"""Whether the driver makes the monitor's routine looks itself, in C (see the module's docstring);
False: every look is Python's, the chunks ending at each (the same looks, decided alike: tests
compare the two)."""

LI_CADENCE, LI_SINCE, LI_BASE, LI_STEPS, LI_NEXT_CHECK, LI_MAX_STEPS, LI_LOOKS, LI_FLAG, LI_CAPACITY, LI_ITERATIONS = range(10)
"""The routine look's integer state (ida_driver.c's ``li[]``)."""
LF_THRESHOLD, LF_H_FLOOR, LF_T_END, LF_LAST_RATIO, LF_T0, LF_R0, LF_T1, LF_R1 = range(8)
"""Its float state (``lf[]``; NaN: no look)."""

_SAID: set = set()


def say_unused(why: str) -> None:
    """Say once per process and reason that the native IDA driver does not run a simulation."""
    from phc.errors import CompiledLoopWarning, caller_stacklevel

    if not why or why in _SAID:
        return
    _SAID.add(why)
    warnings.warn(f"IDA runs through scikit-sundae, not phc's native IDA driver: {why}", CompiledLoopWarning,
                  stacklevel=caller_stacklevel())


def usable(mod, events=None) -> tuple[bool, str]:
    """Whether an IDA run of `mod` (a generated module, guarded or not) can use the native
    driver, and if not, why ("" where there is nothing to say: not on the C back end)."""
    raw = mod.module if isinstance(mod, GuardedModule) else mod
    if getattr(raw, "BACKEND", "") != "c" or getattr(raw, "C_LIBRARY", None) is None:
        return False, ""
    from phc.codegen import c_ida

    if c_ida.library() is None:
        return False, c_ida.why_not()
    if events is not None and getattr(events, "n", 0):
        return False, "the model has switching conditions (events), which need IDA's root finding"
    if raw.N > DENSE_LIMIT:
        return False, f"the model has {raw.N} unknowns, above the {DENSE_LIMIT} of the dense linear solver"
    return True, ""


def integrate(mod, p, t_out, y0, yp0, options, *, progress=None, names=None, events=None,
              nominal=None) -> BackendRun:
    """:func:`phc.simulation.ida.integrate_ida`'s interface and results: through the native
    driver where :func:`usable`, else (and after a failure, from the start) through scikit-sundae."""
    use, why = usable(mod, events)
    if use:
        run, why = _native(mod, p, t_out, y0, yp0, options, progress=progress, names=names, nominal=nominal)
        if run is not None:
            return run
    say_unused(why)
    return integrate_ida(mod, p, t_out, y0, yp0, options, progress=progress, names=names, events=events,
                         nominal=nominal)


def _native(mod, p, t_out, y0, yp0, options, *, progress, names, nominal):
    """(the run, "") through the C driver, or (None, why it handed the run to scikit-sundae)."""
    from phc.codegen import c_ida

    lib = c_ida.library()
    raw = mod.module if isinstance(mod, GuardedModule) else mod
    n = int(raw.N)
    rtol, max_steps = float(options.rtol), int(options.max_steps)
    t_out = np.ascontiguousarray(t_out, dtype=float)
    t0, t_end = float(t_out[0]), float(t_out[-1])
    y0 = np.ascontiguousarray(y0, dtype=float)
    atol, _local, _atol_j, yp0, choice, settings, calls = run_settings(mod, p, t0, t_end, y0, yp0, options, nominal)
    yp0 = np.ascontiguousarray(yp0, dtype=float)
    ida_rtol = float(settings["rtol"])
    atol_vec = np.ascontiguousarray(np.broadcast_to(np.asarray(settings["atol"], dtype=float), (n,)))
    ident = np.ones(n)
    ident[np.asarray(settings["algebraic_idx"], dtype=np.intp)] = 0.0
    pv = np.ascontiguousarray(p, dtype=float)
    jrows = np.ascontiguousarray(raw.JAC_ROWS, dtype=np.int64)
    jcols = np.ascontiguousarray(raw.JAC_COLS, dtype=np.int64)
    residual, jacobian = c_ida.model_functions(raw.C_LIBRARY)
    _ptr = c_ida.address

    monitor = SingularityMonitor(mod, p, names=names, scales=nominal, count_factors=True)
    monitor.h_floor = 1e-6 * (t_end - t0)
    monitor.start = (t0, y0, yp0.copy())
    # the step hook's state and its monitor looks (_StepHook._look), fed at the ends of chunks
    hook = _StepHook(t0, y0, yp0, t_end=t_end, max_steps=max_steps, monitor=monitor, calls=calls, progress=None,
                     base=10 if n <= 60 else 20)
    status = np.zeros(1, np.int64)
    c_looks = C_LOOKS and monitor.enabled
    if c_looks:  # the routine look's state and record (ida_driver.c: phc_ida_watch)
        capacity = CHUNK // hook.base + 2  # (the cadence is at least the base: CHUNK // base looks a chunk)
        li, lf = np.zeros(c_ida.LI_N, np.int64), np.full(c_ida.LF_N, np.nan)
        li[LI_BASE], li[LI_MAX_STEPS], li[LI_CAPACITY], li[LI_ITERATIONS] = hook.base, max_steps, capacity, SEARCH_ITERATIONS
        lf[LF_THRESHOLD], lf[LF_H_FLOOR], lf[LF_T_END] = monitor.threshold, monitor.h_floor, t_end
        look_t, look_h, look_r = np.empty(capacity), np.empty(capacity), np.empty(capacity)
        look_y, look_yp = np.empty((capacity, n)), np.empty((capacity, n))
        last_h, last_y, last_yp = np.zeros(3), np.zeros((3, n)), np.zeros((3, n))  # the last looks (the search's)
        watch_where = [_ptr(a) for a in (li, lf, look_t, look_h, look_r, look_y, look_yp, last_h, last_y, last_yp)]

    current = [None]  # the driver's IDA (a switch of the order makes a new one)
    if c_looks:
        rcond_c = lib.phc_ida_rcond

        def rcond(t, y_, yp_, h):
            if not current[0]:  # (freed: the monitor's own look)
                return np.nan
            y_, yp_ = np.ascontiguousarray(y_, dtype=float), np.ascontiguousarray(yp_, dtype=float)
            return rcond_c(current[0], float(t), _ptr(y_), _ptr(yp_), float(h))

        monitor.rcond = rcond  # the looks Python makes ask the driver's estimate first

    def create(t, y, yp, order, h0):
        w = lib.phc_ida_create(n, len(jrows), residual, jacobian, _ptr(pv), _ptr(jrows), _ptr(jcols), float(t),
                               _ptr(np.ascontiguousarray(y, dtype=float)), _ptr(np.ascontiguousarray(yp, dtype=float)),
                               ida_rtol, _ptr(atol_vec), _ptr(ident), int(order), t_end, float(h0),
                               max_steps + 1, _ptr(status))
        if not w:
            raise RuntimeError(f"SUNDIALS refused the driver's setup (step {int(status[0])} of phc_ida_create)")
        if c_looks:
            lib.phc_ida_watch(w, *watch_where)
        current[0] = w
        return w

    def looks_in() -> None:
        """The hook's and the monitor's state of the looks, for the driver's routine looks."""
        li[LI_CADENCE], li[LI_SINCE], li[LI_STEPS], li[LI_NEXT_CHECK] = (hook.cadence, hook.since_look, steps,
                                                                          hook.next_crawl_check)
        lf[LF_LAST_RATIO] = np.nan if hook.last_ratio is None else hook.last_ratio
        looks = monitor._looks[-2:]
        last = [(look[0], look[4]) for look in looks]
        last = [(np.nan, np.nan)] * (2 - len(last)) + last
        (lf[LF_T0], lf[LF_R0]), (lf[LF_T1], lf[LF_R1]) = last
        for i, look in enumerate(looks, 2 - len(looks)):
            last_y[i], last_yp[i], last_h[i] = look[1], look[2], look[3]

    def looks_out() -> int:
        """The driver's routine looks of the chunk, kept by the monitor and the hook; the steps since the
        last look (a look Python must make: as many as the cadence or more)."""
        m = int(li[LI_LOOKS])
        if m:
            monitor.routine_looks(look_t[:m].tolist(), look_y[:m].copy(), look_yp[:m].copy(), look_h[:m].tolist(),
                                  look_r[:m].tolist())
            hook.cadence, hook.last_ratio = int(li[LI_CADENCE]), float(lf[LF_LAST_RATIO])
        return int(li[LI_SINCE])

    nout = len(t_out)
    ys, yps = np.empty((nout, n)), np.empty((nout, n))
    ys[0], yps[0] = y0, yp0
    k = np.ones(1, np.int64)
    hist = np.empty(2 * CHUNK)
    taken_c, cur, h_ref = np.zeros(1, np.int64), np.zeros(1), np.zeros(1)
    y, yp = y0.copy(), yp0.copy()
    counts, reals = np.zeros(6, np.int64), np.zeros(3)
    y_failed, yp_failed = np.empty(n), np.empty(n)
    recent = deque(maxlen=RECENT_STEPS)
    steps = since_progress = 0
    nfev = njev = 0
    ok, message, interrupted, used_up = True, "integration finished", False, False
    # the addresses the C loop writes at, taken once (finding an array's address costs microseconds)
    where = [_ptr(a) for a in (t_out, k, ys, yps, hist, taken_c, cur, y, yp, h_ref)]
    stats_where = [_ptr(a) for a in (counts, reals, y_failed, yp_failed)]
    advance, stats = lib.phc_ida_advance, lib.phc_ida_stats
    start = time.process_time()
    w = create(t0, y0, yp0, choice.order, 0.0)
    try:
        while True:
            budget = min(CHUNK, max_steps - steps)
            if monitor.enabled and not c_looks:  # end the chunk at the monitor's next look
                budget = min(budget, max(1, hook.cadence - hook.since_look))
            if not choice.final:  # end the chunk where phc's choice of the order looks next
                if choice.order == DEFAULT_ORDER:
                    budget = min(budget, max(1, choice.next_look - steps))
                elif choice.trial_mark is None:
                    budget = 1
                else:
                    budget = min(budget, max(1, CHECK_STEPS - (steps - choice.trial_mark[1])))
            h_ref[0] = hook.h_ref  # (a rewind clears it)
            if c_looks:
                looks_in()
            result = advance(w, where[0], nout, where[1], budget, *where[2:])
            taken = int(taken_c[0])
            if result < 0:
                # (IDA's own words, lib.phc_ida_message(w), are the scikit-sundae path's to give)
                return None, ("a run IDA fails on is run again from its start through scikit-sundae, whose path "
                              "diagnoses failures and bridges rank drops")
            t = float(cur[0])
            if taken:
                hs = hist[1:2 * taken:2]
                steps += taken
                since_progress += taken
                recent.extend(hs[-RECENT_STEPS:].tolist())
                hook.after_chunk(steps, t, y, yp, hs, h_ref[0], since_look=looks_out() if c_looks else None)
                if not choice.final:
                    try:
                        after_step(choice, mod, p, t, y, yp, steps=steps, recent=recent, t_end=t_end)
                    except Switch as switch:  # a new IDA at the order phc chose (IDA sets it when made)
                        stats(w, *stats_where)
                        nfev, njev = nfev + int(counts[0]), njev + int(counts[1])
                        lib.phc_ida_free(w)
                        w = current[0] = None
                        if switch.rewind:
                            hook.rewind(t0, y0, yp0)
                            k[0] = 1
                            w = create(t0, y0, yp0, choice.order, 0.0)
                        else:
                            w = create(switch.t, switch.y, switch.yp, choice.order, switch.h)
                        recent.clear()
                        continue
            if progress is not None and since_progress >= PROGRESS_STEPS:
                since_progress = 0
                progress(t)
            if result == DONE:
                break
            if steps >= max_steps and t < t_end:
                raise _Stop(f"stopped after {steps} steps at t = {t:.6g} (max_steps); raise `max_steps` or "
                            "loosen the tolerances", max_steps=True)
        if progress is not None and k[0] > 1:
            progress(float(t_out[k[0] - 1]))
    except _Stop as stop:
        if not stop.max_steps:  # the monitor's stop: the scikit-sundae path words it and may bridge it
            return None, ("a run the singularity monitor stops is run again from its start through scikit-sundae, "
                          "whose path bridges rank drops")
        ok, message, used_up = False, stop.message, True
        grows = unbounded_growth(mod, *hook.latest(), start=monitor.start, scales=nominal)
        if grows:
            message = (f"stopped after {steps} steps at t = {hook.t_last:.6g}: {grows}; results up to "
                       f"t = {t_out[k[0] - 1]:.6g} are kept")
    except KeyboardInterrupt:
        ok, interrupted = False, True
        message = f"interrupted at t = {t_out[k[0] - 1]:.6g}"
    finally:
        if w:
            stats(w, *stats_where)
            nfev, njev = nfev + int(counts[0]), njev + int(counts[1])
            lib.phc_ida_free(w)
            current[0] = None
    kk = int(k[0])
    if not message.startswith(("stopped ", "interrupted")):
        note = check_scales(mod, ys[:kk], yps[:kk], t_end - t0, rtol, atol, not ok, scales=nominal)
        if note:
            message = f"{message}; {note}"
    major, minor = lib.sundials_version
    return BackendRun(t_out[:kk], ys[:kk], yps[:kk], steps=steps, nfev=nfev, njev=njev, success=ok,
                      message=message, cpu=time.process_time() - start, conditioning=monitor.worst,
                      interrupted=interrupted,
                      extra=dict(max_steps_reached=used_up, t_reached=hook.t_last, max_order=choice.order,
                                 order_note=choice.note(), max_order_chosen=choice.order if choice.decided else None,
                                 ida_driver=f"native (SUNDIALS {major}.{minor})")), ""


__all__ = ["CHUNK", "integrate", "say_unused", "usable"]
