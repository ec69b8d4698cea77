"""IDA's residual and Jacobian as compiled C callbacks, for models on the numba backend.

With the NumPy module, IDA calls the residual through phc's ``ctypes`` callback
(:meth:`phc.simulation.ida._IdaCounters.install_residual`): a Python call per evaluation,
about 2 µs on top of the function itself. On the numba backend the generated functions
are machine code already, and this module builds the two functions IDA calls as numba
``cfunc``\\ s around them, so that IDA's step loop runs without Python:

* the residual callback reads IDA's vectors (``N_Vector``: its content's data pointer),
  calls the compiled residual and checks the result for finite values;
* the Jacobian callback calls the compiled Jacobian into a buffer, checks it, and writes
  the entries into IDA's dense matrix (column-major) after zeroing it;
* both take their parameters, buffers and failure record from one float64 array, the
  *context*, which IDA passes as its user data.

A value that is not finite is a recoverable failure for IDA (it retries the step shorter,
as with the Python callback); the context records the time, state and rates of the last
one, from which :meth:`Native.error` produces the located error through the guard
(:mod:`phc.simulation.guard`) when IDA gives up. Ctrl-C is answered between chunks (at
most :data:`~phc.simulation.ida.CHUNK_STEPS` steps apart), where Python runs again.

The callbacks depend on the model (its compiled functions and sizes are compiled in),
so they are built once per model and process, in about 0.1–0.5 s: a run starts with the
Python callback and changes to these after
:data:`phc.simulation.ida.SWITCH_EVALUATIONS` residual evaluations, when what the Python calls cost has reached about what building them costs
(a short run never pays for it). ``PHC_IDA_NATIVE=0`` keeps the Python callback.

The layouts used — an ``N_Vector``'s and a dense ``SUNMatrix``'s content (its data
pointer after two integers), scikit-SUNDAE's solver object (the matrix after the state
vectors) — are checked against SUNDIALS' own accessors before a run uses them; where a
check fails, the run keeps the Python callback.
"""

from __future__ import annotations

import ctypes
import os
from typing import Optional

import numpy as np

# the context array: header, then p, the failing point's y and ẏ, the Jacobian buffer
_FAILED, _T, _KIND, _CJ, _COUNT = range(5)
_HEADER = 5

_SMAT_A = 80
"""Offset of the SUNMatrix in scikit-SUNDAE's ``_cy_ida.IDA`` object (after mem, ctx, atol,
algidx, constraints, yy, yp; see :class:`phc.simulation.ida._IdaCounters`)."""


def enabled() -> bool:
    return os.environ.get("PHC_IDA_NATIVE", "1").strip().lower() not in ("0", "no", "false", "off")


def _word_intrinsic():
    from llvmlite import ir
    from numba.core import types
    from numba.extending import intrinsic

    @intrinsic
    def word(typingctx, address, offset):
        """The pointer stored at ``address + offset`` (bytes)."""
        sig = types.voidptr(types.voidptr, types.intp)

        def codegen(context, builder, signature, args):
            base, off = args
            byte = ir.IntType(8).as_pointer()
            at = builder.gep(builder.bitcast(base, byte), [off])
            return builder.load(builder.bitcast(at, byte.as_pointer()))

        return sig, codegen

    return word


_WORD: list = []


def _build(raw, n: int, n_p: int, rows: np.ndarray, cols: np.ndarray, at: int):
    """(residual cfunc, Jacobian cfunc, context size) of `raw`'s compiled functions; `at`:
    the offset of the data pointer in an N_Vector's and a dense SUNMatrix's content (8 or
    16 bytes: after two 32- or 64-bit integers, as SUNDIALS was built)."""
    import numba
    from numba import carray, types

    if not _WORD:
        _WORD.append(_word_intrinsic())
    word = _WORD[0]
    residual, jacobian = raw.residual, raw.jacobian
    njac = len(rows)
    flat = (np.asarray(cols, dtype=np.int64) * n + np.asarray(rows, dtype=np.int64)).copy()  # column-major
    p0, y0 = _HEADER, _HEADER + n_p
    yp0 = y0 + n
    j0 = yp0 + n
    size = j0 + njac
    f64 = np.float64

    def record(ctx, kind, t, y, yp):
        ctx[_FAILED], ctx[_T], ctx[_KIND] = 1.0, t, kind
        ctx[_COUNT] += 1.0
        for i in range(n):
            ctx[y0 + i] = y[i]
            ctx[yp0 + i] = yp[i]

    record = numba.njit(error_model="numpy")(record)

    def res_c(t, yy, yp, rr, ud):
        ctx = carray(ud, (size,), f64)
        y = carray(word(word(yy, 0), at), (n,), f64)
        ydot = carray(word(word(yp, 0), at), (n,), f64)
        r = carray(word(word(rr, 0), at), (n,), f64)
        residual(t, y, ydot, ctx[p0:y0], r)
        for i in range(n):
            if not np.isfinite(r[i]):
                record(ctx, 1.0, t, y, ydot)
                return 1
        ctx[_FAILED] = 0.0
        return 0

    def jac_c(t, cj, yy, yp, rr, jj, ud, tmp1, tmp2, tmp3):
        ctx = carray(ud, (size,), f64)
        y = carray(word(word(yy, 0), at), (n,), f64)
        ydot = carray(word(word(yp, 0), at), (n,), f64)
        ctx[_CJ] = cj
        buf = ctx[j0:size]
        jacobian(t, y, ydot, ctx[p0:y0], cj, buf)
        for k in range(njac):
            if not np.isfinite(buf[k]):
                record(ctx, 2.0, t, y, ydot)
                return 1
        data = carray(word(word(jj, 0), at), (n * n,), f64)
        for k in range(n * n):
            data[k] = 0.0
        for k in range(njac):
            data[flat[k]] += buf[k]
        ctx[_FAILED] = 0.0
        return 0

    res_sig = types.intc(types.float64, types.voidptr, types.voidptr, types.voidptr, types.voidptr)
    jac_sig = types.intc(types.float64, types.float64, types.voidptr, types.voidptr, types.voidptr, types.voidptr,
                         types.voidptr, types.voidptr, types.voidptr, types.voidptr)
    res_cf = numba.cfunc(res_sig, error_model="numpy")(res_c)
    jac_cf = numba.cfunc(jac_sig, error_model="numpy")(jac_c)
    return res_cf, jac_cf, size


