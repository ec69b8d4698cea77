"""The fixed-step methods' step loops in C, for models on the C back end.

When a model runs on the ``c`` backend (:mod:`phc.codegen.c_backend`), has at most
:data:`~phc.simulation.compiled_steps.MAX_UNKNOWNS` unknowns and is integrated by a fixed-step
method (``midpoint``, ``discrete_gradient``, ``midpoint4``) without contacts, its
steps run in one C function, ``phc_steps_chunk`` of the step library, that
calls the model's compiled residual, Jacobian, position invariants, Hamiltonian, energy scale and
port powers through function pointers (no Python in between). The step logic the Python loop and
the numba kernel share is not written again in C: :func:`source` translates
:func:`phc.simulation.step_logic.newton` (the stopping rules, refresh of the Newton matrix,
round-off acceptance: one Newton iteration, which every method's stages call), the methods'
steps (:func:`~phc.simulation.step_logic.discrete_gradient`,
:func:`~phc.simulation.step_logic.midpoint4`), the driver's bookkeeping
(``step_logic.next_step``, ``predict`` with ``predictor_nodes``, ``lagrange_weights``,
``polynomial``, ``extrapolate``, ``looks`` and ``accept``) and the chunk loop
(:func:`~phc.simulation.step_logic.chunk`, which the numba kernel runs as well) with
:mod:`phc.codegen.c_translate`, writes the library's entry ``phc_steps_chunk`` from chunk's
parameters (:func:`entry`), and puts both into steps.c (when the library is built, and into an
exported FMU's sources). Written by hand in steps.c are the operations those call
(``_operations``: the matrix's age, refactor, correct, one stage, one step of the run's method,
the singularity monitor's routine look — a 1-norm condition estimate of the equilibrated
iteration matrix, as LAPACK's ``dgecon`` is in the numba kernel — and the watch of a run's
switching functions, ``op_watch``, which calls the model library's ``phc_events``), with a dense LU with partial
pivoting of the Newton matrix equilibrated as the Python loop's sparse LU is
(:func:`phc.simulation.midpoint.equilibration`); its header says what the numba loop does that
it does not (mixed-precision corrections: here every correction is in double precision) and
why LAPACK is not used.

The Python side is the numba loop's: :func:`phc.simulation.compiled_steps.integrate` runs
the chunks, reports progress and sees Ctrl-C between them, and does whatever the chunk hands
back (a failed or ill-conditioned step, a look of the singularity monitor) exactly as the
Python loop does. This module only builds the library (once per machine and phc version, in
phc's signed cache of compiled code, beside the models' libraries: :func:`library`), says
whether a run can use it (:func:`usable`) — once per reason, with a
:class:`~phc.errors.CompiledLoopWarning`, when it cannot — and binds a run's arrays to it
(:func:`bind`). The library keeps no state; every array is the run's, so threads may
integrate at once (ctypes releases the GIL during a chunk).
"""

from __future__ import annotations

import ctypes
import functools
import os
import threading
import warnings
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from phc.codegen import numba_steps_kernel as _k
from phc.simulation import step_logic as _sl

SOURCE = Path(__file__).resolve().parents[1] / "codegen" / "c_runtime" / "steps.c"
"""The hand-written part of the step loop's C text (shipped in the package); :func:`source` is
the whole text."""

TRANSLATED = ("substeps", "next_step", "predictor_nodes", "lagrange_weights", "polynomial", "extrapolate", "predict",
              "looks", "accept", "newton", "discrete_gradient", "passivity_floor", "midpoint4", "chunk")
"""The functions of :mod:`phc.simulation.step_logic` steps.c gets translated (each after those it
calls)."""

MARKER = "/* PHC_STEP_LOGIC */"
"""The line of steps.c the translation replaces."""

DENSE_LU = Path(__file__).resolve().parent / "c_runtime" / "dense_lu.c"
"""The dense LU and the singularity monitor's routine look, shared with the native IDA driver
(:mod:`phc.codegen.c_ida`); :func:`with_dense_lu` puts it at a source's :data:`DENSE_LU_MARKER` line."""

