"""Nominal scales of the variables: what makes tolerances mean the same in every unit system.

A tolerance is only meaningful relative to the size of what it measures. A small mechanism
in SI units has momenta of ~1e-5 kg·m/s; an absolute tolerance of 1e-6 is then 10 % of
them, while the same model in grams and centimetres has momenta of ~1 and the same
tolerance is 1e-6 of them. phc therefore gives every variable ``y_j`` a *nominal scale*
``s_j > 0`` (in the variable's own unit) and measures every tolerance in the scaled
variables ``y_j / s_j``:

* IDA's absolute tolerance of a differential variable is ``atol · s_j`` (``atol`` is
  relative to the nominal scale; ``rtol`` stays relative to the current value);
* the Newton tests of the fixed-step solvers are ``max_j |Δy_j| / s_j ≤ tol`` on the
  states (:func:`weights_from_scales`);
* consistent initialization checks its start in the scaled variables
  (:func:`phc.simulation.initial.consistent_initial_conditions`).

Scaling the units of a model scales every ``s_j`` the same way (all rules below are
homogeneous of degree one in the variable's unit), so the scaled problem, and with it the
steps, the Newton iterations and the relative errors, do not depend on the units.

How ``s`` is found, in this order (docs/tolerances.md):

1. the size at the start, ``|y_j(t₀)|``, and the rate at the start over the probe's time
   scale τ, ``|ẏ_j(t₀)| τ``;
2. a short probe: :data:`PROBE_STEPS` implicit-midpoint steps over τ (20 % of the run; on
   the C back end in its step loop, :func:`phc.codegen.c_steps.midpoint_steps`);
   the largest ``|y_j|`` seen, and for
   the energy accumulator the largest energy scale (sum of |terms| of H), also with every
   state at its scale;
3. values below :data:`NOISE` times the largest of their block (states, algebraic
   variables) are round-off (1e-47 where a mechanism at rest has 0) and count as zero;
4. algebraic variables that are zero (a multiplier at rest), and before consistent
   initialization (``residual=True``) the states too, get a size from the rows they appear
   in: the iteration matrix ``J = F_y + F_ẏ/τ`` at the start, whose row ``i`` has the
   size ``r_i = max_k |J_ik| s_k`` over the variables with a scale; ``y_j`` then has the
   size ``min_i r_i / |J_ij|`` that makes its term as large as the row's others;
5. a floor from the energy: at least :data:`ENERGY_FLOOR` times ``sqrt(2E/∂²H/∂y_j²)``,
   the size the state would have if it held the energy scale E alone — a beam that starts
   straight has curvatures of round-off size, not zero;
6. a floor from the variables of the same kind (the same name up to the index, e.g. the
   dofs ``rod.p[k]`` of one beam): at least :data:`KIND_FLOOR` times the largest of them;
7. a value the user set (``simulation.nominal: {state: value}``, or a scene's
   ``nominal``) replaces all of this for its variable;
8. a variable nothing gives a size to (a state at rest that the probe does not see move)
   keeps 1, its own unit: ``atol`` then means for it what it always meant;
9. a floor from round-off (when the absolute tolerance is known): ``atol · s_j`` must stay
   :data:`ROUNDOFF_ULPS` times above the round-off with which the equations determine
   ``y_j`` (:func:`roundoff_sizes`). The end of a free beam that drifts by 5e-10 m while
   the other end sits at 0.3 m is fixed by a constraint whose terms are 0.3 m: it is known
   to ~1e-16 m, and an absolute tolerance of 1e-10 · 5e-10 m is one no step can meet.
   A row that depends on time explicitly also carries the round-off of ``t`` itself,
   ``ε |t| |∂F_i/∂t|`` at the latest time of the run: a source ``V0 sin(ω t)`` of 10 V at
   314 rad/s, 0.045 s into a run, is known to ~2e-14 V whatever the states, and a diode's
   current that follows it through 1 Ω cannot be held to 5e-14 A (IDA then failed its
   error test on every step near the diode's switching, 15 000 steps for one half-period).

The module is over 800 lines because the nine rules above, the promise scales of the
outputs and the run's energy scale are one definition of "how large is this quantity":
split, each rule would need the others' private helpers (row sizes, kinds, round-off).
"""

from __future__ import annotations

import hashlib
import itertools
import re
import weakref
from typing import Mapping, Optional

import numpy as np

from phc.simulation.energy_sizes import energy_sizes

PROBE_STEPS = 20
"""Implicit-midpoint steps of the probe."""
PROBE_FRACTION = 0.2
"""The probe covers this fraction of the run (a beam loaded from rest must show a good part of
its deflection: its scales set IDA's absolute tolerances)."""
KIND_FLOOR = 1e-3
"""A variable's scale is at least this times the largest scale of its kind."""
NOISE = 1e-16
"""Values below this times the largest |y| of the states (or of the algebraic variables) are
zeros computed inexactly (1e-47 where 0 was meant, at rest): they say nothing about a
variable's size."""
NOISE_COEFFICIENT = 1e-20
"""Jacobian entries below this times the largest of their row are zeros computed inexactly."""
ROUNDOFF_ULPS = 10.0
"""``atol · s_j`` stays at least this many times the round-off of ``y_j`` (step 9)."""
DENSE_ROUNDOFF = 400
"""Up to this many unknowns the round-off floor uses the dense inverse (step 9)."""
ENERGY_FLOOR = 1e-3
"""A state's scale is at least this times its size if it held the energy scale alone
(:func:`energy_sizes`): a curvature of a beam that starts straight (1e-19) gets the size
its bending would reach, not its round-off."""


