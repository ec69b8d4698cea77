"""The energy sizes of the states (:func:`energy_sizes`): ``sqrt(2E / ∂²H/∂y_j²)``, the size
a state would have if it held the energy scale E alone — the energy floor of the nominal
scales (:mod:`phc.simulation.scaling`, rule 5).

Central differences need H with every state perturbed on its own: one call each would be
quadratic in the size of the model. The generated NumPy H (a compiled module's NumPy
reference too) is straight-line arithmetic on entries of y and sparse quadratic forms of
its index blocks, so the perturbed states of many variables are one call, first as a lazy
object whose products cost the nonzeros (:class:`_OneEntryColumns`), else as a matrix of
states (:func:`_columns`), each batch checked against single calls of the module's own H.
A C module's H at many states is one call of the step library (its own H at each state): the
first round's states are one call, and the later rounds' states of the variables still left
(:func:`_c_ahead`) another, of which a round reads its own (the rounds grow the step of a
variable H is linear in eight times: 16 calls became 2, the same sizes to the bit), up to
:data:`C_COLUMNS_ENTRIES`: each of its states costs the whole H, and a mesh's many states take
the NumPy reference's lazy columns instead.
"""

from __future__ import annotations

import numpy as np

def energy_sizes(mod, p, t0, y0, s, energy: float) -> np.ndarray:
    """``sqrt(2E / ∂²H/∂y_j²)`` for each differential variable j: its size if it held the
    energy scale E alone (0 where H is not curved in y_j or E is 0). Central differences
    with a step that grows until the second difference stands above H's round-off.

    One evaluation of H per variable and step would make this quadratic in the size of the
    model; the generated NumPy H evaluates a matrix of states column by column, so the
    perturbed states of many variables are one call (:func:`_columns`), checked against
    single calls."""
    from phc.simulation.guard import CATCH, ModelEvaluationError

    n = mod.N
    out = np.zeros(n)
    if not energy > 0:
        return out
    diff = np.flatnonzero(np.asarray(mod.DIFFERENTIAL, dtype=bool))
    names = list(mod.VARIABLES)
    skip = names.index("energy.supplied") if "energy.supplied" in names else -1
    H = mod.hamiltonian
    loaded = getattr(mod, "module", mod)
    # the C H at many states is one call: few, larger calls (not for a mesh: C_COLUMNS_ENTRIES)
    in_c = getattr(loaded, "BACKEND", "") == "c" and 2 * len(diff) * n <= C_COLUMNS_ENTRIES
    try:
        h0 = float(H(t0, y0, p))
        noise = 1e-12 * max(energy, abs(h0))
        todo = np.array([j for j in diff if j != skip], dtype=int)
        delta = np.maximum(np.asarray(s, dtype=float)[todo], np.abs(y0[todo]))
        delta = np.where(delta > 0, delta, 1.0)
        ahead = None  # (C) H at the later rounds' steps, evaluated at once after the first round
        for r in range(ROUNDS):
            if not len(todo):
                break
            pair = None
            if in_c:
                if r == 1:
                    ahead, pos = _c_ahead(loaded, t0, y0, p, todo, delta, ROUNDS - 1), np.arange(len(todo))
                    if ahead is not None and _rounds_at_once(ahead, todo, delta, h0, noise, energy, out):
                        break
                pair = ahead[r - 1][:, pos] if ahead is not None else \
                    _c_values(loaded, t0, y0, p, np.concatenate([todo, todo]), np.concatenate([delta, -delta]))
                pair = None if pair is None else pair.reshape(2, len(todo))
                in_c = pair is not None
            if pair is not None:
                hp, hm = _filled(H, t0, y0, p, todo, delta, pair[0]), _filled(H, t0, y0, p, todo, -delta, pair[1])
            else:
                hp, hm = _columns(mod, t0, y0, p, todo, delta), _columns(mod, t0, y0, p, todo, -delta)
            d2 = hp - 2.0 * h0 + hm
            finite = np.isfinite(d2)
            # above the round-off of the values differenced: an H linear in y_j (a
            # potential m·g·y) has no curvature, whatever its round-off at a huge step says
            with np.errstate(invalid="ignore", over="ignore"):
                curved = finite & (np.abs(d2) > np.maximum(noise, 1e-12 * np.maximum(np.abs(hp), np.abs(hm))))
                k = np.where(curved, d2, 0.0) / delta ** 2
            good = curved & (k > 0)
            out[todo[good]] = np.sqrt(2.0 * energy / k[good])
            more = finite & ~curved
            todo, delta = todo[more], delta[more] * 1e3
            if ahead is not None:
                pos = pos[more]
    except (ModelEvaluationError, *CATCH):
        return np.zeros(n)
    return np.where(np.isfinite(out), out, 0.0)


