"""Certify the system that is compiled: its power balance and the passivity of its losses.

Input: a :class:`~phc.pipeline.CompiledModel` (the generated module and the assembled
:class:`~phc.ir.dae.Dae` it was printed from). Output: a :class:`CompiledCertificate`.

The Dirac certificate of :mod:`phc.checks.certify` looks at each component's Dirac
structure; this one looks at the equations that are integrated. For a port-Hamiltonian
system the energy balance

    dH/dt = −P_ports − P_diss,   P_diss ≥ 0

(T. Berger, R. Hochdahl, T. Reis, R. Seifried, "Port-Hamiltonian modelling of coupled
rigid/flexible multibody systems", Section 2, the energy balance of a pH system; P_ports is
the power delivered through the external ports in the generator convention) must hold on
*every* solution, so it is an identity of the compiled residual at every consistent point
(y, ẏ) with F(t, y, ẏ) = 0 and its hidden constraints. The checks:

* **power balance** at sampled consistent points: the model's initial point and points
  obtained from randomly perturbed states by phc's consistent initialization; dH/dt is the
  derivative ∇H·ẏ of the generated ``hamiltonian`` (fourth-order central
  differences), P_ports and P_diss come from the generated ``powers``. A wrong sign or
  term in any compiled row changes ẏ and breaks the identity.
* **declared controlled sources** (a ``phs`` resistive port with ``kind: source``, such as a
  transistor's collector) are the environment at their port, like an ``effort_source``: their
  power is in P_ports (supplied energy), in the balance but not in the passivity checks, and
  the certificate lists them;
* **passivity of every dissipative term** (each component's P_diss, kept apart in
  ``Dae.dissipation_terms``): ≥ 0 at the consistent samples, and, for terms that depend
  only on states and velocities (a rigid body's damping force vᵀF_d(q, v), a phs's
  ∇Hᵀ R(x) ∇H), at random states over several magnitudes; quadratic dissipation forms
  (Kelvin–Voigt, distributed damping, ``linear_phs`` R) have a non-negative coefficient
  and a positive semidefinite matrix.

A failure is a located diagnostic with the failing sample in the message. The fast
variant runs inside every ``phc compile``/``phc simulate``; ``phc check`` runs more samples.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla
import sympy as sp

from phc.diagnostics import Diagnostic, DiagnosticList
from phc.frontend.source import SourceSpan

BALANCE_RTOL = 1e-6
"""Allowed |dH/dt + P_ports + P_diss| relative to the magnitudes of the terms it sums
(|dH/dt| and every term f·e of P_ports and P_diss)."""
CONSISTENCY_RTOL = 1e-11
"""The samples are consistent to this fraction of their rows' sizes (the tolerance of
consistent initialization, :func:`phc.simulation.initial.consistent_initial_conditions`),
so the balance at a sample holds only to this fraction of the power passing through the
model: at rest, a velocity of round-off size times an O(1) force is a power that no
relative test can judge. Residuals below this fraction of the largest power seen over all
samples are round-off, whatever the sample's own powers."""
PASSIVITY_RTOL = 1e-9
"""A dissipation term below −PASSIVITY_RTOL · (its scale) is non-passive."""
DENSE_EIG_LIMIT = 1500
"""Quadratic dissipation forms up to this size get a dense eigenvalue check."""


