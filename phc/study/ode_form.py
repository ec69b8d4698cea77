"""A compiled model as an ODE ``ẋ = f(t, x)`` for scipy's ``solve_ivp`` methods, built from
the same residual every phc solver integrates (`phc bench` runs scipy's Radau, BDF and
DOP853 beside phc's solvers with it: issue 33, the work–precision corpus).

A compiled model is the DAE ``F(t, y, ẏ) = 0`` (:mod:`phc.ir.dae`) with differential
variables ``x`` (``DIFFERENTIAL``: their rates appear) and algebraic ones ``z`` (efforts,
co-energy variables, multipliers). Given ``t`` and ``x``, the unknowns ``w = (ẋ, z)`` solve

    F(t, x, z, ẋ) = 0,

a system whose Jacobian ``M = [∂F/∂ẋ | ∂F/∂z]`` comes from the compiled Jacobian
(``∂F/∂y + cj·∂F/∂ẏ`` at ``cj = 0`` and ``1``, :func:`phc.study.linearize.dense_jacobians`). When
``M`` is regular — an ODE after eliminating the algebraic variables, an index-1 DAE — ``f``
is ``ẋ(t, x)``, solved by Newton's method with ``M`` factored once per call (the chord
iteration; one correction is exact for a system linear in ``w``, the second confirms it),
and the Jacobian of ``f`` follows from differentiating ``F = 0``:

    ∂w/∂x = −M⁻¹ ∂F/∂x,     ∂f/∂x = the ẋ rows of ∂w/∂x

(for a model with no algebraic variables: ``−(∂F/∂ẏ)⁻¹ ∂F/∂y``). When ``M`` is singular —
a constrained multibody model, whose constraint rows hold no rate and no algebraic
variable (index 2 or 3) — there is no ``f``: :class:`NotAnODE` says so with
:data:`NOT_AN_ODE`, instead of a result. Conditions in t (a load pulse) and input
breakpoints cut the span into pieces, each integrated by a fresh scipy solver with the
conditions' sides of that piece (as phc's drivers do, :mod:`phc.simulation.events`);
conditions on variables and contacts are refused (``f`` would jump at a state event).

The start is phc's consistent initial state (:func:`phc.simulation.start_state`), so the
scipy run starts where phc's runs do.
"""

from __future__ import annotations

import time
from typing import Optional

import numpy as np

from phc.errors import NotAnODE
from phc.names import PEER_SOLVER_NAMES

NOT_AN_ODE = "not an ODE: scipy's explicit/implicit ODE solvers do not apply"
SCIPY_METHODS = tuple(name.removeprefix("scipy_") for name in PEER_SOLVER_NAMES)
"""The solve_ivp methods `phc bench` runs (Radau and BDF with the Jacobian of :class:`OdeForm`)."""
NEWTON_MAX = 8
CHORD_FAST = 3
NEWTON_TOL = 1e-13
"""The chord iteration stops when the correction is below this relative to |w| (round-off:
a few ulps of the solution)."""
MAX_STEPS = 200_000
"""A scipy run that takes more steps stops (a failed row): an explicit method on a stiff mode."""


