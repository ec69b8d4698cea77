"""Long constant arrays of a generated module, printed in a size that does not grow with a mesh.

A distributed component's sparse blocks repeat one element's stencil: the row and column
indices step by the same pattern from element to element and the entries repeat the same
values. :func:`pieces` splits an array into *runs* — integers made of p interleaved
arithmetic sequences (entry k + p is entry k plus the step of k's sequence), floats whose
values repeat with period p — and literal stretches in between (the boundary elements,
another component, irregular data). The module rebuilds the array with ``_runs``
(:func:`_runs`, whose source :func:`decoder_source` prints into the module): integer runs exactly in int64
(then stored in the array's own type: int32 for the index arrays that fit), float runs by repeating the values (the
same bits). A uniform mesh of 10⁵ elements prints in the size of a few stencils; a
non-uniform mesh, whose entries differ from element to element, keeps its literal data.

Finding the runs costs a few passes over the array: the period is read off short windows
(:data:`WINDOW` entries, periods up to :data:`MAX_PERIOD`), the run around a window is
extended by one vectorized comparison, and the parts to its left and right are split the
same way; a part without a period at its middle or quarters is halved, down to
:data:`LITERAL_BELOW` entries (irregular data: log₂(n/LITERAL_BELOW) passes).
"""

from __future__ import annotations

import base64
import inspect

import numpy as np

MAX_PERIOD = 64
"""The longest repeating pattern looked for (entries): a stencil of the element types phc
lowers has at most a few dozen entries per element."""

WINDOW = 4 * MAX_PERIOD
"""Entries a period is read from; a run shorter than this is left literal."""

LITERAL_BELOW = 1024
"""A part shorter than this, without a period at its middle or quarters, is printed literally."""

def _runs(_dtype, _parts):
    """A long constant array stored in pieces: ('=', base64 of its little-endian bytes), or a
    run ('~', first, steps, count) of `count` integers made of len(first) interleaved
    sequences, sequence j from first[j] by steps[j] (a mesh's indices), or ('~', values, count)
    of `count` floats that repeat `values` (a mesh's stencil)."""
    _out = []
    for _part in _parts:
        if _part[0] == '=':
            _out.append(np.frombuffer(base64.b64decode(_part[1]), dtype=_dtype))
        elif len(_part) == 4:
            _k = np.arange(_part[3])
            _j = _k % len(_part[1])
            _out.append(np.array(_part[1], dtype=np.int64)[_j]
                        + (_k // len(_part[1])) * np.array(_part[2], dtype=np.int64)[_j])
        else:
            _out.append(np.resize(np.array(_part[1], dtype=float), _part[2]))
    return np.concatenate(_out, dtype=_dtype, casting='same_kind')


def decoder_source() -> str:
    """The source of :func:`_runs`, printed into every generated module that stores a long
    array in runs (the module needs only ``np`` and ``base64``), so that the module and this
    package decode with the same code."""
    return inspect.getsource(_runs)


def _holds(seq: np.ndarray, p: int, integer: bool) -> np.ndarray:
    """For each k with k + span < len(seq) (span 2p for integers, p for floats): whether entry
    k + span continues the run, i.e. ``seq[k+2p] − seq[k+p] == seq[k+p] − seq[k]`` (integers: each
    of the p interleaved sequences steps by its own constant) or ``seq[k+p] == seq[k]``."""
    if integer:
        return seq[2 * p:] - seq[p:-p] == seq[p:-p] - seq[:-2 * p]
    return seq[p:] == seq[:-p]


def _period(window: np.ndarray, integer: bool) -> int:
    """The smallest p ≤ MAX_PERIOD for which the whole window is one run, or 0."""
    top = min(MAX_PERIOD, len(window) // 3)
    p = np.arange(1, top + 1)
    first = (window[2 * p] - window[p] == window[p] - window[0]) if integer else window[p] == window[0]
    for q in p[first]:  # the first entry's test passes: then the whole window's
        if _holds(window, int(q), integer).all():
            return int(q)
    return 0


def _runs_of(seq: np.ndarray, integer: bool) -> list[tuple[int, int, int]]:
    """The runs of `seq` as (start, stop, period) of entries, in order, disjoint."""
    todo = [(0, len(seq))]
    found = []
    while todo:
        a, b = todo.pop()
        if b - a < WINDOW:
            continue
        mid = (a + b) // 2
        p = 0
        for at in (mid, (a + mid) // 2, (mid + b) // 2):  # the middle, then the quarters
            w0 = max(a, min(at - WINDOW // 2, b - WINDOW))
            p = _period(seq[w0:w0 + WINDOW], integer)
            if p:
                break
        if not p:
            if b - a >= 2 * LITERAL_BELOW:
                todo += [(a, mid), (mid, b)]
            continue
        span = 2 * p if integer else p
        good = _holds(seq[a:b], p, integer)  # good[k - a]: entry k + span continues from k
        k0 = w0 - a
        bad_left = np.flatnonzero(~good[:k0])
        bad_right = np.flatnonzero(~good[k0:])
        s = a + (bad_left[-1] + 1 if len(bad_left) else 0)
        e = (a + k0 + bad_right[0] + span) if len(bad_right) else b
        found.append((int(s), int(e), p))
        todo += [(a, s), (e, b)]
    return sorted(found)


def _literal(values: np.ndarray, dtype: str) -> tuple:
    return ("=", base64.b64encode(np.ascontiguousarray(values, dtype=dtype).tobytes()).decode())


def pieces(values, dtype: str) -> list[tuple]:
    """`values` (int64 with ``dtype='<i8'``, int32 with ``'<i4'``, float64 with ``'<f8'``) as the
    parts ``_runs`` reads."""
    a = np.ascontiguousarray(values, dtype=dtype)
    integer = dtype in ("<i8", "<i4")
    # integers compared in int64 (an int32 run's second differences may not fit in 32 bits), floats
    # by bits: -0.0 is not 0.0, NaN is NaN
    seq = a.astype(np.int64, copy=False) if integer else a.view(np.int64)
    parts, at = [], 0
    for s, e, p in _runs_of(seq, integer):
        if integer:
            piece = ("~", a[s:s + p].tolist(), (a[s + p:s + 2 * p] - a[s:s + p]).tolist(), e - s)
        else:
            pattern = a[s:s + p]
            if not np.all(np.isfinite(pattern)):
                continue  # printed literally: repr of inf/nan is not a Python literal
            piece = ("~", pattern.tolist(), e - s)
        if s > at:
            parts.append(_literal(a[at:s], dtype))
        parts.append(piece)
        at = e
    if at < len(a):
        parts.append(_literal(a[at:], dtype))
    return parts


def decode(parts: list, dtype: str) -> np.ndarray:
    """What the module's ``_runs`` builds from `parts` (for tests and checks)."""
    return _runs(dtype, parts)


def expression(values, dtype: str) -> str:
    """Python source that builds `values` in a generated module (needs ``_runs``)."""
    return f"_runs({dtype!r}, {pieces(values, dtype)!r})"