@dataclass
class CompiledCertificate:
    model: str
    samples: int = 0
    balance_error: float = 0.0
    """Largest relative |dH/dt + P_ports + P_diss| over the samples."""
    terms_checked: int = 0
    forms_checked: int = 0
    diagnostics: DiagnosticList = field(default_factory=DiagnosticList)
    seconds: float = 0.0
    skipped: str = ""
    balance_note: str = ""
    """Why the power balance was not sampled (the model is above the size limit of the
    fast certificate); passivity was still checked."""
    supplied: list = field(default_factory=list)
    """The declared controlled sources (``component.port`` of a ``phs`` resistive port with
    ``kind: source``): their power is in the balance as supplied power, not checked for passivity."""

    @property
    def certified(self) -> bool:
        return not self.diagnostics.has_errors

    def summary(self) -> str:
        if self.skipped:
            return f"not certified: {self.skipped}"
        balance = (self.balance_note if self.balance_note else
                   f"power balance at {self.samples} consistent state(s), max relative error {self.balance_error:.1e}")
        what = (f"{balance}; {self.terms_checked} dissipative term(s)"
                + (f" and {self.forms_checked} quadratic form(s)" if self.forms_checked else "")
                + " checked for passivity"
                + (f"; supplied power through the declared source(s) {', '.join(self.supplied)}" if self.supplied
                   else "")
                + f"; {self.seconds:.2f} s")
        head = "NOT certified (" if not self.certified else (
            "passivity certified, balance not sampled (" if self.balance_note else "certified (")
        return head + what + ")"

    def to_dict(self) -> dict:
        return {"certified": self.certified and not self.skipped, "samples": self.samples,
                "balance_error": self.balance_error, "dissipative_terms": self.terms_checked,
                "quadratic_forms": self.forms_checked, "supplied_by": list(self.supplied), "seconds": self.seconds,
                "skipped": self.skipped,
                "diagnostics": self.diagnostics.to_json()}


# ---------------------------------------------------------------------------------------


SHRINK = 4.0
SHRINK_TRIES = 2
"""A random sample's perturbation that cannot be made consistent is retried SHRINK times
shorter, up to SHRINK_TRIES times."""


def _consistent_samples(compiled, p, n_random: int, rng) -> tuple[list, list[str]]:
    """[(t, y, ẏ)]: the initial consistent point and up to `n_random` perturbed ones."""
    from phc.errors import InconsistentInitialError, SimulationSetupError
    from phc.simulation import ModelEvaluationError, initial_values, start_state
    from phc.simulation.initial import consistent_initial_conditions

    mod = compiled.module
    t0 = float(compiled.options.get("t_start", 0.0))
    t1 = float(compiled.options.get("t_end", t0 + 1.0))
    notes = []
    out = []
    try:
        values, fixed = initial_values(compiled, p)
        # the start of every run: solved as `simulate` solves it and kept for it (one solve)
        init = start_state(compiled, p, t0, values, fixed)
    except (InconsistentInitialError, SimulationSetupError, ModelEvaluationError, np.linalg.LinAlgError,
            ValueError, ArithmeticError) as err:
        # ArithmeticError: the equations cannot be evaluated there (1/sqrt(0) of a moving beam
        # whose ends start at one point); simulate reports that located, through its guards
        notes.append(f"no consistent initial point ({str(err)[:120]})")
        return out, notes
    out.append((t0, init.y0, init.yp0))
    dif = np.flatnonzero(np.asarray(mod.DIFFERENTIAL))
    energy = list(mod.VARIABLES).index("energy.supplied")
    states = np.array([j for j in dif if j != energy], dtype=int)
    y0 = init.y0
    # States are perturbed by 30 % of their size plus a tenth of the largest one (1 when the
    # model starts at rest at zero: a sample where nothing moves would certify nothing).
    largest = float(np.abs(y0[states]).max(initial=0.0)) if len(states) else 0.0
    base = 0.1 * largest if largest > 0 else 1.0
    # A perturbation Gauss–Newton cannot bring back to the constraint manifold is shrunk (the
    # same direction, SHRINK times shorter, up to SHRINK_TRIES times) rather than rescued by a
    # dense least-squares solve: with many closed kinematic loops (the N four-bar, N = 40) the
    # full perturbation of every angle by a tenth of the largest coordinate lands far from any
    # consistent configuration, and the rescue cost minutes per sample.
    for _ in range(n_random):
        step = np.array([rng.normal() * 0.3 * (abs(y0[j]) + base) for j in states])
        t = float(t0 + rng.uniform(0, 1) * (t1 - t0))
        for k in range(SHRINK_TRIES + 1):
            guess = dict(values)
            for j, d in zip(states, step / SHRINK ** k):
                guess[int(j)] = float(y0[j] + d)
            try:
                s = consistent_initial_conditions(mod, p, t, guess, {energy}, initial_relations=False,
                                                  rescue=False)
            except (InconsistentInitialError, np.linalg.LinAlgError, ValueError, ArithmeticError):
                continue  # a perturbed point the solver cannot make consistent: not a finding
            out.append((t, s.y0, s.yp0))
            break
    return out, notes