DENSE_LU_MARKER = "/* PHC_DENSE_LU */"


def with_dense_lu(text: str, name: str) -> str:
    """`text` (the C source `name`) with dense_lu.c in place of its :data:`DENSE_LU_MARKER` line."""
    if text.count(DENSE_LU_MARKER) != 1:
        raise RuntimeError(f"{name} must have the line {DENSE_LU_MARKER} once (a phc bug: please report it)")
    return text.replace(DENSE_LU_MARKER, DENSE_LU.read_text(encoding="utf-8").rstrip("\n"))


def _operations() -> dict:
    from phc.codegen.c_translate import Op

    return {"_begin": Op("op_begin", ("ws", "i"), ("b", "f", "f", "i")),
            "_refactor": Op("op_refactor", ("ws", "i", "f", "f", "v", "v", "f"), ("i",)),
            "_correct": Op("op_correct", ("ws", "i", "f", "f", "v", "v", "f"), ("i", "v", "f", "f", "f", "b", "b")),
            "_precision": Op("op_precision", ("ws", "i"), ()),
            "_consistent": Op("op_consistent", ("ws", "f", "v"), (), writes=(2,)),
            "_stage": Op("op_stage", ("ws", "i", "f", "f", "v", "v", "f", "v"), ("i", "b"), writes=(7,)),
            # the chunk's: one step of the run's method; the monitor's routine look (steps.c's
            # condition estimate of the equilibrated iteration matrix, LAPACK's dgecon on its own LU)
            "_advance": Op("op_advance", ("ws", "f", "f", "v", "v", "v"), ("i", "b"), writes=(5,)),
            "_far_from_singular": Op("op_far_from_singular", ("ws", "f", "v", "v", "f"), ("b",)),
            # the switching functions of a run with events at the step's end (steps.c: the model's phc_events)
            "_watch": Op("op_watch", ("ws", "f", "f", "v", "v"), ("b",))}


_ROWS = {"ys": "nout", "yps": "nout", "pm": "npred"}
"""The row counts (fields of ``struct phc_steps``) of the matrices :func:`phc.simulation.step_logic.chunk` takes."""


def entry() -> str:
    """C text of the library's entry ``phc_steps_chunk(w, budget)``: the translated
    :func:`phc.simulation.step_logic.chunk` on the run's struct. Its parameters are named as the
    struct's fields (``ws`` is the struct, ``budget`` the caller's), so the call is written from
    its parameter list, not by hand."""
    import inspect

    kinds, _ = _sl.C_SIGNATURES["chunk"]
    args = ["w->n"]
    for name, kind in zip(inspect.signature(_sl.chunk).parameters, kinds):
        if kind == "ws":
            args.append("w")
        elif name == "budget":
            args.append("budget")
        elif kind == "V":
            args.append(f"w->{name}, w->{_ROWS[name]}")
        else:
            args.append(f"w->{name}")
    call = ", ".join(args)
    return ("/* Steps of integrate_fixed_step until `budget` steps are done, the run ends, or a step needs the\n"
            " * Python code; the state is in the arrays, the status in ist[I_STATUS] (phc.simulation.step_logic.chunk,\n"
            " * translated; this call is written by phc.codegen.c_steps.entry from chunk's parameters). */\n"
            "void phc_steps_chunk(const struct phc_steps *w, int64_t budget)\n{\n"
            f"    chunk({call});\n}}\n")


_SOURCE_TEXT: Optional[str] = None


def translation() -> str:
    """C text of the :data:`TRANSLATED` functions of :mod:`phc.simulation.step_logic`."""
    from phc.codegen.c_translate import PRELUDE, Translator

    body = Translator(_sl, _sl.C_SIGNATURES, _operations()).translate(TRANSLATED)
    return PRELUDE + "\n" + body + "\n" + entry()


