"""Matrix-defined linear port-Hamiltonian components (``type: linear_phs``).

``E ẋ = (J − R) Q x − Σ_{effort_in} B e + Σ_{flow_in} B f`` with outputs
``f = Bᵀ Q x`` (effort_in) or ``e = −Bᵀ Q x`` (flow_in) and ``H = ½ xᵀ EᵀQ x`` (``EᵀQ``
symmetric; ``½ xᵀQx`` for the default E = I); the power balance
``dH/dt = (Qx)ᵀE ẋ = −(Qx)ᵀR(Qx) − Σ f·e`` follows as in :mod:`phc.library.phs` (a linear
descriptor pH system: Beattie, Mehrmann, Xu, Zwart, "Linear port-Hamiltonian descriptor
systems", Math. Control Signals Syst. 30, 2018). The matrices become
:class:`~phc.ir.dae.LinearTerm` blocks that stay sparse through code generation; only the few
boundary couplings are sympy expressions.

The rows are derived from the complete description (:func:`phc.library.dirac.emit_sparse`),
the same system in kernel form over the co-energy ``z = Qx`` (a multiplier fixed by the
law ``z = Qx``): storage ``f = ẋ``, ``e = ∂H/∂x = EᵀQx = Eᵀz``, ``E f − J z + e_R ± B u = 0``,
resistive pairs ``f_R = z``, ``e_R = R f_R``, outputs ``Bᵀz``. Eliminating z, f_R and e_R
composes the matrices (``J Q``, ``R Q``, ``Bᵀ Q``); ``e = Eᵀz`` then holds identically and
gives no row.
"""

from __future__ import annotations

import io
import math
import struct
import zipfile
from typing import BinaryIO, Optional

import numpy as np
import scipy.sparse as sps
import sympy as sp

from phc.errors import NpzProblem
from phc.ir.dae import LinearTerm, QuadraticForm
from phc.frontend.files import SIZE_LIMIT_ENV, FileAccess, FileRefused, size_limit
from phc.library.dirac import DiracBuilder, emit
from phc.library.phs import local_scope
from phc.library.timing import refuse_time


MAX_NPZ_MEMBERS = 4096
"""Most arrays one matrices file may hold."""

MAX_DEFLATE_RATIO = 1100
"""Deflate cannot compress better than about 1032:1; a member claiming more is corrupt or a
zip bomb."""

MAX_MATRIX_DIMENSION = 10_000_000
"""Largest row or column count a sparse array's `shape` may claim."""

_NUMERIC_KINDS = "fiub"


