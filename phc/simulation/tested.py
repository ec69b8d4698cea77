"""Which algebraic variables IDA tests, and how tightly (used by :mod:`phc.simulation.ida`).

An algebraic variable the algebraic rows determine from the states (index 1: a junction's
effort or flow) goes into IDA's Newton and error tests like a state
(:func:`determined_algebraic`), with its rate at the start computed
(:func:`algebraic_rates`), and with a scale no tighter than the states' tolerances
determine it where it is, or may become, a small difference of its terms
(:func:`determined_scales`; docs/tolerances.md, rule 11).
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import scipy.sparse as sps

from phc.simulation.guard import CATCH, ModelEvaluationError
from phc.simulation.minnorm import dense_min_norm, min_norm_solve


def _adjacency(keys, values, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(pointers, entries): the `values` of key k are ``entries[pointers[k]:pointers[k + 1]]``, for
    keys 0 … size − 1 (a compressed sparse pattern without scipy's checks, which cost more than the
    rest of :func:`determined_algebraic` on a small model)."""
    order = np.argsort(keys, kind="stable")
    return np.searchsorted(keys[order], np.arange(size + 1)), values[order]


def determined_algebraic(mod, p, t, y, yp) -> np.ndarray:
    """Mask of the algebraic variables the algebraic rows determine from the states (index 1:
    a junction effort, a resistor's flow), as opposed to those only the derivative of a
    constraint determines (index 2: multipliers, the torque a flow source applies).

    The algebraic rows are those without ẏ (``F_ẏ`` row zero at (t, y, ẏ)); on their pattern
    in the algebraic variables, a maximum matching and the Dulmage–Mendelsohn
    decomposition: a variable an alternating path reaches from an unmatched variable is
    not determined (the rows leave a choice), every other matched variable is — unless its
    row has an undetermined algebraic variable in it, whose index it then inherits: sliding
    friction's force λ_t = −μσλ follows the contact's force λ (the multiplier of ġ = 0), and
    with λ_t tested IDA's first 300 steps on the woodpecker toy reached t = 4.9e-15 s (a BDF
    step's λ carries the constraint's round-off over h: its error grows as the step shrinks). Index-1
    variables go into IDA's Newton and error tests like the states; index-2 ones cannot
    (BDF then cuts its step without end) and are recomputed at the output times instead
    (:mod:`phc.simulation.polish`)."""
    from phc.analysis.matching import bipartite_matching

    n, m = mod.N, len(mod.EQUATIONS)
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    out = np.zeros(n, dtype=bool)
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    if not len(rows) or m != n:
        return out
    # the entries that are nonzero here or at a nearby point: the modes of switches are
    # parameters (a sticking friction law replaces its row), a coefficient may vanish by chance
    rng = np.random.default_rng(0)
    size = np.abs(y) + np.abs(yp) + 1e-3
    nonzero_y = np.zeros(len(rows), dtype=bool)
    nonzero_yp = np.zeros(len(rows), dtype=bool)
    for y_, yp_ in ((y, yp), (y + 1e-3 * size * rng.uniform(0.5, 1.5, n), yp + 1e-3 * size * rng.uniform(0.5, 1.5, n))):
        a, b = np.zeros(len(rows)), np.zeros(len(rows))
        try:
            mod.jacobian(t, y_, yp_, p, 0.0, a)
            mod.jacobian(t, y_, yp_, p, 1.0, b)
        except (ModelEvaluationError, *CATCH):
            return out
        nonzero_y |= (a != 0) | ~np.isfinite(a)
        nonzero_yp |= (b - a != 0) | ~np.isfinite(b)
    dynamic = np.zeros(m, dtype=bool)
    dynamic[rows[nonzero_yp]] = True
    alg_rows = np.flatnonzero(~dynamic)
    # GGL multipliers and contact forces (zero while open, index 2 while closed) are never tested
    from phc.simulation.impacts import contact_forces

    untested = {j for j, v in enumerate(mod.VARIABLES) if str(v).startswith("ggl.")} | set(contact_forces(mod))
    alg_cols = np.flatnonzero(~diff & np.array([j not in untested for j in range(n)]))
    if not len(alg_rows) or not len(alg_cols):
        return out
    rpos = np.full(m, -1)
    rpos[alg_rows] = np.arange(len(alg_rows))
    cpos = np.full(n, -1)
    cpos[alg_cols] = np.arange(len(alg_cols))
    sel = (rpos[rows] >= 0) & (cpos[cols] >= 0) & nonzero_y
    if sel.any():
        pattern = sps.csr_matrix((np.ones(int(sel.sum())), (rpos[rows[sel]], cpos[cols[sel]])),
                                 shape=(len(alg_rows), len(alg_cols)))
        match = bipartite_matching(pattern)
    else:  # no algebraic row has an algebraic variable: nothing matched (what the matching returns)
        match = np.full(len(alg_rows), -1, dtype=np.int64)
    row_of = np.full(len(alg_cols), -1)
    matched = np.flatnonzero(match >= 0)
    row_of[match[matched]] = matched
    col_ptr, col_rows = _adjacency(cpos[cols[sel]], rpos[rows[sel]], len(alg_cols))  # each column's rows
    seen = np.zeros(len(alg_cols), dtype=bool)
    stack = list(np.flatnonzero(row_of < 0))
    seen[stack] = True
    while stack:  # alternating paths: unmatched column → its rows → their matched columns
        c = stack.pop()
        for r in col_rows[col_ptr[c]:col_ptr[c + 1]]:
            c2 = match[r]
            if c2 >= 0 and not seen[c2]:
                seen[c2] = True
                stack.append(c2)
    # a variable its row determines from an undetermined one (a sliding friction force
    # λ_t = −μσλ, λ a contact's force) inherits that one's index: not determined
    determined = ~seen & (row_of >= 0)
    alg_set = ~diff
    alg_set[list(untested)] = True  # (GGL multipliers and contact forces are algebraic)
    free = np.zeros(n, dtype=bool)
    free[alg_set] = True
    free[alg_cols[determined]] = False
    row_ptr, row_cols = _adjacency(rows[nonzero_y], cols[nonzero_y], m)  # each row's columns in F_y
    changed = True
    while changed:
        changed = False
        for i in np.flatnonzero(determined):
            r = alg_rows[row_of[i]]
            if free[row_cols[row_ptr[r]:row_ptr[r + 1]]].any():
                determined[i] = False
                free[alg_cols[i]] = True
                changed = True
    out[alg_cols[determined]] = True
    return out