def make_source() -> str:
    """The step loop's whole C text, translated anew (:func:`source` keeps it)."""
    text = SOURCE.read_text(encoding="utf-8")
    if text.count(MARKER) != 1:
        raise RuntimeError(f"{SOURCE} must have the line {MARKER} once (a phc bug: please report it)")
    return with_dense_lu(text.replace(MARKER, translation().rstrip("\n")), SOURCE.name)


def source() -> str:
    """The step loop's whole C text: steps.c with :func:`translation` in place of its
    :data:`MARKER` line (self-contained: the FMU export ships it as its ``steps.c``); once per
    process, and kept in the signed cache keyed by the files it is made from (the layout's
    constants are numba_steps_kernel's: :func:`phc.codegen.c_backend.translated_text`)."""
    global _SOURCE_TEXT
    if _SOURCE_TEXT is None:
        from phc.codegen import c_backend
        from phc.codegen.c_ida import TRANSLATOR

        _SOURCE_TEXT = c_backend.translated_text(
            "steps", (SOURCE, DENSE_LU, __file__, _sl.__file__, _k.__file__, TRANSLATOR), make_source)
    return _SOURCE_TEXT

FLAGS = ("-std=c99", "-O3", "-fPIC", "-shared", "-ffp-contract=off")
"""The model libraries' flags (:data:`phc.codegen.c_backend.FLAGS`) with ``-O3``: the
compiler vectorizes the LU's column loops, which reorders no sum; no fused multiply-adds, no
``-ffast-math``, no ``-march`` (the cached library must run on any x86-64 CPU)."""

METHODS = ("midpoint", "discrete_gradient", "midpoint4")
"""The fixed-step methods whose step loop is written in C (the others run the Python loop)."""

ABI = 5
"""``PHC_STEPS_ABI`` of the steps.c this module binds (the layout of ``struct phc_steps`` and of
the constants vector: ABI 5 added ``C_RUN_ENERGY``, midpoint4's passivity floor)."""

MAX_NODES = 16
"""Predictor nodes the C file has room for (its ``MAX_NODES``)."""

_LOCK = threading.Lock()
_LIBRARY = None
"""The loaded library once built; False when it cannot be built here (:data:`_WHY` says why)."""
_WHY = ""
_SAID: set = set()


def _layout() -> list[int]:
    """What ``phc_steps_layout`` must write: the indices the Python driver uses (without the
    struct size, which :func:`library` compares with :class:`_Steps`)."""
    return [ABI, _k._NI, _k._NF, _sl._NC,
            _k._K, _k._J, _k._SUBSTEPS, _k._STEPS, _k._LAST_LOOK, _k._HAS_MID, _k._MAX_STEPS, _k._STATUS, _k._NFEV,
            _k._NFACT, _k._HIST, _k._MONITOR, _k._METHOD, _k._CODE, _k._ILL, _k._E, _k._NEND, _k._NMID, _k._LOWP,
            _k._STRIKES,
            _k._T, _k._H, _k._H_PREV, _k._STEP,
            _sl._TOL, _sl._RATE, _sl._FLOOR, _sl._MAX_AGE, _sl._MAX_NEWTON, _sl._THRESHOLD, _sl._EVERY, _sl._ORDER,
            _sl._ZONE, _sl._STAGNATION, _sl._ORDER_ALG, _sl._BAL_TOL, _sl._MAX_SECANT, _sl._S_MIN, _sl._S_MAX, _sl._G1,
            _sl._G2, _sl._M0, _sl._M1, _sl._M2, _sl._RUN_ENERGY,
            _k._BUDGET, _k._DONE, _k._HARD, _k._LOOK, _k._MAXSTEPS, _sl._EVENT, _sl._OK, _sl._FAIL, _sl._SINGULAR,
            _sl._EVAL, _sl._PASSIVITY,
            MAX_NODES]


_P = ctypes.c_void_p
_I = ctypes.c_int64