def _dHdt(mod, p, t, y, yp) -> tuple[float, float]:
    """Derivative of H along ẏ (∇H·ẏ) and an estimate of its rounding/truncation error."""
    ny = max(float(np.linalg.norm(y)), 1e-300)
    nyp = float(np.linalg.norm(yp))
    h = 1e-4 * ny / nyp if nyp > 0 else 1e-4
    h = min(h, 1e-3 * max(1.0, abs(t)) if nyp == 0 else h)

    if mod.hamiltonian(t + 1e-3, y, p) != mod.hamiltonian(t, y, p):
        h = min(h, 1e-4 * max(1.0, abs(t)))  # H depends on t: the step also moves t

    def H(s):  # the total dH/dt: an explicit ∂H/∂t is in P_ports (assembly books −∂H/∂t there)
        return mod.hamiltonian(t + s, y + s * yp, p)

    d1 = (H(h) - H(-h)) / (2 * h)
    d2 = (H(h / 2) - H(-h / 2)) / h
    d = (4 * d2 - d1) / 3  # Richardson: O(h⁴)
    scale = mod.energy_scale(t, y, p)
    noise = 1e-13 * max(scale, abs(H(0.0))) / h
    return d, abs(d - d2) + noise


def _energy_direction(compiled, p, t, y, yp) -> np.ndarray:
    """(ẏ_x, ż): the rates of the energy states and of the algebraic variables H depends on.

    The generated H may involve algebraic variables (a rigid body's H = ½pᵀv + V with
    M(q)v = p). Their rates are not in ẏ (an index-2 DAE has no use for them), so they are
    taken from the time derivative of the algebraic rows, F_y ż = −F_x ẋ − F_t, solved in
    the least-squares sense (min-norm for the ones H does not see)."""
    from phc.simulation.minnorm import lsmr_min_norm, min_norm_solve

    mod, dae = compiled.module, compiled.dae
    used = set(dae.hamiltonian.free_symbols)
    for form in dae.quadratic_energy:
        used |= set(form.symbols)
    symbols = [v.symbol for v in dae.variables]
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    alg_used = [j for j, s in enumerate(symbols) if s in used and not diff[j]]
    d = np.where(diff, yp, 0.0)
    if not alg_used:
        return d
    n, m = mod.N, len(mod.EQUATIONS)
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    buf = np.zeros(len(rows))
    mod.jacobian(t, y, yp, p, 0.0, buf)
    Jy = sps.csr_matrix((buf.copy(), (rows, cols)), shape=(m, n))
    mod.jacobian(t, y, yp, p, 1.0, buf)
    Jyp = sps.csr_matrix((buf, (rows, cols)), shape=(m, n)) - Jy
    Jyp.eliminate_zeros()
    algebraic_rows = np.flatnonzero(np.diff(Jyp.indptr) == 0)
    alg = np.flatnonzero(~diff)
    Ft = np.zeros(m)
    mod.residual_t(t, y, yp, p, Ft)
    A = Jy[algebraic_rows][:, alg]
    rhs = -(Jy[algebraic_rows][:, np.flatnonzero(diff)] @ yp[diff]) - Ft[algebraic_rows]
    # The rows are in the model's units, not equilibrated: a row that is merely small (a mass
    # in kg beside a stiffness in N/m) must not fall under the rank threshold, so only
    # round-off counts as rank deficiency — numpy's lstsq threshold, eps·max(m, n), which
    # this check used before. The exact least-norm solution up to 4e6 entries (dense when
    # rank-deficient), LSMR beyond.
    cond = np.finfo(float).eps * max(A.shape)
    z = min_norm_solve(A, rhs, cond=cond, dense_limit=4_000_000, iterative=False)
    if z is None:
        z = lsmr_min_norm(A, rhs)[0]
    d[alg] = z
    return d