class Native:
    """The compiled callbacks of one model and the context array of one run."""

    def __init__(self, raw, p, rows, cols, at: int):
        n = int(raw.N)
        built = getattr(raw, "_phc_ida_native", None)
        key = (n, len(p), len(rows), at)
        if built is None or built[0] != key:
            built = (key, *_build(raw, n, len(p), np.asarray(rows), np.asarray(cols), at))
            try:
                raw._phc_ida_native = built
            except AttributeError:  # pragma: no cover - a module object always takes attributes
                pass
        _, self.residual, self.jacobian, size = built
        self.n, self.n_p = n, len(p)
        self.context = np.zeros(size)
        self.context[_HEADER:_HEADER + self.n_p] = np.asarray(p, dtype=float)

    @property
    def count(self) -> int:
        """Recoverable failures so far (a value that was not finite)."""
        return int(self.context[_COUNT])

    @property
    def time(self) -> float:
        return float(self.context[_T])

    @property
    def failed_last(self) -> bool:
        return self.context[_FAILED] != 0.0

    def clear_last(self) -> None:
        self.context[_FAILED] = 0.0

    @property
    def cj(self) -> float:
        return float(self.context[_CJ])

    def error(self, guarded, p):
        """The located error of the last failure (evaluated again through the guard)."""
        from phc.simulation.guard import ModelEvaluationError

        c, n = self.context, self.n
        y0 = _HEADER + self.n_p
        t, y, yp = float(c[_T]), c[y0:y0 + n].copy(), c[y0 + n:y0 + 2 * n].copy()
        kind = "jacobian" if c[_KIND] == 2.0 else "residual"
        if guarded is not None:
            try:
                if kind == "residual":
                    guarded.residual(t, y, yp, p, np.zeros(n))
                else:
                    guarded.jacobian(t, y, yp, p, float(c[_CJ]), np.zeros(len(guarded.JAC_ROWS)))
            except ModelEvaluationError as err:
                return err
        return ModelEvaluationError(f"the compiled {kind} is not finite at t = {t:.9g}", function=kind, t=t)


def data_offset(lib, solver_object_address: int, yy: int, n: int) -> Optional[int]:
    """The offset of the data pointer in the content of an N_Vector (the solver's `yy`) and
    of its dense SUNMatrix, the same in both (8 or 16 bytes: after two integers of
    SUNDIALS' index size), checked against SUNDIALS' own accessors — or None where the
    layouts are not these (then the compiled callbacks are not used)."""
    core = getattr(lib, "array", None)
    dense = _dense_library(core) if core is not None else None
    if core is None or dense is None or not yy or not solver_object_address:
        return None
    word = ctypes.c_void_p.from_address
    A = word(solver_object_address + _SMAT_A).value
    vector, matrix = word(yy).value, word(A).value if A else None
    if not vector or not matrix:
        return None
    a = ctypes.c_void_p(A)
    if dense.SUNMatGetID(a) != 0 or dense.SUNDenseMatrix_Rows(a) != n or dense.SUNDenseMatrix_Columns(a) != n \
            or dense.SUNDenseMatrix_LData(a) != n * n or core.N_VGetLength(ctypes.c_void_p(yy)) != n:
        return None  # not SUNMATRIX_DENSE (0) of this size
    data, matrix_data = core.N_VGetArrayPointer(ctypes.c_void_p(yy)), dense.SUNDenseMatrix_Data(a)
    for at in (8, 16):
        if data and word(vector + at).value == data and word(matrix + at).value == matrix_data:
            return at
    return None


_DENSE: list = []


def _dense_library(core):
    """SUNDIALS' dense-matrix library as loaded in this process, with ``SUNMatGetID`` of its
    core library `core` (``lib.array`` of :func:`phc.simulation.ida._ida_library`), or None."""
    if _DENSE:
        return _DENSE[0]
    lib = None
    try:
        from phc.simulation.ida import _first_library, _mapped

        lib, _ = _first_library(_mapped("libsundials_sunmatrixdense"), "SUNDenseMatrix_Data")
        if lib is not None:
            lib.SUNMatGetID = core.SUNMatGetID
            lib.SUNMatGetID.argtypes, lib.SUNMatGetID.restype = [ctypes.c_void_p], ctypes.c_int
            for name, rt in (("SUNDenseMatrix_Data", ctypes.c_void_p), ("SUNDenseMatrix_Rows", ctypes.c_int64),
                             ("SUNDenseMatrix_Columns", ctypes.c_int64), ("SUNDenseMatrix_LData", ctypes.c_int64)):
                fn = getattr(lib, name)
                fn.argtypes, fn.restype = [ctypes.c_void_p], rt
    except Exception:  # noqa: BLE001 - an optimization with a fallback
        lib = None
    _DENSE.append(lib)
    return lib