class _Steps(ctypes.Structure):
    """``struct phc_steps`` of steps.c, field by field (pointers as addresses)."""

    _fields_ = [(name, _I) for name in ("n", "njac", "nend", "nout", "npred")] + [
        (name, _P) for name in (
            "residual", "jacobian", "invariants", "p", "jrows", "jcols", "end_rows", "emask", "algmask", "weights",
            "colscale", "c", "t_out",
            "ys", "yps", "y", "mid", "mid_slope", "y_prev", "y_new", "pt", "pm", "fst", "ist",
            "lu", "piv", "perm", "eq", "matf",
            "xs", "d", "r", "guess", "yp", "g", "jbuf", "ebuf", "mon", "monpiv", "monv",
            "hamiltonian", "energy_scale", "powers", "hist_t", "hist_v", "sub", "start", "y1in", "y_half", "y_best",
            "y_sec", "events")] + [(name, _I) for name in ("nwatch", "nev")] + [
        (name, _P) for name in ("wmap", "wprev", "wnew", "vbuf", "slope")]


def library():
    """The step loop's library (compiled, or loaded from phc's signed cache, once per process),
    or None when it cannot be built here (:func:`why_not`)."""
    global _LIBRARY, _WHY
    with _LOCK:
        if _LIBRARY is None:
            try:
                _LIBRARY = _build()
            except Exception as err:  # noqa: BLE001 — the Python loop runs instead, and says why once
                _LIBRARY, _WHY = False, f"{type(err).__name__}: {err}"
        return _LIBRARY or None


def _build():
    global _WHY
    from phc.codegen import c_backend

    lib, why = c_backend.runtime_library(source(), FLAGS)
    if lib is None:
        _WHY = why
        return False
    expected = _layout()
    out = (ctypes.c_int64 * (len(expected) + 1))()
    lib.phc_steps_layout.argtypes, lib.phc_steps_layout.restype = [ctypes.c_void_p], None
    lib.phc_steps_layout(ctypes.addressof(out))
    found = list(out)
    if found[:-1] != expected or found[-1] != ctypes.sizeof(_Steps):
        _WHY = "steps.c was written for another layout of the step loop's state (a phc bug: please report it)"
        return False
    lib.phc_steps_chunk.argtypes, lib.phc_steps_chunk.restype = [ctypes.POINTER(_Steps), ctypes.c_int64], None
    lib.phc_steps_along.argtypes = [_P] * 6 + [_I] * 2 + [_P] * 4 + [_I] * 3 + [_P] * 6
    lib.phc_steps_along.restype = None
    return lib


def why_not() -> str:
    """Why the library could not be built in this process ("" when it was, or was not tried)."""
    return _WHY


def usable(method: str, raw) -> tuple[bool, str]:
    """Whether a fixed-step run of `method` on the C module `raw` uses the C step loop, and if
    not, why (an empty reason: switched off by ``PHC_COMPILED_LOOP=0``, nothing to say)."""
    from phc.simulation.compiled_steps import MAX_UNKNOWNS

    if os.environ.get("PHC_COMPILED_LOOP", "1").strip().lower() in ("0", "no", "false", "off"):
        return False, ""
    if method not in METHODS:
        return False, f"the `{method}` solver's step loop is not written in C"
    if raw.N > MAX_UNKNOWNS:
        return False, f"the model has {raw.N} unknowns, more than the {MAX_UNKNOWNS} its dense LU is meant for"
    if getattr(raw, "C_LIBRARY", None) is None:
        return False, "the model's C library is not loaded"
    if library() is None:
        return False, f"its library could not be built ({_WHY})"
    return True, ""


def say_unused(why: str) -> None:
    """Say once per process and reason that the C step loop does not run a simulation."""
    from phc.errors import CompiledLoopWarning, caller_stacklevel

    if not why or why in _SAID:
        return
    _SAID.add(why)
    warnings.warn(f"the C step loop does not run this simulation: {why}; the Python step loop runs it (the same "
                  "steps, more time per step)", CompiledLoopWarning, stacklevel=caller_stacklevel())


def _address(a: Optional[np.ndarray]) -> Optional[int]:
    return None if a is None or not a.size else a.ctypes.data