class OdeForm:
    """``ẋ = f(t, x)`` of a compiled model about its consistent start (see the module).

    Attributes: ``x0`` (the differential variables at the start), ``t0``, ``p``,
    :meth:`fun` and :meth:`jac` for ``solve_ivp``, :meth:`full` (all variables and rates at
    ``(t, x)``), :meth:`states` and :meth:`outputs` (along a run)."""

    def __init__(self, compiled, params: Optional[dict] = None, t0: Optional[float] = None):
        from phc.simulation import initial_values, parameter_vector, start_state
        
        from phc.simulation.impacts import has_contacts

        mod = compiled.module
        self.mod = mod
        time_only = np.asarray(getattr(mod, "SWITCH_TIME_ONLY", ()), dtype=bool)
        if has_contacts(mod) or not time_only.all() or len(getattr(mod, "STICKS", ())):
            raise NotAnODE(f"{NOT_AN_ODE} as one smooth right-hand side: the model has switching conditions on "
                           "its variables or contacts (state events)")
        if len(mod.EQUATIONS) != mod.N:
            raise NotAnODE(f"{NOT_AN_ODE}: {len(mod.EQUATIONS)} equations for {mod.N} variables")
        self.p = parameter_vector(mod, params)
        self.t0 = float(compiled.description.options["t_start"] if t0 is None else t0)
        values, fixed = initial_values(compiled, self.p)
        init = start_state(compiled, self.p, self.t0, values, fixed)
        self.diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
        self.y = np.array(init.y0, dtype=float)
        self.yp = np.array(init.yp0, dtype=float)
        self.yp[~self.diff] = 0.0  # no algebraic rate enters F
        self.x0 = self.y[self.diff].copy()
        self._r = np.zeros(mod.N)
        self._minv = None
        M, _ = self._matrices(self.t0, self.y, self.yp)
        rank = np.linalg.matrix_rank(M)
        if rank < mod.N:
            names = [mod.EQUATIONS[i] for i in np.flatnonzero(np.all(M == 0, axis=1))][:3]
            rows = f" (rows without a rate or an algebraic variable: {', '.join(names)})" if names else ""
            raise NotAnODE(f"{NOT_AN_ODE}: the Jacobian ∂F/∂(ẋ, z) of the residual is singular, rank {rank} of "
                           f"{mod.N} — constraints make it a higher-index DAE{rows}")
        self.nfev = 0
        self.njev = 0
        self._minv = None  # M⁻¹ of the chord iteration, kept while it converges fast

    def set_modes(self, a: float, b: float) -> None:
        """The sides of the conditions in t for the piece (a, b) (none switches inside it),
        frozen in the parameters as phc's event driver freezes them."""
        mod = self.mod
        slots = np.asarray(getattr(mod, "SWITCH_SLOTS", ()), dtype=np.int64)
        if not len(slots):
            return
        free = self.p.copy()
        free[slots] = 0.0
        buf = np.zeros(len(mod.SWITCHES) + len(getattr(mod, "STICKS", ())))
        mod.events(0.5 * (a + b), self.y, self.yp, free, buf)
        self.p[slots] = np.where(buf[: len(slots)] >= 0, 1.0, -1.0)
        self._minv = None

    def cuts(self, t0: float, t1: float) -> list[float]:
        """The switching times of the conditions in t and the input breakpoints inside (t0, t1)."""
        from phc.simulation.events import breakpoints_within, switch_times

        found = {f[0] for f in switch_times(self.mod, self.p, t0, t1, self.y, self.yp)}
        found.update(breakpoints_within(getattr(self.mod, "BREAKPOINTS", ()), t0, t1))
        return sorted(t for t in found if t0 < t < t1)

    def _matrices(self, t, y, yp):
        from phc.study.linearize import dense_jacobians

        Fy, Fyp = dense_jacobians(self.mod, t, y, yp, self.p)
        M = Fyp.copy()
        M[:, ~self.diff] = Fy[:, ~self.diff]
        return M, Fy

    def _solve(self, t: float, x: np.ndarray):
        """(y, ẏ) at (t, x): the algebraic variables and rates by the chord iteration from
        those of the last call, with the last factored M while it converges within
        :data:`CHORD_FAST` corrections (a model linear in w keeps one M for the whole run),
        else with M refactored here."""
        y, yp, diff = self.y, self.yp, self.diff
        y[diff] = x
        for fresh in (False, True):
            if fresh or self._minv is None:
                M, _ = self._matrices(t, y, yp)
                # the inverse, not LU factors: a product is a few µs where scipy's lu_solve
                # costs tens (the small dense systems of this form); the iteration corrects
                # the residual, so the inverse's rounding does not reach the solution
                self._minv = np.linalg.inv(M)
                fresh = True
            limit = NEWTON_MAX if fresh else CHORD_FAST
            for _ in range(limit):
                self.mod.residual(t, y, yp, self.p, self._r)
                if not np.all(np.isfinite(self._r)):
                    raise FloatingPointError(f"the residual is not finite at t = {t:.6g}")
                dw = self._minv @ self._r
                yp[diff] -= dw[diff]
                y[~diff] -= dw[~diff]
                w = np.where(diff, yp, y)
                if np.abs(dw).max() <= NEWTON_TOL * (1.0 + np.abs(w).max()):
                    return y, yp
        raise FloatingPointError(f"the rates do not converge at t = {t:.6g} (Newton on F(t, x, z, ẋ) = 0)")

    def fun(self, t: float, x: np.ndarray) -> np.ndarray:
        self.nfev += 1
        return self._solve(t, x)[1][self.diff].copy()

    def jac(self, t: float, x: np.ndarray) -> np.ndarray:
        self.njev += 1
        y, yp = self._solve(t, x)
        M, Fy = self._matrices(t, y, yp)  # at the solved point
        dw = -np.linalg.solve(M, Fy[:, self.diff])
        return dw[self.diff]

    def full(self, t: float, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """All variables and rates at (t, x) (copies)."""
        y, yp = self._solve(t, x)
        return y.copy(), yp.copy()

    def states(self, t: np.ndarray, xs: np.ndarray, ps=None) -> tuple[np.ndarray, np.ndarray]:
        """All variables and rates along a run (`ps`: the parameters of each time, with its
        piece's modes; :func:`integrate`) — what phc's polish gives its solvers' runs."""
        ys, yps = np.zeros((len(t), self.mod.N)), np.zeros((len(t), self.mod.N))
        for k, (ti, xi) in enumerate(zip(t, xs)):
            self._use(ps, k)
            ys[k], yps[k] = self.full(float(ti), xi)
        return ys, yps

    def outputs(self, t: np.ndarray, ys: np.ndarray, yps: np.ndarray, ps=None) -> dict[str, np.ndarray]:
        """The model's outputs (its `OUTPUTS`, closed-form references included) along a run
        (from :meth:`states`)."""
        rows = []
        for k, (ti, y, yp) in enumerate(zip(t, ys, yps)):
            self._use(ps, k)
            rows.append(np.asarray(self.mod.outputs(float(ti), y, yp, self.p), dtype=float))
        data = np.array(rows, dtype=float).reshape(len(rows), len(self.mod.OUTPUTS))
        return {name: data[:, k] for k, name in enumerate(self.mod.OUTPUTS)}

    def _use(self, ps, k: int) -> None:
        if ps is not None and not np.array_equal(self.p, ps[k]):
            self.p = np.array(ps[k], dtype=float)
            self._minv = None


def integrate(form: OdeForm, method: str, t_out, rtol: float, atol: float, max_steps: int = MAX_STEPS) -> dict:
    """Run scipy's `method` (Radau, BDF, DOP853, ...) on `form` over the output times, as
    ``solve_ivp`` does (the solver object's steps, its dense output at the output times in
    each step), counting steps, then all variables and rates at the output times
    (:meth:`OdeForm.states`, as phc's polish gives them); a fresh solver on each piece
    between the cuts (:meth:`OdeForm.cuts`).

    Returns ``t``, ``x`` (at the output times reached), ``y``, ``yp``, ``p`` (the parameters
    of each, with the modes of its piece), ``steps``, ``nfev``, ``njev``, ``nlu``,
    ``success``, ``message`` and ``cpu_time_s`` (process time of the integration and of the
    states at the output times). A failure — the method's, a residual that cannot be solved
    for the rates, more than `max_steps` steps — is a result with ``success`` False, never
    an exception."""
    from scipy.integrate import BDF, DOP853, LSODA, RK23, RK45, Radau

    from phc.simulation.events import SwitchTimeError

    classes = dict(Radau=Radau, BDF=BDF, DOP853=DOP853, RK45=RK45, RK23=RK23, LSODA=LSODA)
    if method not in classes:
        raise ValueError(f"unknown scipy method {method!r}; choose one of {', '.join(classes)}")
    t_out = np.asarray(t_out, dtype=float)
    form.nfev = form.njev = 0
    kwargs = dict(rtol=rtol, atol=atol)
    if method in ("Radau", "BDF", "LSODA"):
        kwargs["jac"] = form.jac
    start = time.process_time()
    x = form.x0.copy()
    ts, xs, ps = [t_out[0]], [x.copy()], [form.p.copy()]
    steps, success, message, nlu = 0, True, "ok", 0
    try:
        ends = [*form.cuts(float(t_out[0]), float(t_out[-1])), float(t_out[-1])]
        a, k = float(t_out[0]), 1
        for b in ends:
            form.set_modes(a, b)
            solver = classes[method](form.fun, a, x, b, **kwargs)
            while solver.status == "running":
                if steps >= max_steps:
                    raise _Stop(f"stopped after {max_steps} steps at t = {solver.t:.6g} "
                                f"(a stiff mode for an explicit method?)")
                problem = solver.step()
                if solver.status == "failed":
                    raise _Stop(f"{method} failed at t = {solver.t:.6g}: {problem}")
                steps += 1
                dense = None
                reached = b if solver.status == "finished" else solver.t
                while k < len(t_out) and t_out[k] <= reached:
                    if t_out[k] == solver.t or solver.status == "finished" and t_out[k] >= solver.t:
                        xs.append(solver.y.copy())
                    else:
                        dense = dense or solver.dense_output()
                        xs.append(np.asarray(dense(t_out[k]), dtype=float))
                    ts.append(t_out[k])
                    ps.append(form.p.copy())
                    k += 1
            nlu += int(getattr(solver, "nlu", 0) or 0)
            x, a = solver.y.copy(), b
    except _Stop as stop:
        success, message = False, str(stop)
    except (FloatingPointError, np.linalg.LinAlgError, ValueError, ArithmeticError, SwitchTimeError) as err:
        success, message = False, f"{method} stopped: {err}"
    nfev, njev = form.nfev, form.njev
    try:
        ys, yps = form.states(np.array(ts), np.array(xs), ps)
    except (FloatingPointError, np.linalg.LinAlgError, ArithmeticError) as err:
        ys = yps = np.zeros((0, form.mod.N))
        success, message = False, f"the algebraic variables at the output times: {err}"
    cpu = time.process_time() - start
    return dict(t=np.array(ts), x=np.array(xs), y=ys, yp=yps, p=ps, steps=steps, nfev=nfev, njev=njev, nlu=nlu,
                success=success, message=message, cpu_time_s=cpu)


class _Stop(Exception):
    """A scipy run ends early (too many steps, the method failed): caught in :func:`integrate`,
    whose result keeps the message."""


__all__ = ["OdeForm", "NotAnODE", "NOT_AN_ODE", "SCIPY_METHODS", "integrate"]