class Scales(np.ndarray):
    """Nominal scales, with ``floored``: the variables whose scale the round-off floor set
    (step 9). They cannot be integrated more accurately than that, whatever the user sets,
    so the conditioning warning leaves them out. ``user``: the indices the user set (never
    raised, :func:`mode_floor` included). ``sizes``: the scales before the round-off floor
    (steps 1–8), the sizes the variables take: a floor says how finely a variable can be
    resolved, not how large it is (:func:`phc.simulation.tested.determined_scales` judges by
    them whether a variable is a small difference of larger terms)."""

    floored = None
    user: tuple = ()
    sizes = None

    def __array_finalize__(self, obj):
        self.floored = None  # a computed array is not the scales any more
        self.user = ()
        self.sizes = None


def _floored(mod, p, rows, cols, vals, s, y0, yp0, seen, *, t0, span, t_out, atol, user, sizes=None) -> Scales:
    """`s` raised to the round-off floor of step 9 (the iteration matrix's entries `rows`,
    `cols`, `vals` at (t0, y0, ẏ0); `seen`: the largest values the variables took;
    `sizes`: the scales before any floor, `s` itself when None)."""
    n, m = mod.N, len(mod.EQUATIONS)
    names = list(mod.VARIABLES)
    energy_index = names.index("energy.supplied") if "energy.supplied" in names else None
    # round-off comes from the values the variables take (the start and the probe), not
    # from scales, which may be generous (an energy floor, a fill from the rows)
    # without the energy accumulator and its row: it feeds nothing back, and its values (as
    # large as the energy gets: exp(q) near overflow) would only add the inverse's round-off
    # to everything else
    keep_r, keep_c = np.ones(m, dtype=bool), np.ones(n, dtype=bool)
    if energy_index is not None:
        keep_c[energy_index] = False
        keep_r[np.unique(rows[cols == energy_index])] = False
    attainable = np.zeros(n)
    rho_time = time_roundoff(mod, p, t0, y0, yp0, span, t_out, m)
    if keep_r.sum() == keep_c.sum():
        rpos, cpos = np.cumsum(keep_r) - 1, np.cumsum(keep_c) - 1
        sel = keep_r[rows] & keep_c[cols]
        nk = int(keep_c.sum())
        # at the probe's step, and with the states held (the short steps of a restart or of
        # a switching: c_j F_ẏ dominates, and a row's round-off goes to its algebraic variables)
        from phc.simulation.guard import CATCH, ModelEvaluationError

        held = vals
        try:
            _, _, buf = _jacobian_entries(mod, p, t0, y0, yp0, HELD_CJ / probe_time(span, t_out))
            if np.all(np.isfinite(buf)):
                held = buf
        except (ModelEvaluationError, *CATCH):  # the probe's step alone then
            pass
        for entries in (vals, held):
            size = ROUNDOFF_ULPS * roundoff_sizes(rpos[rows[sel]], cpos[cols[sel]], entries[sel],
                                                  y0[keep_c], seen[keep_c], nk, nk,
                                                  rho_time=rho_time[keep_r]) / atol
            attainable[keep_c] = np.maximum(attainable[keep_c], size)
    user = sorted(int(j) for j in user)
    attainable[user] = 0.0
    attainable = np.where(np.isfinite(attainable), attainable, 0.0)
    out = np.maximum(s, attainable).view(Scales)
    out.floored = attainable > s
    out.user = tuple(user)
    out.sizes = np.array(s if sizes is None else sizes, dtype=float)
    return out


FIXED_STEP_FRACTION = 0.1
"""The fraction of `atol` step 9 measures against for the fixed-step solvers (their Newton
test does not use `atol`): where IDA's local tolerance was when this floor was set."""


def tested_fraction(solver: str, rtol: float) -> float:
    """The fraction of `atol` (times the nominal scales) the solver's error test applies, which
    step 9 keeps above round-off: IDA's :func:`~phc.simulation.ida.local_fraction` of it; the
    fixed-step solvers' :data:`FIXED_STEP_FRACTION`."""
    if solver == "ida":
        from phc.simulation.ida import local_fraction

        return local_fraction(rtol)
    return FIXED_STEP_FRACTION


def mode_floor(mod, p, scales, y, yp, *, t0: float, span: float, t_out=None, atol: Optional[float]) -> np.ndarray:
    """The run's `scales` raised, where needed, to the round-off floor (step 9) of the
    equations in the mode they are in at (t0, y, ẏ) (`p` holds the modes of the switching
    conditions, :mod:`phc.simulation.events`). A mode changes the iteration matrix: a diode
    that conducts ties its current to a source voltage it ignored while blocking. Never
    lowers a scale; variables floored before stay marked; the user's scales stay as set."""
    from phc.simulation.guard import CATCH, ModelEvaluationError

    if not atol or scales is None:
        return scales
    base = np.asarray(scales, dtype=float)
    y, yp = np.asarray(y, dtype=float), np.asarray(yp, dtype=float)
    try:
        rows, cols, vals = _jacobian_entries(mod, p, t0, y, yp, 1.0 / probe_time(span, t_out))
    except (ModelEvaluationError, *CATCH):
        return scales
    if not len(rows):
        return scales
    seen = np.where(np.isfinite(y), np.abs(y), 0.0)
    out = _floored(mod, p, rows, cols, vals, base, y, yp, seen, t0=t0, span=span, t_out=t_out, atol=atol,
                   user=getattr(scales, "user", ()), sizes=getattr(scales, "sizes", None))
    before = getattr(scales, "floored", None)
    if before is not None:
        out.floored = out.floored | np.asarray(before, dtype=bool)
    return out