class NpzArchive:
    """The arrays of a ``.npz`` matrices file, checked before any of them is read.

    An ``.npz`` is a zip of ``.npy`` members. On opening, the zip's central directory is
    bounded (:data:`MAX_NPZ_MEMBERS`), members must be stored or deflated (no bzip2/lzma,
    whose decompression phc cannot bound), not encrypted, and their declared sizes within
    :func:`phc.frontend.files.size_limit` ("matrices") and a deflate ratio of
    :data:`MAX_DEFLATE_RATIO`. :meth:`array` then reads one member: its ``.npy`` header is
    parsed first (numpy's parser with its 10 000-character limit; never unpickling) and
    the dtype (real numbers only: no object, string, complex or structured types), the
    number of dimensions (1 or 2) and the byte count claimed by the shape are checked
    against the budget *before* the data are read, and exactly that many bytes are read
    (a truncated member or one longer than its header says is refused). The total of
    bytes read is bounded by the same budget.
    """

    def __init__(self, fh: BinaryIO, label: str) -> None:
        self.label = label
        self.budget = size_limit("matrices")
        self.used = 0
        try:
            self._zip = zipfile.ZipFile(fh)
        except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError, struct.error,
                NotImplementedError, UnicodeDecodeError):
            raise NpzProblem(f"matrices file `{label}` is not a valid .npz (zip) file") from None
        infos = self._zip.infolist()
        if len(infos) > MAX_NPZ_MEMBERS:
            raise NpzProblem(f"matrices file `{label}` holds {len(infos):,} members, more than {MAX_NPZ_MEMBERS:,}")
        self.members: dict[str, zipfile.ZipInfo] = {}
        for info in infos:
            if info.filename.endswith(".npy"):
                self.members[info.filename[:-4]] = info

    @property
    def files(self) -> list[str]:
        return sorted(self.members)

    def __contains__(self, name: str) -> bool:
        return name in self.members

    def array(self, name: str) -> np.ndarray:
        """Array `name` (a native-order copy), or :class:`NpzProblem` naming what is wrong."""
        info = self.members[name]
        what = f"array `{name}` in `{self.label}`"
        if info.flag_bits & 0x1:
            raise NpzProblem(f"{what} is encrypted")
        if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise NpzProblem(f"{what} uses a compression phc does not read (only stored or deflated, as "
                             "numpy.savez and savez_compressed write)")
        if info.file_size > self.budget - self.used:
            raise NpzProblem(f"{what} unpacks to {info.file_size:,} bytes, above the budget of {self.budget:,} "
                             f"bytes for matrices (set {SIZE_LIMIT_ENV['matrices']} in MiB to raise it)")
        if info.compress_type == zipfile.ZIP_DEFLATED and info.file_size > MAX_DEFLATE_RATIO * max(info.compress_size, 1):
            raise NpzProblem(f"{what} claims to unpack {info.file_size / max(info.compress_size, 1):,.0f} times "
                             "its packed size, more than deflate can (a corrupt file or a zip bomb)")
        try:
            with self._zip.open(info) as member:
                version = np.lib.format.read_magic(member)
                if version == (1, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_1_0(member)
                elif version == (2, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_2_0(member)
                else:
                    raise NpzProblem(f"{what} has .npy format version {version}, which phc does not read")
                header_len = member.tell()
                self._check_header(what, shape, dtype)
                nbytes = math.prod(shape) * dtype.itemsize
                if header_len + nbytes != info.file_size:
                    raise NpzProblem(f"{what} is truncated or corrupt: its header promises {nbytes:,} bytes of "
                                     f"data, the member holds {max(info.file_size - header_len, 0):,}")
                raw = member.read(nbytes)
                if len(raw) != nbytes:
                    raise NpzProblem(f"{what} is truncated: {len(raw):,} of {nbytes:,} bytes")
        except NpzProblem:
            raise
        except Exception:  # noqa: BLE001 - any failure to parse untrusted bytes (numpy's header parser
            # raises ValueError, SyntaxError, tokenize.TokenError, ...; zipfile BadZipFile, zlib.error, EOFError).
            # Their messages may quote the file's bytes: say what, not those.
            raise NpzProblem(f"{what} is not a valid .npy array (corrupt header, data or zip member)") from None
        self.used += nbytes
        arr = np.frombuffer(raw, dtype=dtype).reshape(shape, order="F" if fortran else "C")
        return arr.astype(arr.dtype.newbyteorder("="), copy=True)

    def _check_header(self, what: str, shape, dtype: np.dtype) -> None:
        if dtype.hasobject or dtype.fields is not None or dtype.subdtype is not None or \
                dtype.kind not in _NUMERIC_KINDS:
            kind = {"O": "Python objects", "U": "strings", "S": "bytes", "c": "complex numbers",
                    "V": "a structured type", "M": "dates", "m": "time spans"}.get(dtype.kind, f"`{dtype}`")
            if dtype.fields is not None or dtype.subdtype is not None:
                kind = "a structured type"
            raise NpzProblem(f"{what} holds {kind}; matrices must hold real numbers (float or int)")
        if not isinstance(shape, tuple) or any(not isinstance(d, int) or d < 0 for d in shape):
            raise NpzProblem(f"{what} has an invalid shape")
        if len(shape) not in (1, 2):
            raise NpzProblem(f"{what} is {len(shape)}-D; matrices are 2-D arrays (or 1-D parts of a sparse one)")
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > self.budget - self.used:
            dims = " × ".join(f"{d:,}" for d in shape)
            raise NpzProblem(f"{what} claims {dims} entries ({nbytes:,} bytes), above the budget of "
                             f"{self.budget:,} bytes for matrices (set {SIZE_LIMIT_ENV['matrices']} in MiB to "
                             "raise it)")


def _load_npz(b, ctx, spec, path):
    """The checked archive of `spec.matrices` (:class:`NpzArchive`), ``{}`` without one, or
    None after reporting why it cannot be used (at the `matrices` key)."""
    if spec.matrices is None:
        return {}
    files = getattr(b, "files", None) or FileAccess()
    where = (*path, "matrices")
    try:
        _, real = files.resolve(ctx.file, spec.matrices, "matrices")
        data = files.read_bytes(real, spec.matrices, "matrices")  # bounded; no file stays open
    except FileRefused as err:
        b.error("PHC-E130" if err.reason == "missing" else "PHC-E116", err.message, ctx, where, hint=err.hint)
        return None
    try:
        return NpzArchive(io.BytesIO(data), spec.matrices)
    except NpzProblem as err:
        b.error("PHC-E130", str(err), ctx, where, hint="write it with numpy.savez (arrays of numbers)")
        return None


def _real_array(arrays, b, ctx, name, path, role) -> Optional[np.ndarray]:
    """Array `name` of the archive as checked by :class:`NpzArchive`, plus: non-empty (a
    whole matrix), integers (indices), finite (values). `role` is ``dense``, ``data`` (the
    values of a sparse matrix, possibly none) or ``index``. Problems are reported at `path`."""
    try:
        arr = arrays.array(name)
    except NpzProblem as err:
        b.error("PHC-E131", str(err), ctx, path)
        return None
    what = f"array `{name}` in `{arrays.label}`"
    if arr.size == 0 and role == "dense":
        b.error("PHC-E131", f"{what} is empty", ctx, path)
        return None
    if role == "index" and arr.dtype.kind not in "iu":
        b.error("PHC-E131", f"{what} must hold integers (it holds {arr.dtype})", ctx, path)
        return None
    if role != "index" and arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        b.error("PHC-E131", f"{what} has non-finite entries (NaN or inf)", ctx, path)
        return None
    return arr


def _sparse_from_npz(b, ctx, arrays, ref, path, shape, what):
    """A CSR matrix from `ref.data`, `ref.indices`, `ref.indptr`, `ref.shape`, each part
    checked before scipy sees them (scipy's own checks are not memory-safe on every bad
    input: out-of-range indices crashed the process)."""
    parts = {}
    for part in ("data", "indices", "indptr", "shape"):
        key = f"{ref}.{part}"
        if key not in arrays:
            b.error("PHC-E131", f"sparse array `{ref}` in `{arrays.label}` has no `{key}`", ctx, path,
                    hint="store CSR parts NAME.data, NAME.indices, NAME.indptr, NAME.shape")
            return None
        role = "data" if part == "data" else "index"
        arr = _real_array(arrays, b, ctx, key, path, role)
        if arr is None:
            return None
        if arr.ndim != 1:
            b.error("PHC-E131", f"array `{key}` in `{arrays.label}` must be 1-D (it is {arr.ndim}-D)", ctx, path)
            return None
        parts[part] = arr
    bad = lambda msg: b.error("PHC-E131", f"sparse array `{ref}` in `{arrays.label}`: {msg}", ctx, path)  # noqa: E731
    dims = parts["shape"]
    if dims.size != 2 or (dims < 0).any() or (dims > MAX_MATRIX_DIMENSION).any():
        bad(f"`{ref}.shape` must hold two sizes between 0 and {MAX_MATRIX_DIMENSION:,}")
        return None
    n_rows, n_cols = int(dims[0]), int(dims[1])
    if shape is not None and (n_rows, n_cols) != shape:
        b.error("PHC-E102", f"{what} is {n_rows} × {n_cols}, expected {shape[0]} × {shape[1]}", ctx, path)
        return None
    data, indices, indptr = parts["data"], parts["indices"], parts["indptr"]
    if len(indptr) != n_rows + 1:
        bad(f"`{ref}.indptr` has {len(indptr):,} entries, expected rows + 1 = {n_rows + 1:,}")
        return None
    if len(indices) != len(data):
        bad(f"`{ref}.indices` has {len(indices):,} entries but `{ref}.data` has {len(data):,}")
        return None
    if indptr[0] != 0 or (np.diff(indptr.astype(np.int64, copy=False)) < 0).any() or (indptr < 0).any():
        bad(f"`{ref}.indptr` must start at 0 and never decrease")
        return None
    if int(indptr[-1]) != len(data):
        bad(f"`{ref}.indptr` ends at {int(indptr[-1]):,}, but there are {len(data):,} entries")
        return None
    if len(indices) and ((indices < 0).any() or (indices >= n_cols).any()):
        bad(f"`{ref}.indices` must lie in 0 … {n_cols - 1} (the column count is {n_cols})")
        return None
    try:
        m = sps.csr_matrix((data.astype(float), indices.astype(np.int64), indptr.astype(np.int64)),
                           shape=(n_rows, n_cols))
        m.check_format(full_check=True)
    except (ValueError, TypeError) as err:  # pragma: no cover - the checks above come first
        bad(f"rejected by scipy ({type(err).__name__})")
        return None
    return m


def _matrix(b, ctx, ref, arrays, path, shape, what):
    """A sparse matrix from an inline list of numbers or a named array."""
    if isinstance(ref, str):
        if arrays is None:
            return None
        if ref in arrays:
            arr = _real_array(arrays, b, ctx, ref, path, "dense")
            if arr is None:
                return None
            m = sps.csr_matrix(np.atleast_2d(arr.astype(float)))
        elif f"{ref}.data" in arrays:
            m = _sparse_from_npz(b, ctx, arrays, ref, path, shape, what)
            if m is None:
                return None
        else:
            b.error("PHC-E131", f"no array `{ref}` in the matrices file", ctx, path,
                    hint=f"it holds: {', '.join(sorted(getattr(arrays, 'files', arrays))[:20]) or 'nothing'}")
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
    for key in spec.scale:  # the sparse blocks' values are computed once per parameter vector
        if refuse_time(b, ctx, name, scale[key], (*path, "scale", key), f"the scale of `{key}`",
                       "scales are parameters: a time-varying linear system is a `phs` (or a `modulation`)"):
            return
    if any(m is None for m in mats.values()):
        return
    J, R, Q, E = mats["J"], mats["R"], mats["Q"], mats["E"]
    tol = 1e-12 * max(1.0, abs(J).max(), abs(R).max(), abs(Q).max())
    if abs(J + J.T).max() > tol:
        b.error("PHC-E402", f"`J` of `{name}` is not skew-symmetric (max |J + Jᵀ| = {abs(J + J.T).max():.3g})",
                ctx, (*path, "J"))
    if abs(R - R.T).max() > tol or abs(Q - Q.T).max() > tol:
        b.error("PHC-E403", f"`R` and `Q` of `{name}` must be symmetric", ctx, path)
    EQ = (E.T @ Q).tocsr()
    if spec.E is not None and abs(EQ - EQ.T).max() > 1e-12 * max(1.0, abs(EQ).max()):
        b.error("PHC-E403", f"`Eᵀ Q` of `{name}` must be symmetric (max |EᵀQ − QᵀE| = "
                f"{abs(EQ - EQ.T).max():.3g}): the energy of E ẋ = (J − R) Q x is H = ½ xᵀEᵀQx", ctx,
                (*path, "E"))
    x, dx = zip(*(b.add_state(name, nm, span) for nm in names)) if n else ((), ())
    x, dx = tuple(x), tuple(dx)
    # The complete description, kept sparse (see the module docstring); the rows are derived
    # from it (phc.library.dirac.emit): e = ∂H/∂x = s_E Eᵀz, law z = s_Q Q x,
    # s_E E f − s_J J z + e_R + Σ B e_in − Σ B f_in = 0, f_R = z, e_R = s_R R f_R;
    # outputs f = Bᵀz (effort_in), e = −Bᵀz (flow_in).
    ds = DiracBuilder(name, "linear_phs", span)
    f_x, e_x = ds.storage_vector("x", x, dx, [LinearTerm(scale["E"] * scale["Q"], EQ, x)])
    z = ds.mults("z", n)  # the co-energy Qx
    eye = sps.identity(n, format="csr")
    ds.block("coenergy", n, [LinearTerm(sp.Integer(1), eye, e_x), LinearTerm(-scale["E"], E.T.tocsr(), z)])
    ds.block("constitutive", n, [LinearTerm(sp.Integer(1), eye, z), LinearTerm(-scale["Q"], Q, x)], law=True,
             solve=z)
    dyn_terms = [LinearTerm(scale["E"], E, f_x), LinearTerm(-scale["J"], J, z)]
    if R.nnz:
        f_r, e_r = ds.resistor_vector("R", n)
        ds.block("resistive.flow", n, [LinearTerm(sp.Integer(1), eye, f_r), LinearTerm(sp.Integer(-1), eye, z)],
                 solve=f_r)
        ds.block("resistive.law", n, [LinearTerm(sp.Integer(1), eye, e_r), LinearTerm(-scale["R"], R, f_r)],
                 law=True, solve=e_r)
        dyn_terms.append(LinearTerm(sp.Integer(1), eye, e_r))
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
        sign = 1 if pspec.causality == "effort_in" else -1
        d.port(port)
        ds.port(port)
        dim = pspec.dimension
        output, given = (port.f, port.e) if pspec.causality == "effort_in" else (port.e, port.f)
        ds.block(f"{pname}.output", dim, [LinearTerm(sp.Integer(1), sps.identity(dim, format="csr"), tuple(output)),
                                          LinearTerm(sp.Integer(-sign), B.T, z)], solve=tuple(output))
        dyn_terms.append(LinearTerm(sp.Integer(sign), B.tocsr(), tuple(given)))
        Bl = B.tocsc()
        for k in range(pspec.dimension):
            lo, hi = Bl.indptr[k], Bl.indptr[k + 1]
            proj = sum((float(v) * lam.setdefault(int(i), d.mult(f"ex[{int(i)}]"))
                        for i, v in zip(Bl.indices[lo:hi], Bl.data[lo:hi])), sp.Integer(0))
            d.rel(port.f[k] - proj if pspec.causality == "effort_in" else port.e[k] + proj)
    ds.block("dynamics", n, dyn_terms)
    structure = ds.describe()
    d.register(b, kind="port_projection", note="matrix component: J skew, R and Q symmetric checked; ports "
               "certified through im Bᵀ", structure=structure)
    emit(b, structure)
    b.quadratic_energy.append(QuadraticForm(scale["E"] * scale["Q"] / 2, ((EQ + EQ.T) / 2).tocsr(), x))
    if R.nnz:
        b.quadratic_dissipation.append(QuadraticForm(scale["R"] * scale["Q"] ** 2, (Q.T @ R @ Q).tocsr(), x,
                                                     component=name, span=span))