def bind(raw, p, t_out, ys, yps, y, mid, mid_slope, y_prev, y_new, pt, pm, fst, ist, c, jrows, jcols, end_rows,
         emask, weights, algmask, colscale, hist_t, hist_v, wmap=None, wprev=None, wnew=None,
         vbuf=None) -> Callable[[int], None]:
    """``chunk(budget)``: a chunk of steps of the C loop on the driver's arrays (all C-contiguous,
    float64 but the int64 index arrays and int8 masks; kept alive by the closure) with scratch
    arrays of its own. A run with switching conditions passes the watched functions' map `wmap`
    (3 × m, :func:`phc.simulation.compiled_steps.watch_map`), their values `wprev` at the current
    step's start and `wnew` (m each) and `vbuf` (the model's ``events`` values): the loop calls
    the model's ``phc_events`` after each step (steps.c's ``op_watch``)."""
    lib = library()
    n, njac, nend = int(raw.N), len(jrows), len(end_rows)
    if pm.shape[0] > MAX_NODES:
        raise ValueError(f"the C step loop keeps at most {MAX_NODES} predictor nodes, got {pm.shape[0]}")
    arrays = dict(
        p=p, jrows=jrows, jcols=jcols, end_rows=end_rows, emask=emask, algmask=algmask,
        weights=weights if weights.shape == (n,) else None, colscale=colscale if colscale.shape == (n,) else None,
        c=c, t_out=t_out, ys=ys, yps=yps, y=y, mid=mid, mid_slope=mid_slope, y_prev=y_prev, y_new=y_new, pt=pt,
        pm=pm, fst=fst, ist=ist,
        lu=np.zeros((2, n, n)), piv=np.zeros((2, n), np.int64), perm=np.zeros((2, n), np.int64),
        eq=np.ones((2, 2 * n)), matf=np.zeros((2, 3)),
        xs=np.zeros(n), d=np.zeros(n), r=np.zeros(n), guess=np.zeros(n), yp=np.zeros(n), g=np.zeros(max(nend, 1)),
        jbuf=np.zeros(njac), ebuf=np.zeros(njac), mon=np.zeros((n, n)), monpiv=np.zeros(n, np.int64),
        monv=np.zeros(3 * n), hist_t=hist_t, hist_v=hist_v, sub=np.zeros((3, n)), start=np.zeros(n),
        y1in=np.zeros(n), y_half=np.zeros(n), y_best=np.zeros(n), y_sec=np.zeros(n))
    nwatch = 0 if wmap is None else wmap.shape[1]
    if nwatch:
        if wmap.shape != (3, nwatch) or wprev.shape != (nwatch,) or wnew.shape != (nwatch,):
            raise ValueError(f"the watched functions' map must be 3 x {nwatch} and their values {nwatch} each")
        arrays.update(wmap=wmap, wprev=wprev, wnew=wnew, vbuf=vbuf, slope=np.zeros(n))
    kinds = {"jrows": np.int64, "jcols": np.int64, "end_rows": np.int64, "piv": np.int64, "perm": np.int64,
             "monpiv": np.int64,
             "ist": np.int64, "emask": np.int8, "algmask": np.int8}
    for name, a in arrays.items():
        if a is None:
            continue
        if a.dtype != kinds.get(name, np.float64) or not a.flags.c_contiguous:
            raise ValueError(f"`{name}` must be a C-contiguous {np.dtype(kinds.get(name, np.float64))} array")
    lib_model = raw.C_LIBRARY
    run = _Steps(n=n, njac=njac, nend=nend, nout=len(t_out), npred=pm.shape[0],
                 residual=ctypes.cast(lib_model.phc_residual, _P).value,
                 jacobian=ctypes.cast(lib_model.phc_jacobian, _P).value,
                 invariants=ctypes.cast(lib_model.phc_invariants, _P).value,
                 hamiltonian=ctypes.cast(lib_model.phc_hamiltonian, _P).value,
                 energy_scale=ctypes.cast(lib_model.phc_energy_scale, _P).value,
                 powers=ctypes.cast(lib_model.phc_powers, _P).value,
                 events=ctypes.cast(lib_model.phc_events, _P).value if nwatch else None,
                 nwatch=nwatch, nev=len(vbuf) if nwatch else 0,
                 **{name: _address(a) for name, a in arrays.items()})
    pointer = ctypes.byref(run)
    chunk_c = lib.phc_steps_chunk

    def chunk(budget: int) -> None:
        chunk_c(pointer, int(budget))

    chunk.keep = (arrays, run, lib_model)  # the arrays and the model's library live as long as the run
    return chunk