ROUNDS = 8
"""Steps :func:`energy_sizes` tries for a variable, each 1e3 times the one before, until the
second difference stands above H's round-off (a variable H is linear in takes them all)."""

AHEAD_ENTRIES = 1 << 23
"""Most entries (states times unknowns) of the matrix of states :func:`_c_ahead` evaluates H
at for the later rounds of a C module at once (64 MiB); above, one C call a round."""


def _c_values(loaded, t, y0, p, cols, steps) -> np.ndarray | None:
    """``H(t, y0 + steps[k]·e_{cols[k]}, p)`` for every k by the C module `loaded`'s own H, in
    calls of the step library (:func:`phc.codegen.c_steps.along`: the values to the bit of
    single calls, not finite ones included), in batches of :data:`COLUMNS_BATCH` entries; None
    where the library is not at hand."""
    from phc.codegen import c_steps

    out = np.empty(len(cols))
    size = max(2, COLUMNS_BATCH // max(len(y0), 1))
    for start in range(0, len(cols), size):
        stop = min(len(cols), start + size)
        Y = np.repeat(np.asarray(y0, dtype=float)[None, :], stop - start, axis=0)
        Y[np.arange(stop - start), cols[start:stop]] += steps[start:stop]
        rows = c_steps.along(loaded, p, np.full(stop - start, float(t)), Y, Y, only_h=True)
        if rows is None:
            return None
        out[start:stop] = rows["H"]
    return out


def _c_ahead(loaded, t, y0, p, todo, delta, rounds) -> np.ndarray | None:
    """The values of H :func:`energy_sizes` would ask for in its next `rounds` rounds were every
    variable of `todo` still in them (steps `delta`, 1e3 times more each round, as the rounds
    grow them), each round's ``+step`` and ``-step`` states: an array (rounds, 2, len(todo))
    from one C call, values that are not finite left as they are (:func:`_filled` decides where a
    round reads one); None above :data:`AHEAD_ENTRIES` or where the library is not at hand."""
    if not len(todo) or 2 * rounds * len(todo) * len(y0) > AHEAD_ENTRIES:
        return None
    steps, d = [], delta
    for _ in range(rounds):
        steps += [d, -d]
        d = d * 1e3
    values = _c_values(loaded, t, y0, p, np.tile(todo, 2 * rounds), np.concatenate(steps))
    return None if values is None else values.reshape(rounds, 2, len(todo))


def _rounds_at_once(ahead, todo, delta, h0, noise, energy, out) -> bool:
    """The later rounds of :func:`energy_sizes` from :func:`_c_ahead`'s values, all at once: each
    variable leaves at the first round whose second difference is not finite or stands above
    the round-off, as it does round by round (the same operations on the same numbers), and its
    size goes into `out`. False (`out` untouched) where a round would read a value that is not
    finite: the guarded H decides there, round by round."""
    steps = np.empty(ahead.shape[::2])
    d = delta
    for r in range(len(steps)):  # the steps as the rounds grow them
        steps[r], d = d, d * 1e3
    hp, hm = ahead[:, 0], ahead[:, 1]
    with np.errstate(invalid="ignore", over="ignore"):
        d2 = hp - 2.0 * h0 + hm
        finite = np.isfinite(d2)
        curved = finite & (np.abs(d2) > np.maximum(noise, 1e-12 * np.maximum(np.abs(hp), np.abs(hm))))
        k = np.where(curved, d2, 0.0) / steps ** 2
    leaves = ~finite | curved
    last = np.where(leaves.any(axis=0), leaves.argmax(axis=0), len(steps) - 1)  # the last round each is in
    reached = np.arange(len(steps))[:, None] <= last[None, :]
    if (reached & ~(np.isfinite(hp) & np.isfinite(hm))).any():
        return False
    cols = np.arange(len(todo))
    k, curved = k[last, cols], curved[last, cols]
    good = curved & (k > 0)
    out[todo[good]] = np.sqrt(2.0 * energy / k[good])
    return True


def _filled(H, t, y0, p, cols, steps, values) -> np.ndarray:
    """`values` of H at the states ``y0 + steps[k]·e_{cols[k]}`` with each value that is not
    finite replaced by the guarded `H`'s (it may recover or fail), as :func:`_c_columns` does."""
    values = np.array(values, dtype=float)
    for k in np.flatnonzero(~np.isfinite(values)):
        values[k] = _one_column(H, t, y0, p, cols[k], steps[k])
    return values


COLUMNS_BATCH = 1 << 23
"""Most entries of the matrix of states one batched evaluation of H holds (64 MiB). Each
evaluation runs the generated H's statements once on rows of this many columns, so the
interpreter's cost per statement is shared by more columns: for the 9999 unknowns of the
chain of ``benchmarks/bench_components.py`` the sizes took 3.8 s of CPU with 16 MiB
batches (209 columns), 2.0 s with 32 MiB, 1.7 s with 64 and 128 MiB, the same sizes to the bit."""


class _OneEntryColumns:
    """The states ``y0 + steps[k]·e_{cols[k]}`` (k < B) as the NumPy back end's H reads them,
    without a matrix of states: an entry ``y[i]`` is the row of its B values (``y0[i]``
    where column k does not perturb it), and ``y[idx]`` (an index array, the columns of a
    sparse quadratic form ``y[c] @ (Q @ y[c])``) a :class:`_PerturbedBlock`. Anything else the
    generated code might do with y raises TypeError (then the matrix of states, or single
    calls). Each quadratic form then costs its own nonzeros plus B, not B times the unknowns:
    a 40 004-unknown string's energy sizes took 160 s of CPU in single calls."""

    def __init__(self, y0, cols, steps):
        self.y0 = np.asarray(y0, dtype=float)
        self.cols = np.asarray(cols, dtype=np.int64)
        self.steps = np.asarray(steps, dtype=float)

    def __getitem__(self, key):
        if isinstance(key, (int, np.integer)):
            row = np.full(len(self.cols), self.y0[key])
            hit = self.cols == int(key) % len(self.y0)
            row[hit] += self.steps[hit]
            return row
        idx = np.asarray(key)
        if idx.ndim != 1 or idx.dtype.kind not in "iu":
            raise TypeError("only entries and index arrays of the states")
        idx = idx.astype(np.int64) % len(self.y0)
        order = np.argsort(idx, kind="stable")
        ranked = idx[order]
        if len(ranked) > 1 and np.any(ranked[1:] == ranked[:-1]):
            raise TypeError("a repeated index")
        where = np.searchsorted(ranked, self.cols)
        inside = where < len(ranked)
        inside[inside] = ranked[where[inside]] == self.cols[inside]
        k = np.flatnonzero(inside)
        import scipy.sparse as sps

        delta = sps.csc_array((self.steps[k], (order[where[k]], k)), shape=(len(idx), len(self.cols)))
        return _PerturbedBlock(self.y0[idx], delta)


class _PerturbedBlock:
    """B vectors ``base + delta[:, k]`` (`delta` sparse): ``Q @ block`` (Q a scipy sparse
    matrix) is another block, ``block @ block`` the B inner products of matching columns."""

    def __init__(self, base, delta):
        self.base, self.delta = base, delta

    def __rmatmul__(self, Q):
        import scipy.sparse as sps

        if not sps.issparse(Q) or Q.ndim != 2 or Q.shape[1] != len(self.base):
            return NotImplemented
        return _PerturbedBlock(np.asarray(Q @ self.base, dtype=float), sps.csc_array(Q @ self.delta))

    def __matmul__(self, other):
        if not isinstance(other, _PerturbedBlock) or len(other.base) != len(self.base):
            return NotImplemented
        fixed = self.base @ other.base  # the unperturbed value, as a single call computes it
        cross = self.delta.T @ other.base + other.delta.T @ self.base
        both = np.asarray(self.delta.multiply(other.delta).sum(axis=0)).ravel()
        return fixed + (np.asarray(cross).ravel() + both)


LAZY_MIN_ENTRIES = 1 << 20
"""The lazy columns are used where the columns times the unknowns reach this (about 10³
states of a 10³-unknown model): below, the other ways cost milliseconds. Their sums run in
another order than the generated code's own, so the sizes differ in the last bits, and the
tolerances built on them (:func:`phc.simulation.scaling.promise_scales`) with them: a
24-element beam's order choice (tests/simulation/test_ida_order.py) went the other way."""
C_COLUMNS_ENTRIES = 1 << 30
"""Most entries (states times unknowns) a C module's own H is evaluated at, one full state per
column; above, the columns come from its NumPy reference's lazy columns (:class:`_OneEntryColumns`,
linear in the unknowns). Each column costs the whole H in C: the 4·10⁵ states of a 10⁵-element
beam (8·10⁵ unknowns) took more than ten minutes before a step was made."""
LAZY_BATCH = 1 << 16
"""Columns of one :class:`_OneEntryColumns` evaluation of H (its rows cost this many entries each)."""


def _columns(mod, t, y0, p, cols, steps) -> np.ndarray:
    """``H(t, y0 + steps[k]·e_{cols[k]}, p)`` for every k. The NumPy back end's H is
    straight-line arithmetic on the entries of y and sparse quadratic forms of its index
    blocks, so the perturbed states (one column each) give the values of all columns in one
    call: first as :class:`_OneEntryColumns` (cost linear in the unknowns), else as a matrix
    of states; each batch is checked against single calls at its first and last columns (any
    other shape, value or error: one call per column). A compiled module's columns are
    those of its NumPy reference module, checked against the compiled H the same way."""
    H = mod.hamiltonian
    out = np.empty(len(cols))
    raw = getattr(H, "__wrapped__", H)
    loaded = getattr(mod, "module", mod)
    reference = getattr(loaded, "REFERENCE", loaded)  # a compiled module's NumPy module (phc.codegen.backends)
    if reference is not loaded:  # C or numba: their H takes one state; the NumPy H batches, checked against them
        raw = reference.hamiltonian
    batched = getattr(reference, "BACKEND", "numpy") == "numpy" and len(cols) > 1
    # single calls: the module's own H first (a guard costs tens of µs a call; the slider–crank's
    # H, whose sin does not take a matrix of states, was 270 calls, 10 ms a run); the guarded H
    # where that fails or is not finite
    unguarded = getattr(loaded, "hamiltonian", None) if loaded is not mod else None
    size = max(2, COLUMNS_BATCH // max(len(y0), 1))
    start = 0
    if getattr(loaded, "BACKEND", "") == "c" and 1 < len(cols) and len(cols) * len(y0) <= C_COLUMNS_ENTRIES:
        # the C H itself at every column: one C call
        start = _c_columns(H, loaded, t, y0, p, cols, steps, size, out)
    if batched and start < len(cols) and len(cols) * len(y0) >= LAZY_MIN_ENTRIES:
        start = _lazy_columns(H, raw, t, y0, p, cols, steps, out)
    while start < len(cols):
        stop = min(len(cols), start + size)
        c, d = cols[start:stop], steps[start:stop]
        values = None
        if batched and stop - start > 1:
            Y = np.repeat(np.asarray(y0, dtype=float)[:, None], stop - start, axis=1)
            Y[c, np.arange(stop - start)] += d
            try:
                with np.errstate(all="ignore"):
                    values = np.asarray(raw(t, Y, p), dtype=float)
            except Exception:  # noqa: BLE001 - not column by column: single calls below
                values = None
            if values is None or values.shape != (stop - start,) or \
                    not _matches_single(H, t, y0, p, c, d, values, (0, stop - start - 1)):
                values = None
            if values is None:
                batched = False
        single = range(stop - start) if values is None else np.flatnonzero(~np.isfinite(values))
        values = np.empty(stop - start) if values is None else values
        for k in single:  # a value that is not finite: the guarded call decides (it may recover or fail)
            values[k] = _one_column(H, t, y0, p, c[k], d[k], unguarded)
        out[start:stop] = values
        start = stop
    return out


def _c_columns(H, loaded, t, y0, p, cols, steps, size, out) -> int:
    """The columns of :func:`_columns` by the C module `loaded`'s own H, called by the step
    library on a matrix of states (:func:`phc.codegen.c_steps.along`: the values of single
    calls to the bit), in batches of `size`, into `out`; how many (0: the library is not at
    hand). A value that is not finite is the guarded `H`'s to decide (it may recover or fail)."""
    from phc.codegen import c_steps

    start = 0
    while start < len(cols):
        stop = min(len(cols), start + size)
        Y = np.repeat(np.asarray(y0, dtype=float)[None, :], stop - start, axis=0)
        Y[np.arange(stop - start), cols[start:stop]] += steps[start:stop]
        rows = c_steps.along(loaded, p, np.full(stop - start, float(t)), Y, Y, only_h=True)
        if rows is None:
            return start
        values = rows["H"]
        for k in np.flatnonzero(~np.isfinite(values)):
            values[k] = _one_column(H, t, y0, p, cols[start + k], steps[start + k])
        out[start:stop] = values
        start = stop
    return start


def _one_column(H, t, y0, p, col, step, unguarded=None) -> float:
    """H, by the guarded single call, at the state y0 with entry `col` moved by `step`
    (by `unguarded`, the module's own H, when given and its value is finite)."""
    y = np.array(y0, dtype=float)
    y[col] += step
    if unguarded is not None:
        try:
            with np.errstate(all="ignore"):
                value = float(unguarded(t, y, p))
        except Exception:  # noqa: BLE001 - the guarded call says what went wrong
            value = np.nan
        if np.isfinite(value):
            return value
    return float(H(t, y, p))


def _matches_single(H, t, y0, p, c, d, values, ks) -> bool:
    """Whether the batched `values` of H at columns ``ks`` equal single calls (to 1e-14)."""
    for k in ks:
        single = _one_column(H, t, y0, p, c[k], d[k])
        if not (values[k] == single or abs(values[k] - single) <= 1e-14 * abs(single)):
            return False
    return True


def _lazy_columns(H, raw, t, y0, p, cols, steps, out) -> int:
    """The first columns of :func:`_columns` evaluated as :class:`_OneEntryColumns`, in
    batches of :data:`LAZY_BATCH`, into `out`; returns how many (0 when H does not take
    them: the first batch that fails a check stops, and the rest goes the other ways)."""
    start = 0
    while start < len(cols):
        stop = min(len(cols), start + LAZY_BATCH)
        c, d = cols[start:stop], steps[start:stop]
        try:
            with np.errstate(all="ignore"):
                values = np.asarray(raw(t, _OneEntryColumns(y0, c, d), p), dtype=float)
        except Exception:  # noqa: BLE001 - H reads y otherwise: the matrix of states or single calls
            return start
        if values.shape != (stop - start,) or not _matches_single(H, t, y0, p, c, d, values, (0, stop - start - 1)):
            return start
        for k in np.flatnonzero(~np.isfinite(values)):  # the guarded call decides (it may recover or fail)
            values[k] = _one_column(H, t, y0, p, c[k], d[k])
        out[start:stop] = values
        start = stop
    return start
