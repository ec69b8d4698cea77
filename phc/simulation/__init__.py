"""Simulation (pipeline stage 9): consistent initialization, integration, energy figures.

``simulate(compiled, ...)`` returns a :class:`SimResult`. A numerical failure is data
(``success=False`` with a message saying when, why and what to try), never an
exception; invalid options raise :class:`~phc.errors.SimulationSetupError` at once.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Callable, Optional

import numpy as np
import sympy as sp

from phc.errors import InconsistentInitialError, SimulationSetupError
from phc.inputs import breakpoints_within
from phc.simulation.discrete_gradient import integrate_discrete_gradient
from phc.simulation.ida import integrate_ida
from phc.simulation.initial import consistent_initial_conditions
from phc.simulation.midpoint import integrate_midpoint
from phc.simulation.midpoint4 import integrate_midpoint4
from phc.simulation.monitor import describe_equations
from phc.simulation.result import SimResult

BACKENDS = {"ida": integrate_ida, "midpoint": integrate_midpoint, "discrete_gradient": integrate_discrete_gradient,
            "midpoint4": integrate_midpoint4}
"""Integrators by name: `ida` (variable-order BDF), and the fixed-step structure-preserving
`midpoint` (energy-exact for quadratic H), `discrete_gradient` (energy-exact for any H) and
`midpoint4` (order 4: a composition of three midpoint substeps, energy-exact for quadratic H)."""
FIXED_STEP = ("midpoint", "discrete_gradient", "midpoint4")


def parameter_vector(mod, overrides: Optional[dict] = None) -> np.ndarray:
    """Full parameter vector from defaults and base-parameter overrides by name."""
    base_idx = list(mod.BASE_PARAMETERS)
    base = np.array(mod.PARAMETER_DEFAULTS, dtype=float)[base_idx]
    names = [mod.PARAMETERS[i] for i in base_idx]
    fixed = set(getattr(mod, "COMPILE_TIME_PARAMETERS", ()))
    for key, value in (overrides or {}).items():
        if key in fixed and float(value) != float(base[names.index(key)]):
            raise SimulationSetupError(f"parameter `{key}` was used at compile time (a mesh length or a "
                                       "coefficient varying along a distributed component); change it in the "
                                       "model and recompile")
        if key not in names:
            if key in mod.PARAMETERS:
                raise SimulationSetupError(f"parameter `{key}` is derived from other parameters; override those")
            raise SimulationSetupError(f"unknown parameter `{key}`; known: {', '.join(names)}")
        base[names.index(key)] = float(value)
    return mod.full_parameters(base)


def simulate(compiled, t_end: Optional[float] = None, *, params: Optional[dict] = None,
             rtol: Optional[float] = None, atol: Optional[float] = None, n_out: Optional[int] = None,
             t_eval=None, initial: Optional[dict] = None, solver: Optional[str] = None,
             max_steps: Optional[int] = None, progress: Optional[Callable[[float], None]] = None,
             step: Optional[float] = None) -> SimResult:
    """Simulate a compiled model.

    Parameters
    ----------
    compiled : CompiledModel
        From :func:`phc.compile_model`.
    t_end, rtol, atol, n_out, solver, max_steps : optional
        Override the model's `simulation` defaults.
    t_eval : array_like, optional
        Output times (overrides `n_out`).
    step : float, optional
        Step size of the fixed-step `midpoint`, `discrete_gradient` and `midpoint4` solvers (default:
        the model's `simulation.step`, else the output interval).
    params : dict, optional
        Base-parameter overrides by name (one compilation serves a parameter study).
    initial : dict, optional
        Initial values by state name; a value may be ``(value, True)`` to mark a guess.

    Returns
    -------
    SimResult
        Check ``success``; a failed run keeps its partial results.

    Raises
    ------
    SimulationSetupError
        For invalid options, unknown parameters or states.
    InconsistentInitialError
        When fixed initial values violate the equations.
    """
    mod = compiled.module
    opts = dict(compiled.dae.options)
    t0 = float(opts["t_start"])
    t1 = float(t_end if t_end is not None else opts["t_end"])
    rtol = float(rtol if rtol is not None else opts["rtol"])
    atol = float(atol if atol is not None else opts["atol"])
    max_steps = int(max_steps if max_steps is not None else opts["max_steps"])
    solver = solver or opts["solver"]
    if solver not in BACKENDS:
        raise SimulationSetupError(f"unknown solver `{solver}`; choose one of {', '.join(BACKENDS)}")
    if not t1 > t0:
        raise SimulationSetupError(f"`t_end` ({t1}) must be greater than the start time ({t0})")
    if not (0 < rtol < 1) or atol <= 0:
        raise SimulationSetupError("`rtol` must be in (0, 1) and `atol` positive")
    if t_eval is not None:
        t_out = np.asarray(t_eval, dtype=float)
        if t_out[0] != t0:
            t_out = np.concatenate([[t0], t_out])
    else:
        t_out = np.linspace(t0, t1, int(n_out or opts["n_out"]))
    p = parameter_vector(mod, params)
    index = {name: j for j, name in enumerate(mod.VARIABLES)}
    values, fixed = {}, set()
    by_name = {par.symbol: sp.Float(float(p[mod.PARAMETERS.index(par.name)])) for par in compiled.dae.parameters}
    for iv in compiled.dae.initial:
        # initial values written as parameter expressions follow parameter overrides
        values[index[iv.name]] = float(iv.expr.xreplace(by_name)) if iv.expr is not None else iv.value
        if not iv.guess:
            fixed.add(index[iv.name])
    for name, spec in (initial or {}).items():
        if name not in index or not mod.DIFFERENTIAL[index[name]]:
            raise SimulationSetupError(f"`{name}` is not a state of the model")
        value, guess = spec if isinstance(spec, tuple) else (spec, False)
        values[index[name]] = float(value)
        (fixed.discard if guess else fixed.add)(index[name])
    energy_idx = index["energy.supplied"]
    values[energy_idx] = 0.0
    fixed.add(energy_idx)
    cpu0 = time.process_time()
    init = consistent_initial_conditions(mod, p, t0, values, fixed)
    if hasattr(progress, "restart"):
        progress.restart()
    extra = {"step": step if step is not None else opts.get("step")} if solver in FIXED_STEP else {}
    run = partial(BACKENDS[solver], mod, p, rtol=rtol, atol=atol, max_steps=max_steps, progress=progress,
                  max_order=opts.get("max_order", 5), names=describe_equations(compiled), **extra)
    out = _integrate_with_breakpoints(run, mod, p, t_out, init)
    cpu = time.process_time() - cpu0
    result = _finish(compiled, mod, p, out, init, cpu, solver, rtol, atol)
    if solver in FIXED_STEP:  # the step actually taken: no longer than `step` nor an output interval
        intervals = np.diff(t_out)
        h = extra["step"]
        result.step = float(max(d / max(1, int(np.ceil(d / h - 1e-9))) if h else d for d in intervals))
    return result


def _integrate_with_breakpoints(run, mod, p, t_out, init) -> dict:
    """Integrate over `t_out`, stopping at each input breakpoint (module BREAKPOINTS: ends of
    pieces, table rows) and restarting there from a consistent state: the differential
    variables are continuous, the algebraic ones and ẏ may jump. A step input is thus
    located exactly rather than found by step rejections."""
    t0, t1 = float(t_out[0]), float(t_out[-1])
    breaks = breakpoints_within(getattr(mod, "BREAKPOINTS", ()), t0, t1)
    if not breaks:
        return run(t_out, init.y0, init.yp0)
    ends = [*breaks, t1]
    y0, yp0, start = init.y0, init.yp0, t0
    pieces, total = [], dict(steps=0, nfev=0, njev=0)
    out = None
    for end in ends:
        inner = t_out[(t_out > start) & (t_out < end)]
        grid = np.concatenate([[start], inner, [end]])
        out = run(grid, y0, yp0)
        for key in total:
            total[key] += out[key]
        keep = np.isin(out["t"], t_out)
        pieces.append({k: out[k][keep] for k in ("t", "y", "yp")})
        if not out["success"] or end == t1:
            break
        y_end = out["y"][-1]
        dif = set(np.flatnonzero(np.asarray(mod.DIFFERENTIAL)).tolist())
        try:
            restart = consistent_initial_conditions(mod, p, end, dict(enumerate(y_end)), dif,
                                                    initial_relations=False)
        except InconsistentInitialError as err:
            out = dict(out, success=False, message=f"cannot restart after the input breakpoint at t = {end:.6g}: "
                       + "; ".join(err.problems))
            break
        y0, yp0, start = restart.y0, restart.yp0, end
    merged = {k: np.concatenate([pc[k] for pc in pieces]) for k in ("t", "y", "yp")}
    _, first = np.unique(merged["t"], return_index=True)  # a breakpoint on the grid appears twice
    merged = {k: v[np.sort(first)] for k, v in merged.items()}
    return dict(out, **merged, **total)


def _finish(compiled, mod, p, out, init, cpu, solver, rtol, atol) -> SimResult:
    t, y, yp = out["t"], out["y"], out["yp"]
    H = np.array([mod.hamiltonian(ti, yi, p) for ti, yi in zip(t, y)], dtype=float)
    powers = np.array([mod.powers(ti, yi, ypi, p) for ti, yi, ypi in zip(t, y, yp)], dtype=float).reshape(-1, 2)
    energy = y[:, mod.VARIABLES.index("energy.supplied")]
    balance = H - H[0] + energy
    scale = max((float(mod.energy_scale(ti, yi, p)) for ti, yi in zip(t, y)), default=0.0)
    inv = np.array([mod.invariants(ti, yi, p) for ti, yi in zip(t, y)], dtype=float).reshape(len(t), -1)
    vinv = np.array([mod.velocity_invariants(ti, yi, p) for ti, yi in zip(t, y)], dtype=float).reshape(len(t), -1)
    outs = np.array([mod.outputs(ti, yi, ypi, p) for ti, yi, ypi in zip(t, y, yp)], dtype=float)
    outs = outs.reshape(len(t), len(mod.OUTPUTS))
    dae = compiled.dae
    return SimResult(
        success=out["success"], message=out["message"], t=t, y=y, yp=yp, variables=tuple(mod.VARIABLES),
        differential=np.asarray(mod.DIFFERENTIAL), H=H, port_power=powers[:, 0], dissipation=powers[:, 1],
        energy_supplied=energy, outputs={name: outs[:, i] for i, name in enumerate(mod.OUTPUTS)},
        invariants=inv, invariant_labels=tuple(mod.INVARIANTS), velocity_invariants=vinv,
        energy_balance_error=float(np.abs(balance).max(initial=0.0)),
        energy_balance_relative=float(np.abs(balance).max(initial=0.0) / scale) if scale > 0 else 0.0,
        constraint_drift=float(np.abs(inv).max(initial=0.0)), velocity_drift=float(np.abs(vinv).max(initial=0.0)),
        steps=out["steps"], n_residual_evals=out["nfev"], n_jacobian_evals=out["njev"], cpu_time_s=cpu,
        n_states=dae.n_states - 1, n_equations=len(dae.equations), solver=solver, rtol=rtol, atol=atol,
        initial_choices=init.chosen,
    )


__all__ = ["simulate", "SimResult", "BACKENDS", "InconsistentInitialError", "parameter_vector"]