def _rate_magnitudes(mod, p, t, y, yp) -> np.ndarray:
    """Per variable, the size of the terms its rate is the sum of: for each row, the sum of
    its terms' magnitudes to first order, ``|F_y|·|y| + |F_ẏ|·|ẏ|``, divided by the
    coefficient of the rate in that row (the largest over the rows the rate is in; 0 for a
    variable without a rate).

    A rate is computed to round-off of these terms, not of its own value: two rigidly joined
    masses beside a spring move together, ṗ₁ = e − kx = 0 with e = kx ≠ 0, and the consistent
    ṗ₁ is a few ε·kx, which dH/dt multiplies by the velocity."""
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    shape = (len(mod.EQUATIONS), mod.N)
    y_part = np.zeros(len(rows))
    mod.jacobian(t, y, yp, p, 0.0, y_part)
    both = np.zeros(len(rows))
    mod.jacobian(t, y, yp, p, 1.0, both)
    rate_part = both - y_part  # F_ẏ, at the pattern's entries
    row_size = (sps.csr_matrix((np.abs(y_part), (rows, cols)), shape=shape) @ np.abs(y)
                + sps.csr_matrix((np.abs(rate_part), (rows, cols)), shape=shape) @ np.abs(yp))
    out = np.zeros(mod.N)
    has_rate = rate_part != 0.0
    np.maximum.at(out, cols[has_rate], row_size[rows[has_rate]] / np.abs(rate_part[has_rate]))
    return out


def _power_scale(mod, p, t, y, yp, states) -> float:
    """A power scale at (t, y, ẏ) that does not vanish when dH/dt happens to: the energy
    scale Σ|terms of H| times the rate ‖ṙ‖/‖y‖ of the energy states, ṙ the size of the terms
    each rate sums (:func:`_rate_magnitudes`, at least |ẏ|): a power that every term of the
    balance cancels (uniform motion against internal forces) is judged by these terms."""
    ny = float(np.linalg.norm(y[states]))
    if ny == 0.0:
        return 0.0
    rates = np.maximum(np.abs(yp[states]), _rate_magnitudes(mod, p, t, y, yp)[states])
    return float(mod.energy_scale(t, y, p)) * float(np.linalg.norm(rates)) / ny


def _parameter_values(dae, mod, p) -> dict:
    """Parameter symbol -> its value in the parameter vector `p` of the module (one index of
    the module's names: `PARAMETERS.index` per parameter was quadratic in their number)."""
    slot = {name: i for i, name in enumerate(mod.PARAMETERS)}
    return {par.symbol: float(p[slot[par.name]]) for par in dae.parameters}


def _term_magnitudes(compiled, p, samples) -> np.ndarray:
    """Σ|terms| of P_ports and P_diss at each sample: the magnitudes the balance sums, so that
    its round-off is judged against them and not against their (possibly cancelling) sum.
    A term that cannot be evaluated numerically counts 0 (the totals bound it from below)."""
    dae, mod = compiled.dae, compiled.module
    n = len(samples)
    params = _parameter_values(dae, mod, p)
    columns = dict(params)
    columns.update({v.symbol: np.array([y[j] for _, y, _ in samples]) for j, v in enumerate(dae.variables)})
    columns[sp.Symbol("t", real=True)] = np.array([t for t, _, _ in samples])
    total = np.zeros(n)
    for expr in (dae.port_power, dae.dissipation):
        # (a sympy expression the assembly built, or the integer 0 where there is no such term)
        for term in sp.Add.make_args(expr) if isinstance(expr, sp.Basic) else ():
            if term == 0:
                continue
            values = np.abs(_term_values(term, columns, n))
            total += np.where(np.isfinite(values), values, 0.0)
    return total