SENSITIVITY_DENSE = 400
"""Up to this many unknowns the scales of the determined algebraic variables are raised to
what the states' tolerances allow them (:func:`determined_scales`); larger models keep theirs."""


CANCELLATION = 10.0
"""An index-1 variable below 1/CANCELLATION of the terms the states put into it is a
difference of those terms (:func:`determined_scales`)."""


TERM_FRACTION = 1e-6
"""A term of an index-1 variable below this fraction of its largest term does not count
(:func:`source_terms`, :func:`determined_scales`): it cannot cancel the largest to a small
difference, and the coefficients a solve for ``∂z/∂x`` gives where they vanish are round-off,
~1e-16 of the others."""


def source_terms(mod, p, t, y, yp, Fz, alg_rows, dz_dx, x_cols, z_cols, span: float) -> np.ndarray:
    """The size of the part of each index-1 variable z that does not come from the states —
    a source —, to first order at (t, y): z minus ``∂z/∂x · x`` (a constant voltage), or the
    change ``|∂z/∂t|·span`` over the run, ``∂z/∂t = −F_z⁺ F_t`` on the algebraic rows (a sine),
    where the model gives ``F_t``."""
    y = np.asarray(y, dtype=float)
    x = np.where(np.isfinite(y[x_cols]), y[x_cols], 0.0)
    z = np.where(np.isfinite(y[z_cols]), y[z_cols], 0.0)
    size = np.abs(z - dz_dx @ x)
    try:
        ft = np.zeros(len(mod.EQUATIONS))
        mod.residual_t(t, y, np.asarray(yp, dtype=float), p, ft)
        ft = ft[alg_rows]
        if np.all(np.isfinite(ft)) and np.any(ft != 0):
            size = np.maximum(size, np.abs(dense_min_norm(Fz, ft)) * abs(span))
    except (ModelEvaluationError, *CATCH, AttributeError, ValueError, np.linalg.LinAlgError):
        pass
    return size


