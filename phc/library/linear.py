"""Matrix-defined linear port-Hamiltonian components (``type: linear_phs``).

``E ẋ = (J − R) Q x − Σ_{effort_in} B e + Σ_{flow_in} B f`` with outputs
``f = Bᵀ Q x`` (effort_in) or ``e = −Bᵀ Q x`` (flow_in) and ``H = ½ xᵀ Q x``; the power
balance ``dH/dt = −(Qx)ᵀR(Qx) − Σ f·e`` follows as in :mod:`phc.library.phs`. The
matrices become :class:`~phc.dae.LinearTerm` blocks that stay sparse through code
generation; only the few boundary couplings are sympy expressions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.sparse as sps
import sympy as sp

from phc.dae import LinearTerm, QuadraticForm
from phc.library.dirac import DiracBuilder
from phc.library.phs import local_scope


def _load_npz(b, ctx, spec, path):
    if spec.matrices is None:
        return {}
    file = Path(ctx.file).parent / spec.matrices
    try:
        with np.load(file, allow_pickle=False) as data:  # a model's data never unpickles code
            return {k: np.array(data[k]) for k in data.files}
    except (OSError, ValueError) as err:
        b.error("PHC-E130", f"cannot read matrices file `{spec.matrices}`: {err}", ctx, (*path, "matrices"))
        return None


def _matrix(b, ctx, ref, arrays, path, shape, what):
    """A sparse matrix from an inline list of numbers or a named array."""
    if isinstance(ref, str):
        if arrays is None:
            return None
        if ref in arrays:
            m = sps.csr_matrix(np.atleast_2d(np.asarray(arrays[ref], dtype=float)))
        elif f"{ref}.data" in arrays:
            try:
                m = sps.csr_matrix((arrays[f"{ref}.data"], arrays[f"{ref}.indices"], arrays[f"{ref}.indptr"]),
                                   shape=tuple(int(x) for x in arrays[f"{ref}.shape"]))
            except (KeyError, ValueError) as err:
                b.error("PHC-E131", f"sparse array `{ref}` in the matrices file is malformed: {err}", ctx, path)
                return None
        else:
            b.error("PHC-E131", f"no array `{ref}` in the matrices file", ctx, path,
                    hint=f"it holds: {', '.join(sorted(arrays)) or 'nothing'}")
            return None
    else:
        rows = [[v for v in row] if isinstance(row, list) else [row] for row in ref]
        if any(not isinstance(v, (int, float)) for row in rows for v in row):
            b.error("PHC-E132", f"inline {what} of a `linear_phs` must hold numbers; scale it with `scale`",
                    ctx, path)
            return None
        if len({len(r) for r in rows}) > 1:
            b.error("PHC-E102", f"{what} has rows of different lengths", ctx, path)
            return None
        m = sps.csr_matrix(np.array(rows, dtype=float).reshape(len(rows), -1))
    if not np.all(np.isfinite(m.data)):
        b.error("PHC-E012", f"{what} has non-finite entries", ctx, path)
        return None
    if shape is not None and m.shape != shape:
        b.error("PHC-E102", f"{what} is {m.shape[0]} × {m.shape[1]}, expected {shape[0]} × {shape[1]}", ctx, path)
        return None
    return m


def lower_linear_phs(b, ctx, name, spec, path):
    scope = local_scope(b, ctx, name, spec, path)
    span = ctx.smap.locate(path)
    names = ([f"x[{i}]" for i in range(spec.states)] if isinstance(spec.states, int) else list(spec.states))
    n = len(names)
    arrays = _load_npz(b, ctx, spec, path)
    mats = {}
    for key in ("J", "R", "Q", "E"):
        ref = getattr(spec, key)
        if ref is None:
            mats[key] = sps.identity(n, format="csr") if key in ("Q", "E") else sps.csr_matrix((n, n))
        else:
            mats[key] = _matrix(b, ctx, ref, arrays, (*path, key), (n, n), f"`{key}`")
    scale = {key: b.expr(ctx, spec.scale.get(key, 1), (*path, "scale", key), scope) for key in ("J", "R", "Q", "E")}
    if any(m is None for m in mats.values()):
        return
    J, R, Q, E = mats["J"], mats["R"], mats["Q"], mats["E"]
    tol = 1e-12 * max(1.0, abs(J).max(), abs(R).max(), abs(Q).max())
    if abs(J + J.T).max() > tol:
        b.error("PHC-E402", f"`J` of `{name}` is not skew-symmetric (max |J + Jᵀ| = {abs(J + J.T).max():.3g})",
                ctx, (*path, "J"))
    if abs(R - R.T).max() > tol or abs(Q - Q.T).max() > tol:
        b.error("PHC-E403", f"`R` and `Q` of `{name}` must be symmetric", ctx, path)
    x, dx = zip(*(b.add_state(name, nm, span) for nm in names)) if n else ((), ())
    x, dx = tuple(x), tuple(dx)
    terms = [LinearTerm(scale["E"], E, x, derivative=True),
             LinearTerm(-scale["J"] * scale["Q"], (J @ Q).tocsr(), x)]
    if R.nnz:
        terms.append(LinearTerm(scale["R"] * scale["Q"], (R @ Q).tocsr(), x))
    rows = b.add_linear_rows(name, "dynamics", n, terms, span)
    # Certification sees only the ports: with e_x = Qx free, f = Bᵀe_x ranges over im Bᵀ
    # (effort_in) and the other port variable is free; one multiplier per row of B used.
    d = DiracBuilder(name, "linear_phs", span)
    lam: dict[int, sp.Symbol] = {}
    for pname, pspec in spec.ports.items():
        ppath = (*path, "ports", pname)
        port = b.add_port(name, pname, pspec.domain, pspec.dimension, pspec.frame, span)
        B = _matrix(b, ctx, pspec.B, arrays, (*ppath, "B"), (n, pspec.dimension), "`B`")
        if B is None:
            continue
        inputs = port.e if pspec.causality == "effort_in" else port.f
        sign = 1 if pspec.causality == "effort_in" else -1
        d.port(port)
        Bl = B.tocsc()
        for k in range(pspec.dimension):
            lo, hi = Bl.indptr[k], Bl.indptr[k + 1]
            proj = sum((float(v) * lam.setdefault(int(i), d.mult(f"ex[{int(i)}]"))
                        for i, v in zip(Bl.indices[lo:hi], Bl.data[lo:hi])), sp.Integer(0))
            d.rel(port.f[k] - proj if pspec.causality == "effort_in" else port.e[k] + proj)
        Bc = B.tocoo()
        for i, k, v in zip(Bc.row, Bc.col, Bc.data):
            b.add_to_row(rows[i], sign * float(v) * inputs[k])
        BtQ = (B.T @ Q).tocsr()
        for k in range(pspec.dimension):
            lo, hi = BtQ.indptr[k], BtQ.indptr[k + 1]
            out = scale["Q"] * sum((float(v) * x[j] for j, v in zip(BtQ.indices[lo:hi], BtQ.data[lo:hi])),
                                   sp.Integer(0))
            if pspec.causality == "effort_in":
                b.define(port.f[k], out)
            else:
                b.define(port.e[k], -out)
    d.register(b, kind="port_projection", note="matrix component: J skew, R and Q symmetric checked; ports "
               "certified through im Bᵀ")
    b.quadratic_energy.append(QuadraticForm(scale["Q"] / 2, Q.tocsr(), x))
    if R.nnz:
        b.quadratic_dissipation.append(QuadraticForm(scale["R"] * scale["Q"] ** 2, (Q.T @ R @ Q).tocsr(), x))