def _drop_noise(s, diff) -> np.ndarray:
    """`s` with the values below :data:`NOISE` times the largest of their block (states,
    algebraic variables) set to 0."""
    s = s.copy()
    for block in (diff, ~diff):
        top = s[block].max(initial=0.0)
        s[block & (s < NOISE * top)] = 0.0
    return s


_INDEX = re.compile(r"\[\d+\]")


def kind_of(name: str) -> str:
    """The kind of a variable: its name without indices (`rod.p[3]` → `rod.p`). Called for
    every variable of a start (40 000 of a 10⁴-element string): the pattern is compiled once."""
    return _INDEX.sub("", name) if "[" in name else name


def kind_groups(names) -> list[np.ndarray]:
    """The indices of the variables of each kind (:func:`kind_of`) that has more than one:
    one pattern substitution over all the names at once (a 10⁵-element string has 400 004)."""
    names = list(names)
    joined = "\0".join(names)
    kinds = (_INDEX.sub("", joined).split("\0") if names and joined.count("\0") == len(names) - 1
             else [kind_of(name) for name in names])  # a name holding the separator: one by one
    # runs of one kind (a mesh's vector is one run), grouped by kind: Python work per run, not
    # per name (itertools.groupby walks the names in C)
    groups: dict[str, list[tuple[int, int]]] = {}
    start = 0
    for kind, run in itertools.groupby(kinds):
        count = len(list(run))
        groups.setdefault(kind, []).append((start, count))
        start += count
    out = []
    for runs in groups.values():
        if sum(count for _, count in runs) > 1:
            out.append(np.concatenate([np.arange(first, first + count) for first, count in runs]))
    return out


def _jacobian_entries(mod, p, t, y, yp, cj):
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    buf = np.zeros(len(rows))
    mod.jacobian(t, y, yp, p, cj, buf)
    return rows, cols, buf


def row_sizes(rows, cols, vals, s, m: int) -> np.ndarray:
    """``r_i = max_k |J_ik| s_k``: the size of each row's largest term (0 for an empty row)."""
    r = np.zeros(m)
    np.maximum.at(r, rows, np.abs(vals) * s[cols])
    return r


def _fill_from_rows(rows, cols, vals, s, n, m, passes: int = 3, r0=None) -> np.ndarray:
    """The size each variable's rows give it (step 3): ``min_i r_i / |J_ij|`` with ``r_i``
    the row's largest term over the variables with a size; 0 where no row says anything.
    The smallest over the rows: a larger size would make the variable's term dominate a
    row whose other terms balance.
    Variables without a size get theirs in passes (one found may size the next)."""
    a = np.abs(vals)
    ok = np.isfinite(a) & (a > 0)
    rows, cols, a = rows[ok], cols[ok], a[ok]
    # coefficients at round-off level of their row (B'(θ)·ω with ω = 1e-49 at rest) are zeros
    biggest = np.zeros(m)
    np.maximum.at(biggest, rows, a)
    ok = a >= NOISE_COEFFICIENT * biggest[rows]
    rows, cols, a = rows[ok], cols[ok], a[ok]
    known = s > 0
    natural = np.zeros(n)
    for _ in range(passes + 1):
        cur = np.where(known, s, natural)
        r = np.zeros(m) if r0 is None else r0.copy()
        have = cur[cols] > 0
        np.maximum.at(r, rows[have], a[have] * cur[cols[have]])
        cand = np.full(n, np.inf)
        use = r[rows] > 0
        np.minimum.at(cand, cols[use], r[rows[use]] / a[use])
        cand[~np.isfinite(cand)] = 0.0
        if np.array_equal(cand, natural):
            break
        natural = cand
    return natural