def midpoint_steps(raw, p, t_out, y0, yp0) -> tuple[int, np.ndarray]:
    """Implicit-midpoint steps of the C loop, one per interval of the grid `t_out` from the
    consistent start (`y0`, `yp0`) of the C module `raw`, with the Newton test relative to
    |y| + 1 and the singularity monitor off: what the nominal-scales probe
    (:func:`phc.simulation.scaling._probe`) runs, :class:`~phc.simulation.midpoint.StageSolver`'s
    stage solved by the same Newton iteration (``step_logic.newton``). Returns ``(k, ys)``: the
    first `k` rows of `ys` are the solution at ``t_out[:k]``; the loop stops at the first step it
    hands back (a failed or ill-conditioned step: the Python stage solver may retry it), and
    ``k = 1`` where the loop does not run (:func:`usable`: switched off, not built)."""
    from phc.simulation import midpoint as mp
    from phc.simulation.compiled_steps import METHODS as CODES, algebraic_mask, step_constants

    n = int(raw.N)
    t_out = np.ascontiguousarray(t_out, dtype=float)
    nout = len(t_out)
    ys, yps = np.zeros((nout, n)), np.zeros((nout, n))
    ys[0], yps[0] = y0, yp0
    if not usable("midpoint", raw)[0]:
        return 1, ys
    y = np.array(y0, dtype=float)
    mid, mid_slope, y_prev, y_new = np.zeros(n), np.array(yp0, dtype=float), np.zeros(n), np.zeros(n)
    end_rows = np.ascontiguousarray(mp.constraint_rows(raw), dtype=np.int64)
    jrows = np.ascontiguousarray(raw.JAC_ROWS, dtype=np.int64)
    jcols = np.ascontiguousarray(raw.JAC_COLS, dtype=np.int64)
    ist = np.zeros(_k._NI + 2, dtype=np.int64)
    ist[_k._K], ist[_k._LAST_LOOK], ist[_k._MAX_STEPS] = 1, -mp.MONITOR_EVERY, nout
    ist[_k._MONITOR], ist[_k._METHOD], ist[_k._NEND] = 0, CODES["midpoint"], len(end_rows)
    names = list(raw.VARIABLES)
    ist[_k._E] = names.index("energy.supplied") if "energy.supplied" in names else 0
    fst = np.zeros(_k._NF)
    fst[_k._STEP], fst[_k._H_PREV] = 0.0, 1.0  # (no step size: one step per output interval)
    pt, pm = np.zeros(mp.MAX_PREDICTOR_ORDER + 1), np.zeros((mp.MAX_PREDICTOR_ORDER + 1, n))
    run = bind(raw, np.ascontiguousarray(p, dtype=float), t_out, ys, yps, y, mid, mid_slope, y_prev, y_new, pt, pm,
               fst, ist, step_constants("midpoint"), jrows, jcols, end_rows, np.isin(jrows, end_rows).astype(np.int8),
               np.zeros(0), algebraic_mask(raw), np.zeros(0), np.zeros((2, 3)), np.zeros((2, 3, n)))
    run(nout)
    return int(ist[_k._K]), ys


_ALONG = ("hamiltonian", "energy_scale", "powers", "invariants", "velocity_invariants", "outputs")
"""The model's functions ``phc_steps_along`` calls at each point (in its order)."""