def determined_scales(mod, p, t, y, yp, determined, scales, rtol: float = 1.0, atol: float = 1.0,
                      span: float = 0.0) -> Optional[np.ndarray]:
    """The nominal `scales` with each index-1 algebraic variable z_j (`determined`) that is a
    small difference of the terms the states put into it raised to ``(1 + rtol/atol) T_j``,
    ``T_j = Σ_k |∂z_j/∂x_k| s_k``: the error the states' own tolerances (``rtol·|x_k| +
    atol·s_k``, |x_k| up to s_k) put into it, over atol. A small difference is one of

    * over the run: ``Σ_k |∂z_j/∂x_k| n_k`` above ``CANCELLATION · n_j``, with ``n`` the sizes
      the variables take (:attr:`phc.simulation.scaling.Scales.sizes`, the scales before
      the round-off floor; a floor that raised z's scale says how finely z can be resolved,
      not how large it is);
    * at the start of this piece (`y`, in the modes of `p`): the error the states'
      tolerances put into z, ``Σ_k |∂z_j/∂x_k| (rtol·|x_k| + atol·s_k)``, above
      ``CANCELLATION`` times z's own ``rtol·|z_j| + atol·s_j``. A switched law makes z
      small in one mode only — a diode's voltage is Ron·i, 0.1 V out of the source's and
      the capacitor's 7 V, while it conducts, and 13 V while it blocks — and a piece that
      begins at an event begins with z on the boundary;
    * at any time of the run: z is a sum of two or more terms — two
      states, or a state and a source (a part of z that does not vanish with the states, or
      that depends on t) — so it passes through 0 wherever its terms cancel, and the start
      and the sizes cannot say whether they will. A loudspeaker's coil voltage
      ``V(t) − R φ/L − Bl p/m`` is 2.83 V at most and 0 at the start, but crosses 0 twice
      a period of its drive while its terms do not; there its test, ``atol·s_z``, was
      ``rtol/atol`` times tighter than what the states' ``rtol·|x|`` put into it (10⁴ at
      rtol 1e-6, atol 1e-10; 100 at rtol 1e-8): IDA, on large steps at a high order,
      collapsed to steps of 3e-8 s at order 1 there and stayed (the trap below), so that
      rtol 1e-6 took 118 784 steps for 0.1 s of a 200 Hz tone and rtol 1e-8 10 983.
      A variable of one term, ``|z| = |∂z/∂x_k| |x_k|`` (a friction element's flow p/m),
      cannot be a small difference and keeps its scale.

    Other index-1 variables keep their scales (one that is a state times a factor, a
    friction element's flow p/m, is tested as tightly as the state determines it).

    The algebraic rows determine z from the states x (and t); to first order
    ``∂z/∂x = −(F_z)⁺ F_x`` on those rows. IDA tests z like a state, at
    ``rtol·|z| + atol·s_z``; where z is the small difference of large terms driven by the
    states — an inductor's voltage ``V(t) − R φ/L`` behind a resistor, 0.04 V out of 10 V,
    with ``∂z/∂φ = −R/L = −25 000`` — an error of the states within their own tolerance
    moves z by far more than z's, and IDA cuts its step to resolve the states far beyond
    what was asked: 556 000 steps for 0.1 s of an RL circuit driven at 100 rad/s, where
    raising the scale of that voltage to the size of the terms it is the difference of
    takes a few hundred: IDA at order 5 fell into runs of error-test and Newton failures,
    every step, while the same model with the voltage left out of the test, or at order 3,
    ran smoothly. At order 1 it does not get out again: z's error estimate is then the
    change of the states' truncation error times ∂z/∂x — ``(h² − h_old²)/2 · v_C''/Ron`` for
    a diode's current behind a capacitor — so a step that doubles fails the test and the
    retry passes at the old size; with a failure every other step BDF never raises its
    order. The rectifier of tests/simulation/test_events.py crawled that way, with steps of
    2.5e-9 s, to 10⁶ steps: its diode's voltage and current had local tolerances of
    1.5e-12 V and 2.1e-12 A while the capacitor's (3.6e-11 V at 7 V) put 3.6e-11 V and
    7e-11 A into them (the round-off floor had raised their scales to 180 V and 167 A,
    hiding the cancellation; the current takes 0.54 A, the voltage 13 V only while the
    diode blocks). Where it fell into the trap depended on round-off: the BLAS kernel
    (Zen, Haswell; SkylakeX passed) or the end time (t_end = 0.0623 s crawled on SkylakeX);
    now about 3 000 steps on each. The user's own scales are kept. Returns None where
    nothing changes (no determined variable, a model above :data:`SENSITIVITY_DENSE`
    unknowns, or a Jacobian that cannot be evaluated)."""
    n, m = mod.N, len(mod.EQUATIONS)
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    z_cols = np.flatnonzero(np.asarray(determined, dtype=bool) & ~diff)
    names = list(mod.VARIABLES)
    x_mask = diff.copy()
    if "energy.supplied" in names:  # it feeds nothing back
        x_mask[names.index("energy.supplied")] = False
    x_cols = np.flatnonzero(x_mask)
    if scales is None or not len(z_cols) or not len(x_cols) or n > SENSITIVITY_DENSE or m != n:
        return None
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    a, b = np.zeros(len(rows)), np.zeros(len(rows))
    try:
        mod.jacobian(t, y, yp, p, 0.0, a)
        mod.jacobian(t, y, yp, p, 1.0, b)
    except (ModelEvaluationError, *CATCH):
        return None
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return None
    Fy = np.zeros((m, n))
    Fyp = np.zeros((m, n))
    np.add.at(Fy, (rows, cols), a)
    np.add.at(Fyp, (rows, cols), b - a)
    alg_rows = np.flatnonzero(~np.any(Fyp != 0, axis=1))
    if not len(alg_rows):
        return None
    Fz = Fy[np.ix_(alg_rows, z_cols)]
    Fx = Fy[np.ix_(alg_rows, x_cols)]
    try:
        dz_dx = -dense_min_norm(Fz, Fx)  # least norm (phc.simulation.minnorm), all columns at once
    except (ValueError, np.linalg.LinAlgError):
        return None
    s = np.asarray(scales, dtype=float)
    ratio = rtol / atol if atol > 0 and np.isfinite(rtol / atol) else 1.0
    total = np.abs(dz_dx) @ s[x_cols]
    # where z is a small difference of the states' terms, its own rtol·|z| is far tighter than
    # the states' rtol·|x| puts into it: that part goes into the scale too. Judged on the sizes
    # the variables take, before the round-off floor (scaling.Scales.sizes: a floor that raised
    # z's scale above its size says how finely z can be resolved, not how large it is) ...
    size = getattr(scales, "sizes", None)
    size = s if size is None or np.shape(size) != s.shape else np.asarray(size, dtype=float)
    cancels = np.abs(dz_dx) @ size[x_cols] > CANCELLATION * size[z_cols]
    # ... and at the values of the start: in this piece's mode z may be a small difference where
    # its size over the run is not (a diode's voltage: Ron·i, 0.1 V out of the capacitor's 7 V,
    # while it conducts; 13 V blocking), and a piece that starts at an event starts with z on
    # the boundary. There the error the states' tolerances put into z is compared with z's own
    x = np.where(np.isfinite(y), np.abs(np.asarray(y, dtype=float)), 0.0)
    put = np.abs(dz_dx) @ (ratio * x[x_cols] + s[x_cols])
    cancels |= put > CANCELLATION * (ratio * x[z_cols] + s[z_cols])
    # ... and wherever in the run its terms may cancel: a sum of two terms or more
    terms = np.column_stack([np.abs(dz_dx) * s[x_cols],
                             source_terms(mod, p, t, y, yp, Fz, alg_rows, dz_dx, x_cols, z_cols, span)])
    largest = terms.max(axis=1, initial=0.0)
    cancels |= np.sum(terms > TERM_FRACTION * largest[:, None], axis=1) * (largest > 0) >= 2
    need = np.where(cancels, (1.0 + ratio) * total, 0.0)
    out = s.copy()
    user = set(getattr(scales, "user", ()) or ())
    for j, v in zip(z_cols, need):
        if int(j) not in user and np.isfinite(v) and v > out[j]:
            out[j] = v
    return out if np.any(out != s) else None