def roundoff_sizes(rows, cols, vals, y, s, n: int, m: int, samples: int = 4,
                   rho_time: Optional[np.ndarray] = None) -> np.ndarray:
    """How precisely the equations determine each variable: ``δ = |J⁻¹| ρ`` for the
    round-off ``ρ_i = ε Σ_k |J_ik| max(|y_k|, s_k)`` of each row (the size of its terms
    times the unit round-off; `s` here: the largest values seen, not the nominal scales),
    plus `rho_time` (the round-off the time argument brings into each row, already
    absolute). ``J`` is the iteration matrix at the start (its differential
    rows carry ``c_j F_ẏ``, so a state's own round-off ``ε |y_j|`` is counted). Up to
    :data:`DENSE_ROUNDOFF` unknowns with the dense inverse (the componentwise bound); above,
    the largest ``|J⁻¹ (ρ ∘ g)|`` over a few normal random vectors ``g`` (random signs alone
    can cancel exactly: round-offs are multiples of ε). Zeros where the matrix cannot be
    factorized (a singular start is diagnosed elsewhere)."""
    import warnings

    ok = np.isfinite(vals)
    if not ok.all():  # copies only where needed: they would be alive beside the LU below
        rows, cols, vals = rows[ok], cols[ok], vals[ok]
    del ok
    size = np.maximum(np.abs(np.where(np.isfinite(y), y, 0.0)), s)
    rho = np.zeros(m)
    np.add.at(rho, rows, np.abs(vals) * size[cols])
    rho *= np.finfo(float).eps
    if rho_time is not None:
        rho += np.where(np.isfinite(rho_time), np.abs(rho_time), 0.0)
    if m != n or not len(rows) or not rho.any():
        return np.zeros(n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            if n <= DENSE_ROUNDOFF:
                J = np.zeros((n, n))
                np.add.at(J, (rows, cols), vals)
                out = np.abs(np.linalg.inv(J)) @ rho
            else:
                import scipy.sparse as sps
                from phc.simulation.sparse_lu import sparse_lu

                lu = sparse_lu(sps.csc_matrix((vals, (rows, cols)), shape=(m, n)))
                rng = np.random.default_rng(0)
                out = np.zeros(n)
                for _ in range(samples):
                    np.maximum(out, np.abs(lu.solve(rho * rng.standard_normal(m))), out=out)
        except (RuntimeError, ValueError, np.linalg.LinAlgError):
            return np.zeros(n)
    return out if np.all(np.isfinite(out)) else np.zeros(n)


HELD_CJ = 1e6
"""Step 9 also takes the iteration matrix at this many times the probe's ``c_j``: the
states held, as in the short steps of a restart."""
TIME_SAMPLES = 9
"""Times in the run at which :func:`time_roundoff` evaluates ``∂F/∂t``."""


def time_roundoff(mod, p, t0, y0, yp0, span, t_out, m: int) -> np.ndarray:
    """``ε · T · max_k |∂F_i/∂t (t_k)|`` for each row: the round-off the time argument
    brings into it, with ``T`` the latest time of the run (IDA's ``t`` is known to an ulp
    of it) and ``t_k`` :data:`TIME_SAMPLES` times spread over the run, at the start's
    (y, ẏ) (a size, not a solution). Zeros for a model without explicit time."""
    from phc.simulation.guard import CATCH, ModelEvaluationError

    out = np.zeros(m)
    times = [float(t0)]
    if span and np.isfinite(span) and span > 0:
        times = list(float(t0) + float(span) * np.linspace(0.0, 1.0, TIME_SAMPLES))
    if t_out is not None and len(t_out):
        times.append(float(np.max(np.abs(t_out))))
    last = max(abs(t) for t in times)
    if not last > 0:
        return out
    buf = np.zeros(m)
    for t in times:
        try:
            buf[:] = 0.0
            mod.residual_t(t, y0, yp0, p, buf)
        except (ModelEvaluationError, *CATCH):
            continue
        np.maximum(out, np.where(np.isfinite(buf), np.abs(buf), 0.0), out=out)
    return np.finfo(float).eps * last * out


def probe_time(span: Optional[float], t_out=None) -> float:
    """The probe's time scale τ: :data:`PROBE_FRACTION` of the run."""
    del t_out  # not the output grid: the scales (and so IDA's steps) must not depend on n_out
    tau = PROBE_FRACTION * float(span) if span else 1.0
    return tau if tau > 0 and np.isfinite(tau) else 1.0


def _throughput(mod, p, t, y, yp) -> float:
    """``|P_ports| + |P_diss|`` at (t, y, ẏ): the power passing through, whether or not it
    is stored (0 where it cannot be evaluated)."""
    from phc.simulation.guard import CATCH, ModelEvaluationError

    try:
        value = float(np.abs(np.asarray(mod.powers(t, y, yp, p), dtype=float)).sum())
    except (ModelEvaluationError, *CATCH):
        return 0.0
    return value if np.isfinite(value) else 0.0


def _probe(mod, p, t0, y0, yp0, tau, weights) -> tuple[np.ndarray, float, float]:
    """Largest |y|, energy scale and power throughput (:func:`_throughput`) over a few
    implicit-midpoint steps (best effort: the probe stops at the first step Newton cannot do)."""
    from phc.simulation.guard import CATCH, ModelEvaluationError
    from phc.simulation.midpoint import StageSolver

    big = np.abs(y0).copy()
    energy = 0.0
    power = _throughput(mod, p, t0, y0, yp0)
    try:
        energy = abs(float(mod.energy_scale(t0, y0, p)))
    except (ModelEvaluationError, *CATCH):
        pass
    try:
        # the Newton test of the probe is relative to |y| + 1, not to the scales it is there to
        # find: a start at rest where everything is round-off (a source sin(ωt) at t = 0) has
        # scales of 1e-20 that no Newton iteration meets
        del weights
        raw = getattr(mod, "module", mod)  # unguarded: a failure ends the probe anyway
        h = tau / PROBE_STEPS
        y = np.array(y0, dtype=float)
        slope = np.asarray(yp0, dtype=float)
        t = t0
        # the C step loop's steps (the same stage and Newton iteration, each from a better guess; their values
        # one call, where not finite the guarded call's), then the Python stage solver's from one it handed back
        in_c, stage, seen = [], None, None
        if getattr(raw, "BACKEND", "") == "c":
            from phc.codegen import c_steps

            k, ys = c_steps.midpoint_steps(raw, p, t0 + h * np.arange(PROBE_STEPS + 1), y0, yp0)
            in_c = ys[1:k]
            seen = c_steps.probe_values(raw, p, t0, h, y, in_c)
        for i in range(PROBE_STEPS):
            if i < len(in_c):
                y1, ok = in_c[i], True
            else:
                stage = StageSolver(raw, p) if stage is None else stage
                y1, ok = stage.solve(t, h, y, y + h * slope, 0.5)
            if not ok or not np.all(np.isfinite(y1)):
                break
            slope = (y1 - y) / h
            pw, es = (float(seen[0][i]), float(seen[1][i])) if seen is not None and i < len(in_c) else (np.nan,) * 2
            power = max(power, pw if np.isfinite(pw) else _throughput(mod, p, t + 0.5 * h, 0.5 * (y + y1), slope))
            y, t = y1, t + h
            np.maximum(big, np.abs(y), out=big)
            energy = max(energy, abs(es if np.isfinite(es) else float(mod.energy_scale(t, y, p))))
    except (ModelEvaluationError, *CATCH):
        pass
    return big, energy if np.isfinite(energy) else 0.0, power


def nominal_scales(mod, p, y0, yp0, nominal: Optional[Mapping[int, float]] = None, *, t0: float = 0.0,
                   span: Optional[float] = None, t_out=None, probe: bool = True,
                   residual: bool = False, atol: Optional[float] = None) -> np.ndarray:
    """The nominal scale ``s_j > 0`` of every variable (module docstring: how it is found).

    Parameters
    ----------
    mod : module
        A generated residual module (guarded or not).
    p : ndarray
        Full parameter vector.
    y0, yp0 : ndarray
        A consistent start.
    nominal : mapping, optional
        User-set scales by variable index (they win).
    t0, span, t_out : optional
        Start time, length of the run and output times (they set the probe's time scale).
    probe : bool
        Run the short probe (step 2); without it only the start and the rows are used.
    residual : bool
        Count the residual ``|F_i|`` at (y0, yp0) among the terms of row i (step 3): before
        consistent initialization a driven row (a flow source imposing ω) says how large the
        variables it drives will be.
    atol : float, optional
        The absolute tolerance the scales will multiply: with it, no ``atol · s_j`` is
        below :data:`ROUNDOFF_ULPS` times the round-off of ``y_j`` (step 9).
    """
    n = mod.N
    y0 = np.asarray(y0, dtype=float)
    yp0 = np.asarray(yp0, dtype=float)
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    names = list(mod.VARIABLES)
    m = len(mod.EQUATIONS)
    tau = probe_time(span, t_out)
    s = np.where(np.isfinite(y0), np.abs(y0), 0.0)
    s = _drop_noise(s, diff)
    rate = np.where(diff & np.isfinite(yp0), np.abs(yp0) * tau, 0.0)
    s = np.maximum(s, rate)
    s = _drop_noise(s, diff)
    from phc.simulation.guard import CATCH, ModelEvaluationError

    try:
        rows, cols, vals = _jacobian_entries(mod, p, t0, y0, yp0, 1.0 / tau)
    except (ModelEvaluationError, *CATCH):
        rows = cols = np.zeros(0, dtype=int)
        vals = np.zeros(0)
    r0 = None
    if residual:
        try:
            r0 = np.zeros(m)
            mod.residual(t0, y0, yp0, p, r0)
            r0 = np.where(np.isfinite(r0), np.abs(r0), 0.0)
            r0[r0 < NOISE * r0.max(initial=0.0)] = 0.0
        except (ModelEvaluationError, *CATCH):
            r0 = None
    user = {int(j): abs(float(v)) for j, v in (nominal or {}).items() if np.isfinite(v) and float(v) != 0}

    def nominal_energy(s) -> float:
        """The energy scale with every state at its nominal size (the energy supplied is
        measured against what the states can hold, not against H at a start at rest)."""
        y = np.where(diff, np.where(y0 < 0, -1.0, 1.0) * np.maximum(np.abs(y0), s), y0)
        try:
            e = abs(float(mod.energy_scale(t0, y, p)))
        except (ModelEvaluationError, *CATCH):
            return 0.0
        return e if np.isfinite(e) else 0.0

    kinds = kind_groups(names)

    def complete(s, energy=None):
        s = s.copy()
        s = _drop_noise(s, diff)  # round-off of a start (or a probe) at rest
        if energy:
            s = np.maximum(s, ENERGY_FLOOR * energy_sizes(mod, p, t0, y0, s, energy))
        natural = _fill_from_rows(rows, cols, vals, s, n, m, r0=r0)
        # the rows size what has no size of its own: algebraic variables (a multiplier at rest)
        # and, before consistent initialization (`residual`), states the equations drive; a
        # state at rest that nothing moves keeps its own unit (below), as `atol` always meant
        fill = ~diff | residual
        if energy_index is not None:
            fill[energy_index] = True
        natural = np.where(fill, natural, 0.0)
        s = np.where(s > 0, s, natural)
        s = _drop_noise(s, diff)
        for idx in kinds:
            s[idx] = np.maximum(s[idx], KIND_FLOOR * s[idx].max())
        for j, v in user.items():
            s[j] = v
        s = np.where((s > 0) & np.isfinite(s), s, 1.0)
        if energy_index is not None and energy_index not in user:
            s[energy_index] = max(s[energy_index], nominal_energy(s))
        return s

    energy_index = names.index("energy.supplied") if "energy.supplied" in names else None
    if energy_index is not None:  # the energy supplied is measured against the energy stored
        try:
            e0 = abs(float(mod.energy_scale(t0, y0, p)))
        except (ModelEvaluationError, *CATCH):
            e0 = 0.0
        if np.isfinite(e0):
            s[energy_index] = max(s[energy_index], e0)
    s_start = complete(s, s[energy_index] if energy_index is not None else None)
    def floor(s):
        """Step 9: no absolute tolerance below the round-off of its variable."""
        if not atol or not len(rows):
            return s
        return _floored(mod, p, rows, cols, vals, s, y0, yp0, seen, t0=t0, span=span, t_out=t_out, atol=atol,
                        user=user)

    seen = np.where(np.isfinite(y0), np.abs(y0), 0.0)
    if not probe:
        return floor(s_start)
    big, energy, power = _probe(mod, p, t0, y0, yp0, tau, 1.0 / s_start)
    seen = np.maximum(seen, np.where(np.isfinite(big), big, 0.0))
    s = np.maximum(s, np.where(np.isfinite(big), big, 0.0))
    if energy_index is not None:
        s[energy_index] = max(s[energy_index], energy)
        if atol:
            # the energy supplied is a sum of port and dissipated energies that may cancel (a
            # source feeding resistors: nothing stored, 0 supplied in total): it carries the
            # round-off of the energy that passes through, and its absolute tolerance stays
            # above that (step 10)
            eps = np.finfo(float).eps
            s[energy_index] = max(s[energy_index], ROUNDOFF_ULPS * eps * tau * power / atol)
    return floor(complete(s, s[energy_index] if energy_index is not None else None))


CACHED_RUNS = 8
"""Most sets of inputs a generated module's per-run set-up is kept for (:func:`remember`)."""

_CACHE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _digest(parts) -> bytes:
    """A digest of numbers and arrays (their dtype, shape and bytes; None as an empty array)."""
    h = hashlib.blake2b(digest_size=20)
    for part in parts:
        a = np.ascontiguousarray(np.zeros(0) if part is None else part)
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.digest()


def remember(mod, what: str, parts, compute):
    """``compute()``, kept per generated module (`mod`, guarded or not) and `what` for the last
    :data:`CACHED_RUNS` values of `parts` (numbers and arrays: every input `compute` reads besides
    the module): a run that repeats another's inputs (a benchmark, a sweep that changes only what
    this part of the set-up does not read) gets what was computed then — the same numbers,
    without computing them again; any other input computes them anew. The caller copies what it
    may change."""
    raw = getattr(mod, "module", mod)  # the generated module under a guard (phc.simulation.guard)
    try:
        kept = _CACHE.setdefault(raw, {})
    except TypeError:  # a module that cannot be referenced weakly: nothing is kept
        return compute()
    key = (what, _digest(parts))
    if key in kept:
        return kept[key]
    value = compute()
    if len(kept) >= CACHED_RUNS:
        kept.pop(next(iter(kept)))
    kept[key] = value
    return value


def copy_scales(scales):
    """A copy of nominal scales with their attributes (a copy of :class:`Scales` is plain scales)."""
    out = np.array(scales, dtype=float).view(type(scales)) if isinstance(scales, Scales) else np.array(scales)
    if isinstance(scales, Scales):
        out.floored = None if scales.floored is None else np.array(scales.floored)
        out.user = tuple(scales.user)
        out.sizes = None if scales.sizes is None else np.array(scales.sizes)
    return out


def cached_nominal_scales(mod, p, y0, yp0, nominal: Optional[Mapping[int, float]] = None, *, t0: float = 0.0,
                          span: Optional[float] = None, t_out=None, atol: Optional[float] = None) -> np.ndarray:
    """:func:`nominal_scales` (with the probe), computed once for a set of inputs (:func:`remember`:
    the start, the parameters, the user's scales, the time span, the output times and the
    absolute tolerance); each call returns its own copy."""
    parts = (np.asarray(p, dtype=float), np.asarray(y0, dtype=float), np.asarray(yp0, dtype=float),
             np.array(sorted((int(j), float(v)) for j, v in (nominal or {}).items()), dtype=float),
             np.array([t0, np.nan if span is None else span, np.nan if atol is None else atol], dtype=float),
             None if t_out is None else np.asarray(t_out, dtype=float))
    found = remember(mod, "nominal_scales", parts, lambda: nominal_scales(mod, p, y0, yp0, nominal, t0=t0, span=span,
                                                                          t_out=t_out, atol=atol))
    return copy_scales(found)


def weights_from_scales(scales, differential=None) -> np.ndarray:
    """Newton-test weights of nominal scales: ``1/s_j`` on differential variables, 0 on
    algebraic ones (multipliers and efforts follow from the differential variables; like
    IDA, which leaves them out of its error and Newton tests: the GGL multiplier of an exact
    solution is 0 and its corrections are round-off amplified like 1/h)."""
    w = 1.0 / np.asarray(scales, dtype=float)
    if differential is not None:
        w = np.where(np.asarray(differential, dtype=bool), w, 0.0)
    return w


def newton_weights(mod, p, y0, yp0, nominal: Optional[Mapping[int, float]] = None, *, t0: float = 0.0,
                   span: Optional[float] = None, t_out=None) -> np.ndarray:
    """Weights of a Newton test on scaled variables (:func:`weights_from_scales` of
    :func:`nominal_scales`): an iteration has converged when ``max_j |Δy_j| w_j`` is below
    its tolerance."""
    s = nominal_scales(mod, p, y0, yp0, nominal, t0=t0, span=span, t_out=t_out)
    return weights_from_scales(s, mod.DIFFERENTIAL)


def nominal_indices(mod, nominal: Optional[Mapping[str, float]]) -> dict[int, float]:
    """User-set nominal scales by variable name → by index; a name that is not a state
    raises :class:`~phc.errors.SimulationSetupError`."""
    from phc.errors import SimulationSetupError

    if not nominal:
        return {}
    index = {name: j for j, name in enumerate(mod.VARIABLES)}
    out = {}
    for name, value in nominal.items():
        if name not in index or not mod.DIFFERENTIAL[index[name]]:
            raise SimulationSetupError(f"nominal scale: `{name}` is not a state of the model")
        value = float(value)
        if not np.isfinite(value) or value <= 0:
            raise SimulationSetupError(f"nominal scale of `{name}` must be a finite positive number, got {value}")
        out[index[name]] = value
    return out


__all__ = ["nominal_scales", "newton_weights", "weights_from_scales", "nominal_indices", "row_sizes", "kind_of", "probe_time"]


PROMISE_MARGIN = 10.0
"""A state's promise scale replaces its nominal scale only where it is at least this many
times larger (:func:`promise_scales`): the rule is for states far below what the outputs and
the energy notice (an unobserved stiff mode), not a reweighting of the states they are made
of. A series LC circuit whose charge the output does not see but the energy does, at 1.6
times its nominal scale, took 1 465 IDA steps instead of 657 at rtol 1e-8 with its
absolute tolerance loosened 40 times (docs/tutorials/custom-components.md)."""
SENSITIVITY_STATES = 2000
"""Up to this many states :func:`promise_scales` looks at the outputs (two evaluations of
them per state); above, at the energy alone."""


def output_sensitivities(mod, p, t0, y0, yp0, s) -> np.ndarray:
    """``∂o_k/∂y_j`` of the requested outputs with respect to the states at the start, by
    central differences of ``mod.outputs`` with the step ``1e-6 · s_j`` (two evaluations
    per state: a C module's in one call, c_steps.along; an empty matrix without outputs or above
    :data:`SENSITIVITY_STATES` states; zeros where an output cannot be evaluated). None where an
    output reads an algebraic variable or a rate (a support force, a velocity ṡ): it sees the
    states through the equations, and its derivatives by the states alone would say it sees none."""
    from phc.codegen import c_steps
    from phc.simulation.guard import CATCH, ModelEvaluationError

    names, n = tuple(getattr(mod, "OUTPUTS", ())), mod.N
    states = np.flatnonzero(np.asarray(mod.DIFFERENTIAL, dtype=bool))
    if not names or len(states) > SENSITIVITY_STATES:
        return np.zeros((0, n))
    out = np.zeros((len(names), n))
    y0, yp0 = np.asarray(y0, dtype=float), np.asarray(yp0, dtype=float)
    try:
        o0 = np.asarray(mod.outputs(t0, y0, yp0, p), dtype=float)
        # an output that reads an algebraic variable (a support force) or a rate sees the
        # states through the equations, which these derivatives do not follow: say nothing
        algebraic = ~np.asarray(mod.DIFFERENTIAL, dtype=bool)
        rng = np.random.default_rng(0)
        y1 = y0 + np.where(algebraic, 1e-3 * (np.abs(y0) + s) * (1 + rng.random(n)), 0.0)
        yp1 = yp0 + 1e-3 * (np.abs(yp0) + s) * (1 + rng.random(n))
        for moved in (np.asarray(mod.outputs(t0, y1, yp0, p), dtype=float),
                      np.asarray(mod.outputs(t0, y0, yp1, p), dtype=float)):
            if not np.array_equal(moved, o0):
                return None
        k, h = len(states), 1e-6 * s[states]
        Y = np.repeat(y0[None, :], 2 * k, axis=0)  # each state up, then each down, by its step h
        Y[np.arange(k), states], Y[np.arange(k, 2 * k), states] = y0[states] + h, y0[states] - h
        rows = c_steps.along(getattr(mod, "module", mod), p, np.full(2 * k, float(t0)), Y, np.tile(yp0, (2 * k, 1)))
        values = np.full((2 * k, len(names)), np.nan) if rows is None else rows["outs"]
        for i in np.flatnonzero(~np.isfinite(values).all(axis=1)):  # (single calls, through the guard)
            values[i] = np.asarray(mod.outputs(t0, Y[i], yp0, p), dtype=float)
        out[:, states] = ((values[:k] - values[k:]) / (2.0 * h)[:, None]).T
    except (ModelEvaluationError, *CATCH):
        return np.zeros((len(names), n))
    return np.where(np.isfinite(out), out, 0.0)


def promise_scales(mod, p, t0, y0, yp0, scales) -> np.ndarray:
    """The scales IDA's error test measures the states against: each state's nominal
    scale raised, where the requested outputs and the energy allow it, to the size at
    which its error first matters to one of them (docs/tolerances.md, "What the tolerance
    is about"):

    * the energy: ``sqrt(2E/∂²H/∂y_j²)`` (:func:`energy_sizes`), the size at which the
      state holds the run's energy scale E alone (the energy norm: an error of ``r`` times
      it changes the energy by at most about ``2r·E``);
    * each requested output o_k: ``S_k / |∂o_k/∂y_j|``, the size at which the state's
      first-order effect on o_k is o_k's size ``S_k = max(|o_k(t₀)|, Σ_j |∂o_k/∂y_j| s_j)``
      (the output with every state at its nominal size).

    The energy size is first scaled by ``ρ = min(1, min_j P^out_j / e_j)`` over the states an
    output sees and the energy is curved in: the dynamics carry an error from state to state
    at its energy norm (``y_j / e_j``), so no state is loosened beyond the energy norm the most
    demanding output asks of the states it sees (the controlled beam's tip velocity was 1.3e-4
    off at rtol 1e-6 without it). The smaller of ``ρ·e_j`` and the output size, where it is
    at least :data:`PROMISE_MARGIN` times the nominal scale; a state neither sees (H flat in
    it and no output depends on it directly: a position that only the constraints and the
    dynamics carry to the outputs) keeps its nominal scale, as do the energy accumulator
    and the scales the user set. Where an output reads an algebraic variable or a rate
    (:func:`output_sensitivities` cannot tell which states it sees) every state keeps its
    nominal scale. Both sizes are homogeneous of degree one in the state's unit (ρ is a
    ratio of sizes of one unit), so the tolerances still mean the same in every unit system."""
    base = np.asarray(scales, dtype=float)
    n = mod.N
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    names = list(mod.VARIABLES)
    energy_index = names.index("energy.supplied") if "energy.supplied" in names else None
    if energy_index is not None:
        energy = float(base[energy_index])
    else:
        from phc.simulation.guard import CATCH, ModelEvaluationError

        y = np.where(diff, np.where(y0 < 0, -1.0, 1.0) * np.maximum(np.abs(y0), base), y0)
        try:
            energy = abs(float(mod.energy_scale(t0, y, p)))
        except (ModelEvaluationError, *CATCH):
            energy = 0.0
    e = np.zeros(n)
    if energy > 0 and np.isfinite(energy):
        e = energy_sizes(mod, p, t0, np.asarray(y0, dtype=float), base, energy)
    d = output_sensitivities(mod, p, t0, y0, yp0, base)
    if d is None:  # the outputs see the states through the equations: no state is loosened
        return scales
    seen_size = np.full(n, np.inf)
    if len(d):
        try:
            o0 = np.abs(np.asarray(mod.outputs(t0, y0, yp0, p), dtype=float))
        except Exception:  # noqa: BLE001 - the derivatives were zeros then too
            o0 = np.zeros(len(d))
        a = np.abs(d) * base[None, :]
        terms = np.where(diff[None, :], a, 0.0)
        top = terms.max(axis=1, initial=0.0)
        S = np.maximum(np.where(np.isfinite(o0), o0, 0.0), terms.sum(axis=1))
        seen = (terms > NOISE_COEFFICIENT * top[:, None]) & (np.abs(d) > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            cand = np.where(seen, S[:, None] / np.abs(d), np.inf)
        seen_size = cand.min(axis=0)
    # the dynamics carry an error from state to state at its energy norm (y_j / e_j): no
    # state is loosened beyond the energy norm the most demanding output asks of the
    # states it sees
    both = (e > 0) & np.isfinite(seen_size)
    ratio = min(1.0, float((seen_size[both] / e[both]).min())) if both.any() else 1.0
    size = np.minimum(np.where(e > 0, ratio * e, np.inf), seen_size)
    # a state the outputs or the energy notice within PROMISE_MARGIN of its own size is what
    # they are made of, and is tested as before
    keep = ~diff | ~np.isfinite(size) | (size < PROMISE_MARGIN * base)
    if energy_index is not None:
        keep[energy_index] = True
    keep[list(getattr(scales, "user", ()))] = True
    out = np.where(keep, base, np.maximum(base, size))
    result = out.view(Scales)
    for attr in ("floored", "user", "sizes"):
        setattr(result, attr, getattr(scales, attr, None) if attr != "user" else tuple(getattr(scales, "user", ())))
    return result


def run_energy(mod, scales) -> float:
    """The run's energy scale: the energy scale of the model with every state at its nominal
    size — the nominal scale of the energy accumulator ``energy.supplied``, which
    :func:`phc.simulation.scaling.nominal_scales` sets to at least that (the energy supplied is
    measured against what the states can hold). 0 without nominal scales. Computed once per
    run (``c[_RUN_ENERGY]`` of :mod:`phc.simulation.step_logic`). It floors the energy checks,
    whose scale would otherwise vanish with the state (a driven block that sticks at rest:
    H ≈ 1e-73, its dissipated power's round-off ±4e-54): midpoint4's passivity guard
    (:func:`phc.simulation.step_logic.passivity_floor`, ``1e-13·max(|escale|, run_energy)``)
    and the discrete gradient's energy balance (``c[_TOL]²·run_energy``: the stage values'
    tolerance, squared where H is stationary)."""
    if scales is None:
        return 0.0
    s = np.asarray(scales, dtype=float)
    names = list(getattr(mod, "module", mod).VARIABLES)
    if "energy.supplied" not in names or s.shape != (len(names),):
        return 0.0
    e = abs(float(s[names.index("energy.supplied")]))
    return e if np.isfinite(e) else 0.0