def _balance(compiled, p, samples, cert, span) -> None:
    mod = compiled.module
    dif = np.flatnonzero(np.asarray(mod.DIFFERENTIAL))
    states = np.array([j for j in dif if mod.ROLES[j] != "energy"], dtype=int)
    terms = _term_magnitudes(compiled, p, samples)
    rows = []
    for (t, y, yp), magnitude in zip(samples, terms):
        dH, err = _dHdt(mod, p, t, y, _energy_direction(compiled, p, t, y, yp))
        ports, diss = mod.powers(t, y, yp, p)
        # The magnitudes of the terms set the scale; the energy-rate scale only keeps it from
        # vanishing where every term happens to be ~0 (a pendulum at its turning point).
        scale = max(abs(dH) + max(float(magnitude), abs(ports) + abs(diss)),
                    1e-6 * _power_scale(mod, p, t, y, yp, states))
        rows.append((t, dH, err, ports, diss, scale))
    # Absolute round-off: the samples are consistent only to CONSISTENCY_RTOL of the power
    # that passes through the model (a sample at rest: round-off velocities times forces),
    # and a power that would move the energy by less than CONSISTENCY_RTOL of its scale over
    # the whole simulated span is round-off too (a body coasting with no force on it: every
    # power is 0 and dH/dt is 1e-81).
    t0 = float(compiled.options.get("t_start", 0.0))
    horizon = abs(float(compiled.options.get("t_end", t0 + 1.0)) - t0) or 1.0
    energy = max((abs(float(mod.energy_scale(t, y, p))) for t, y, _ in samples), default=0.0)
    floor = CONSISTENCY_RTOL * max(max((r[-1] for r in rows), default=0.0), energy / horizon)
    worst = 0.0
    for t, dH, err, ports, diss, scale in rows:
        residual = dH + ports + diss
        # allowed: BALANCE_RTOL of the terms, the absolute round-off, and the finite-difference
        # noise of dH/dt (which powers below it cannot be judged more finely than)
        allowed = BALANCE_RTOL * scale + floor + 10 * err
        if allowed == 0.0:
            continue  # at rest: nothing to balance
        rel = BALANCE_RTOL * abs(residual) / allowed  # ≤ BALANCE_RTOL when within what is allowed
        worst = max(worst, rel)
        if rel > BALANCE_RTOL:
            cert.diagnostics.append(Diagnostic(
                "PHC-E450",
                f"the compiled equations do not conserve energy: dH/dt = {dH:.6g} but "
                f"−P_ports − P_diss = {-(ports + diss):.6g} at t = {t:.6g} (relative error {rel:.1e}); "
                f"either a component's relations are not power conserving (`phc check` certifies each "
                f"component's Dirac structure) or a compiled row is wrong — then please report it with "
                f"this model (`--no-certify` compiles anyway)",
                span=span))
            break
    cert.balance_error = worst


def _value(expr: sp.Expr, point: dict) -> float:
    return float(expr.xreplace(point))


_NUMPY = {sp.sin: np.sin, sp.cos: np.cos, sp.tan: np.tan, sp.exp: np.exp, sp.log: np.log, sp.Abs: np.abs,
          sp.sign: np.sign, sp.sinh: np.sinh, sp.cosh: np.cosh, sp.tanh: np.tanh, sp.asin: np.arcsin,
          sp.acos: np.arccos, sp.atan: np.arctan, sp.atan2: np.arctan2}


class _NotNumeric(Exception):
    """A node `_numeric` does not evaluate (sympy evaluates it instead)."""


def _numeric(expr: sp.Expr, columns: dict):
    """`expr` evaluated in numpy on arrays of points (a tree walk: nothing is printed or
    executed); raises _NotNumeric for a node it does not know."""
    if expr.is_Symbol:
        if expr not in columns:
            raise _NotNumeric(expr)
        return columns[expr]
    if expr.is_Number:
        value = complex(expr)
        if value.imag or not math.isfinite(value.real):
            raise _NotNumeric(expr)
        return value.real
    if not (expr.is_Add or expr.is_Mul or expr.is_Pow or expr.func in (sp.Max, sp.Min) or expr.func in _NUMPY):
        raise _NotNumeric(expr.func)
    args = [_numeric(a, columns) for a in expr.args]
    if expr.is_Add:
        return sum(args[1:], args[0])
    if expr.is_Mul:
        out = args[0]
        for a in args[1:]:
            out = out * a
        return out
    if expr.is_Pow:
        return np.power(np.asarray(args[0], dtype=float), args[1])
    if expr.func in (sp.Max, sp.Min):
        reduce = np.maximum if expr.func is sp.Max else np.minimum
        out = args[0]
        for a in args[1:]:
            out = reduce(out, a)
        return out
    return _NUMPY[expr.func](*args)