def along(raw, p, t, y, yp, only_h: bool = False) -> Optional[dict]:
    """H, the energy scale, the port powers, the invariants, the velocity invariants and the
    outputs of the C module `raw` at the points (``t[i]``, ``y[i]``, ``yp[i]``), in one call of
    the step library's ``phc_steps_along`` (the model's own C functions, the values to the bit
    of one call per point and function): a dict of arrays with the keys of
    ``phc.simulation._evaluate_along``'s rows, not checked for finite values; None where the
    library or the model's library is not at hand. `only_h`: ``{"H": ...}`` alone (`yp` is not
    read)."""
    if getattr(raw, "BACKEND", "") != "c" or getattr(raw, "C_LIBRARY", None) is None or library() is None:
        return None
    n, npts = int(raw.N), len(t)
    sizes = (1, 1, 2, len(raw.INVARIANTS), len(getattr(raw, "VELOCITY_INVARIANTS", ())), len(raw.OUTPUTS))
    t = np.ascontiguousarray(t, dtype=float)
    y = np.ascontiguousarray(y, dtype=float).reshape(npts, n)
    yp = y if only_h else np.ascontiguousarray(yp, dtype=float).reshape(npts, n)
    pv = np.ascontiguousarray(p, dtype=float)
    keys = ("H",) if only_h else ("H", "scale", "powers", "inv", "vinv", "outs")
    rows = {key: np.zeros((npts, size) if key in ("powers", "inv", "vinv", "outs") else npts)
            for key, size in zip(keys, sizes)}
    fns = _addresses(raw.C_LIBRARY)
    library().phc_steps_along(*(fns[:1] + (None,) * 5 if only_h else fns), n, npts,
                              *[a.ctypes.data if a.size else None for a in (t, y, yp, pv)], *sizes[3:],
                              *[rows[key].ctypes.data if key in rows and rows[key].size else None
                                for key in ("H", "scale", "powers", "inv", "vinv", "outs")])
    return rows


def probe_values(raw, p, t0, h, y0, ys) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """(``|P_ports| + |P_diss|`` at each step's midpoint, the energy scale at its end) of the
    nominal-scales probe's steps this loop took (:func:`midpoint_steps`; `ys`: the states after
    them, from `y0`, steps `h` from `t0`), at the points and summed as
    :func:`phc.simulation.scaling._probe` evaluates them one by one: one :func:`along` call,
    values that are not finite as they are (the probe's guarded calls decide there); None where
    the library is not at hand."""
    k = len(ys)
    if not k:
        return None
    t = [t0]
    for _ in range(k):  # (the times as the probe adds them up)
        t.append(t[-1] + h)
    t = np.array(t)
    before = np.vstack([np.asarray(y0, dtype=float)[None, :], ys[:-1]])
    slope = (ys - before) / h
    rows = along(raw, p, np.concatenate([t[:-1] + 0.5 * h, t[1:]]), np.vstack([0.5 * (before + ys), ys]),
                 np.vstack([slope, slope]))
    if rows is None:
        return None
    with np.errstate(all="ignore"):
        return np.abs(rows["powers"][:k]).sum(axis=1), rows["scale"][k:]


@functools.lru_cache(maxsize=64)
def _addresses(model) -> tuple:
    """The addresses of the model library's functions :data:`_ALONG` (a loaded library lives as
    long as the process: :mod:`phc.codegen.c_backend` keeps it)."""
    return tuple(ctypes.cast(getattr(model, f"phc_{name}"), _P).value for name in _ALONG)


def watches(raw) -> bool:
    """Whether the C module `raw`'s library has the switching functions the loop watches
    (``phc_events``: printed by :mod:`phc.codegen.c_printer` since the step library's ABI 4)."""
    lib = getattr(raw, "C_LIBRARY", None)
    return lib is not None and hasattr(lib, "phc_events")


__all__ = ["ABI", "DENSE_LU", "DENSE_LU_MARKER", "FLAGS", "MARKER", "METHODS", "SOURCE", "TRANSLATED", "bind", "along", "library", "make_source", "midpoint_steps", "probe_values", "say_unused", "source", "translation", "usable", "watches", "why_not", "with_dense_lu"]