def algebraic_rates(mod, p, t, y, yp, determined) -> np.ndarray:
    """ẏ with the rates of the `determined` (index-1) algebraic variables filled in: the
    time derivative of their algebraic rows, ``F_y[R, A] ż_A = −(F_y[R, states] ẏ + F_t[R])``
    (least squares). A consistent start leaves them 0, and IDA's first predictor then
    misses by ż·h: a diode voltage that follows V₀ sin(ωt) from 0 at 3 kV/s failed the error
    test at every step size down to 1e-13 s."""
    yp = np.array(yp, dtype=float)
    A = np.flatnonzero(determined)
    if not len(A):
        return yp
    n, m = mod.N, len(mod.EQUATIONS)
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    a, b = np.zeros(len(rows)), np.zeros(len(rows))
    ft = np.zeros(m)
    try:
        mod.jacobian(t, y, yp, p, 0.0, a)
        mod.jacobian(t, y, yp, p, 1.0, b)
        mod.residual_t(t, y, yp, p, ft)
    except (ModelEvaluationError, *CATCH, AttributeError):
        return yp
    algebraic_row = np.ones(m, dtype=bool)
    algebraic_row[rows[b - a != 0]] = False
    R = np.flatnonzero(algebraic_row)
    Fy = sps.csr_matrix((a, (rows, cols)), shape=(m, n))[R]
    known = yp.copy()
    known[~np.asarray(mod.DIFFERENTIAL, dtype=bool)] = 0.0
    rhs = -(Fy @ known + ft[R])
    M = Fy[:, A]
    try:
        z = min_norm_solve(M, rhs)  # dense, sparse LU or LSMR by size and rank (phc.simulation.minnorm)
    except (ValueError, np.linalg.LinAlgError):
        return yp
    if np.all(np.isfinite(z)):
        yp[A] = z
    return yp