def _term_values(term: sp.Expr, columns: dict, n: int) -> np.ndarray:
    """`term` at n points, `columns` mapping each of its symbols to n values (or one);
    NaN where it cannot be evaluated (outside its domain, complex, a symbol not given).

    One numpy evaluation of all points; a term with a function `_numeric` does not know is
    substituted point by point in sympy."""
    symbols = sorted(term.free_symbols, key=lambda s: s.name)
    if any(s not in columns for s in symbols):
        return np.full(n, np.nan)
    args = {s: np.broadcast_to(np.asarray(columns[s], dtype=float), (n,)) for s in symbols}
    try:
        with np.errstate(all="ignore"):
            return np.array(np.broadcast_to(_numeric(term, args), (n,)), dtype=float)
    except _NotNumeric:
        out = np.full(n, np.nan)
        for k in range(n):
            try:
                out[k] = _value(term, {s: sp.Float(float(a[k])) for s, a in args.items()})
            except (TypeError, ValueError, ZeroDivisionError):
                continue
        return out


def _first_negative(values: np.ndarray) -> Optional[int]:
    """Index of the first value that is non-passive (below −PASSIVITY_RTOL · its scale)."""
    with np.errstate(invalid="ignore"):
        bad = np.isfinite(values) & (values < -PASSIVITY_RTOL * np.maximum(1.0, np.abs(values)))
    hits = np.flatnonzero(bad)
    return int(hits[0]) if len(hits) else None


def _passivity_at_samples(compiled, p, samples, cert) -> None:
    dae, mod = compiled.dae, compiled.module
    params = _parameter_values(dae, mod, p)
    symbols = [v.symbol for v in dae.variables]
    column_of = {s: j for j, s in enumerate(symbols)}
    ys = np.array([y for _, y, _ in samples])  # samples × unknowns
    times = np.array([t for t, _, _ in samples])
    for component, term, span in dae.dissipation_terms:
        if term == 0:
            continue
        used = term.free_symbols
        # the term's own symbols only (all unknowns and parameters per term was quadratic)
        columns = {s: params[s] for s in used if s in params}
        columns.update({s: ys[:, column_of[s]] for s in used if s in column_of})
        columns[sp.Symbol("t", real=True)] = times
        values = _term_values(term, columns, len(samples))
        k = _first_negative(values)
        if k is not None:
            point = {s: sp.Float(float(np.broadcast_to(v, (len(samples),))[k])) for s, v in columns.items()}
            resistive = any(v.role == "resistive" for v in dae.variables if v.symbol in used)
            _non_passive(cert, component, span, float(values[k]), point, used, set(symbols), resistive)


def _passivity_random(compiled, p, samples, cert, rng, n: int) -> None:
    """Terms in states and velocities only: vᵀF_d(q, v) ≥ 0 for all (q, v), not only near
    the trajectory."""
    dae, mod = compiled.dae, compiled.module
    params = _parameter_values(dae, mod, p)
    by_symbol = {v.symbol: (j, v) for j, v in enumerate(dae.variables)}
    y0 = samples[0][1] if samples else np.zeros(len(dae.variables))
    for component, term, span in dae.dissipation_terms:
        used = [s for s in term.free_symbols if s in by_symbol]
        if term == 0 or not used or any(by_symbol[s][1].role not in ("state", "velocity") for s in used):
            continue
        if any(s not in by_symbol and s not in params and s.name != "t" for s in term.free_symbols):
            continue
        own = {s: params[s] for s in term.free_symbols if s in params}  # not all parameters per term
        for magnitude in (1e-2, 1.0, 1e2):
            # drawn sample by sample, symbol by symbol (the order of one draw per value)
            draws = rng.normal(size=(n, len(used)))
            columns = dict(own)
            columns[sp.Symbol("t", real=True)] = 0.0
            for i, s in enumerate(used):
                j = by_symbol[s][0]
                columns[s] = y0[j] + magnitude * draws[:, i] * max(1.0, abs(y0[j]))
            values = _term_values(term, columns, n)
            k = _first_negative(values)
            if k is not None:
                point = {s: sp.Float(float(np.broadcast_to(v, (n,))[k])) for s, v in columns.items()}
                _non_passive(cert, component, span, float(values[k]), point, set(used), by_symbol)
                break


def _non_passive(cert, component, span, value, point, used, variables, resistive: bool = False) -> None:
    """PHC-E451 for `component`; with `resistive` (the term is a ``phs`` resistive law's f·e)
    the hint says how to declare a law that supplies power by design."""
    shown = ", ".join(f"{s.name} = {float(point[s]):.4g}"
                      for s in sorted(used, key=lambda s: s.name) if s in point and s in variables)
    cert.diagnostics.append(Diagnostic(
        "PHC-E451",
        f"the dissipation of `{component}` is not passive: its dissipated power is {value:.4g} < 0 at "
        f"{shown or 'a sampled state'}; a dissipative term must never supply energy (for a damping force "
        f"vᵀF_d(q, v) ≥ 0, for R(x) positive semidefinite)",
        span=span, hint=("a resistive law that supplies power by design (a controlled source, such as a "
                         "transistor's collector) is declared `kind: source`: its power is then supplied power"
                         if resistive else None)))


def _quadratic_forms(compiled, p, cert) -> None:
    dae, mod = compiled.dae, compiled.module
    params = {s: sp.Float(v) for s, v in _parameter_values(dae, mod, p).items()}
    for form in dae.quadratic_dissipation:
        cert.forms_checked += 1
        component = getattr(form, "component", "") or "a distributed component"
        span = getattr(form, "span", None)
        try:
            coeff = float(form.coeff.xreplace(params))
        except (TypeError, ValueError):
            continue
        A = sps.csr_matrix(form.matrix)
        sym = (A + A.T) / 2
        norm = abs(sym).sum(axis=1).max() if sym.nnz else 0.0
        if norm == 0:
            continue
        n = sym.shape[0]
        if n <= DENSE_EIG_LIMIT:
            lam = float(np.linalg.eigvalsh(sym.toarray()).min())
        else:
            try:
                lam = float(spla.eigsh(sym, k=1, which="SA", return_eigenvectors=False, tol=1e-8,
                                       maxiter=20 * n)[0])
            except (spla.ArpackNoConvergence, ValueError):
                continue
        bad_coeff = coeff < 0
        if bad_coeff or lam < -1e-10 * norm:
            what = (f"its coefficient is {coeff:.4g} < 0" if bad_coeff
                    else f"its matrix has the eigenvalue {lam:.4g} < 0")
            cert.diagnostics.append(Diagnostic(
                "PHC-E451", f"the dissipation of `{component}` is not passive: {what}; a dissipation "
                "matrix must be positive semidefinite with a non-negative coefficient", span=span))


def certify_compiled(compiled, params: Optional[dict] = None, n_random: int = 2, seed: int = 0,
                     passivity_samples: int = 8, max_unknowns: Optional[int] = None) -> CompiledCertificate:
    """Check the power balance and passivity of the compiled model (see the module doc).

    With `max_unknowns`, a model with more unknowns gets the passivity checks only: its
    consistent samples would cost as much as several starts of a simulation (the fast
    certificate of every compilation uses this; ``phc check`` does not)."""
    from phc.simulation import parameter_vector
    from phc.simulation.guard import quiet_floating_point

    t_start = time.perf_counter()
    rng = np.random.default_rng(seed)
    cert = CompiledCertificate(compiled.name)
    p = parameter_vector(compiled.module, params)
    span = SourceSpan(compiled.dae.sources[0], 1, 1) if compiled.dae.sources else None
    # the generated functions evaluated as in a run: NumPy's floating-point warnings off (a
    # 1/c that an `ifelse(c > 0, ...)` discards is no finding; the checks judge the values)
    with quiet_floating_point():
        if max_unknowns is not None and compiled.module.N > max_unknowns:
            cert.balance_note = (f"power balance not sampled ({compiled.module.N} unknowns, above {max_unknowns}: "
                                 "`phc check` samples it)")
            samples, notes = [], []
        else:
            samples, notes = _consistent_samples(compiled, p, n_random, rng)
        cert.samples = len(samples)
        cert.terms_checked = sum(1 for _, term, _ in compiled.dae.dissipation_terms if term != 0)
        cert.supplied = [f"{component}.{port}" for component, port, _, _ in compiled.dae.supply_terms]
        if samples:
            _balance(compiled, p, samples, cert, span)
            _passivity_at_samples(compiled, p, samples, cert)
        _passivity_random(compiled, p, samples, cert, rng, passivity_samples)
        _quadratic_forms(compiled, p, cert)
    if not samples and not cert.balance_note:
        cert.skipped = "; ".join(notes) or "no consistent state found"
    cert.seconds = time.perf_counter() - t_start
    return cert


__all__ = ["CompiledCertificate", "certify_compiled"]
