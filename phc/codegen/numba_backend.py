"""The compiled backend: the generated functions as machine code (numba), optional.

Input: a :class:`~phc.codegen.lower.ResidualIR` and the NumPy module printed from it (the
reference backend: :mod:`phc.codegen.printer`, loaded by :mod:`phc.codegen.load`). Output:
a module with the reference module's constants and ``full_parameters``, and ``residual``,
``residual_t``, ``jacobian``, ``hamiltonian``, ``energy_scale``, ``powers``,
``invariants``, ``velocity_invariants`` and ``outputs`` as numba-compiled functions of
the same signatures (``REFERENCE`` is the NumPy module, ``BACKEND`` is ``"numba"``).

How the functions are built
---------------------------
:class:`KernelPrinter` (a subclass of the reference printer: the same names and literals)
prints each function as numba-compilable Python, differing from the reference where
NumPy idioms do not compile: the sparse linear blocks and quadratic forms become loops
over constant CSR arrays (coefficients evaluated in the call), input tables carry an
``int`` kind, array sizes are checked on entry (the compiled code does not check bounds).

The scalar expressions — the bulk of a model — do not go through numba's Python-level
compiler, whose time grows steeply with the number of statements (seconds for a Jacobian
of a few hundred entries). They become one numba *intrinsic* per function, whose LLVM IR
:class:`~phc.codegen.numba_emit._Emitter` writes straight from the sympy expressions, after the same
common-subexpression elimination and in the evaluation order of the printed Python (terms
and factors as the printer orders them, ``a*b/(c*d)`` as printed, the same ``math``
functions): the compiled values agree with the reference module to the last bit in
most entries and to round-off in all. An expression the emitter does not know (a
function it has no rule for) leaves that function to numba's own compiler, as text.

Caching
-------
Compiled functions are cached in ``<phc cache>/numba/`` (the private directory of
:mod:`phc.codegen.load`: created 0700, refused when another user owns it or others may
write it, it or a directory on the way to it), under names derived from the SHA-256 of everything that determines the code
(the kernel text, the reference module's text, the phc, numba and Python versions); numba
adds the CPU to its key. Numba's own ``cache=True`` is not used: it writes next to the
source file and unpickles whatever its index points to. Here every artefact is written
with an HMAC-SHA256 tag over its file name and content under a per-user secret key kept
*outside* the cache directory (``$PHC_STATE_DIR``, else ``$XDG_STATE_HOME/phc``, else
``~/.local/state/phc``; file ``cache-key``, mode 0600), and an artefact whose tag does not
verify (damaged, or a signed file copied or renamed over another function's name) is
never unpickled — it is compiled again and overwritten, with one
:class:`~phc.errors.CacheWarning`. Functions from the cache that still disagree with the
reference module at the sample point (two writers racing) are compiled again without the
cache, with one warning too: a cache problem, not a phc bug. A cache directory restored
from elsewhere (the CI cache of another build) therefore costs a compilation, never the
execution of someone else's machine code. Set ``PHC_COMPILED_CACHE=0`` to compile in
memory every time.

What a run needs once the functions are built (whether numba is usable, the signed cache,
the module assembled over the reference) is in :mod:`phc.codegen.numba_cache`, which
imports neither sympy nor the model language: the cached front end of ``phc simulate``
loads a model's compiled functions from the cache through it, from the kernel text this
module keeps as the compiled module's ``KERNEL``.

Where what lives: this module prints the kernel text (:class:`KernelPrinter`,
:func:`kernel_source`) and builds and loads the compiled module (:func:`load_compiled`,
making each intrinsic in ``_make_intrinsic``). The LLVM IR emitter — which expressions it
can write (:func:`~phc.codegen.numba_emit.emittable`), what an intrinsic computes
(:class:`~phc.codegen.kernels.Kernel`, shared with the C back end) and the IR of its body
(:func:`~phc.codegen.numba_emit._emit_kernel`) — is :mod:`phc.codegen.numba_emit`; its
names are importable from here as well, and this module calls ``emittable`` and
``_emit_kernel`` through its own names for them.
"""

from __future__ import annotations

import os
import sys
import time
import warnings
from pathlib import Path
from types import ModuleType
from typing import Optional

import sympy as sp

from phc.codegen import numba_cache
from phc.codegen.lower import ResidualIR
# the public names of the compiled backend's light half, re-exported: callers and tests import them from here
from phc.codegen.numba_cache import (EMITTER_VERSION, FUNCTIONS, NUMBA_MIN,  # noqa: F401 — the API
                                     BackendMismatch, BackendUnavailable, CompiledBackendWarning, CompileReport,
                                     _cache_classes, _cross_check, _private_dir, _remember, assemble, available,
                                     cache_key, compile_functions, compiled_cache_dir, kernel_digest, kernel_module,
                                     signed_cache_dir,
                                     why_unavailable)
# the LLVM IR emitter (phc.codegen.numba_emit), its names importable from here as before
from phc.codegen.kernels import function_kernels
from phc.codegen.numba_emit import (_COEFFICIENT, _NODES, _RELATIONS, _SIMPLE, Kernel,  # noqa: F401
                                    _canonical, _coefficient, _Emitter, _emit_kernel, _is_switch, emittable)
from phc.codegen import packing
from phc.codegen.printer import ModulePrinter, _array
from phc.ir.dae import STORED_ENERGY, T

_KIND = {"linear": 0, "previous": 1}


# ---------------------------------------------------------------------------------------
# the kernel text

_HELPERS = '''
def _csr_add(indptr, indices, data, rows, cols, v, c, out):
    """out[rows] += c * (A @ v[cols]) for a constant CSR matrix A."""
    for i in range(indptr.shape[0] - 1):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += data[k] * v[cols[indices[k]]]
        out[rows[i]] += c * acc


def _scatter_add(pos, data, c, out):
    """out[pos] += c * data (the Jacobian entries of a linear term)."""
    for k in range(pos.shape[0]):
        out[pos[k]] += c * data[k]


def _csr_quad(indptr, indices, data, cols, y):
    """x @ A @ x with x = y[cols]."""
    total = 0.0
    for i in range(indptr.shape[0] - 1):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += data[k] * y[cols[indices[k]]]
        total += y[cols[i]] * acc
    return total


def _csr_grad_add(indptr, indices, data, cols, y, c, pos, out):
    """out[pos] += c * (A @ x) with x = y[cols]."""
    for i in range(indptr.shape[0] - 1):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += data[k] * y[cols[indices[k]]]
        out[pos[i]] += c * acc


def _table(times, values, kind, t):
    """Value of an input table at t: linear (kind 0) or zero-order hold (1); end values hold outside."""
    if kind == 1:
        return float(values[max(int(np.searchsorted(times, t, side="right")) - 1, 0)])
    return float(np.interp(t, times, values))


def _table_slope(times, values, kind, t):
    """d/dt of the table's interpolant (0 for a zero-order hold and outside the table)."""
    if kind == 1 or t < times[0] or t >= times[-1]:
        return 0.0
    i = int(np.searchsorted(times, t, side="right")) - 1
    return float((values[i + 1] - values[i]) / (times[i + 1] - times[i]))
'''


class KernelPrinter(ModulePrinter):
    """The generated functions as numba-compilable Python (see the module docstring).

    After :meth:`print`, ``kernels[name]`` is the :class:`Kernel` of the intrinsic
    ``_X_<name>`` the text calls (absent when an expression of the function has no
    emitter rule: then the function is printed as Python for numba's own compiler)."""

    bulk_unpack = False  # numba compiles ``y[j]``, not ``y.tolist()``

    def __init__(self, ir: ResidualIR):
        super().__init__(ir)
        self.kernels: dict[str, Kernel] = {}
        self.trivial: set[str] = set()
        """Functions with nothing to compute (the reference module's are used)."""
        self.known = set(ir.y_symbols) | set(ir.yp_symbols) | set(ir.p_symbols) | {T, sp.Symbol("cj"), STORED_ENERGY}
        self.names[STORED_ENERGY] = "_H"  # an output that uses H (the Python text of a function not emitted)
        self.n_parameters = len(ir.p_symbols)
        self._text_constants: list[str] = []

    # -- pieces ---------------------------------------------------------------------------
    def _csr_constants(self, name: str, matrix, **extra) -> None:
        """Module constants of a CSR matrix (for the Python text of a function that is not emitted)."""
        if any(line.startswith(f"{name}_INDPTR ") for line in self._text_constants):
            return
        m = _canonical(matrix)
        self._text_constants += [f"{name}_INDPTR = {_array(m.indptr.tolist(), 'np.int64')}",
                                 f"{name}_INDICES = {_array(m.indices.tolist(), 'np.int64')}",
                                 f"{name}_DATA = {_array(m.data.tolist(), 'float')}"]
        for key, values in extra.items():
            self._text_constants.append(f"{name}_{key} = {_array(list(values), 'np.int64')}")

    @staticmethod
    def _csr_args(name: str) -> str:
        return f"{name}_INDPTR, {name}_INDICES, {name}_DATA"

    def _size_check(self, name: str, arrays: list[tuple[str, str]]) -> list[str]:
        cond = " or ".join(f"{a}.shape[0] < {n}" for a, n in arrays)
        return [f"if {cond}:", f"    raise ValueError(\"{name}: an array is shorter than the model needs\")"]

    def _sum_text(self, op, out: str, c: str) -> list[str]:
        """Python text of a Kernel sum whose coefficient is the local `c` (for a function
        that is not emitted)."""
        kind = op[0]
        ident = f"_S{len(self._text_constants)}"
        if kind == "matvec":
            _, A, rows, cols, vec, _ = op
            self._csr_constants(ident, A, ROWS=rows.tolist(), COLS=cols.tolist())
            return [f"_csr_add({self._csr_args(ident)}, {ident}_ROWS, {ident}_COLS, {vec}, float({c}), {out})"]
        if kind == "scatter":
            _, pos, data, _, times_cj = op
            self._text_constants += [f"{ident}_POS = {_array(list(pos), 'np.int64')}",
                                     f"{ident}_DATA = {_array(list(data), 'float')}"]
            return [f"_scatter_add({ident}_POS, {ident}_DATA, {'cj * ' if times_cj else ''}float({c}), {out})"]
        if kind == "quad":
            _, A, cols, _, index, absolute = op
            self._csr_constants(ident, A, COLS=cols.tolist())
            value = f"{c} * _csr_quad({self._csr_args(ident)}, {ident}_COLS, y)"
            return [f"{out}[{index}] += {'abs(' + value + ')' if absolute else value}"]
        _, A, cols, pos, _ = op
        self._csr_constants(ident, A, COLS=cols.tolist(), POS=pos.tolist())
        return [f"_csr_grad_add({self._csr_args(ident)}, {ident}_COLS, y, float({c}), {ident}_POS, {out})"]

    def _function(self, name: str, signature: str, arrays, kernel: Kernel, out: str, *, zero=False, scratch=None,
                  tail=()) -> str:
        """A function computing `kernel` into `out` (zeroed first when `zero`; a new array of
        `scratch` entries when given), then `tail`."""
        targets = tuple((i, e, acc) for i, e, acc in kernel.targets if not (e == 0 and acc))
        kernel = Kernel(targets, kernel.sums, kernel.energy)
        expressions = kernel.expressions() + (kernel.energy.expressions() if kernel.energy is not None else [])
        if not targets and not kernel.sums:
            self.trivial.add(name)
        lines = self._size_check(name, arrays)
        if scratch is not None:
            lines.append(f"{out} = np.{'zeros' if zero else 'empty'}({scratch})")
        elif zero:
            lines.append(f"{out}[:] = 0.0")
        if all(emittable(e, self.known) for e in expressions):
            if targets or kernel.sums:
                self.kernels[name] = kernel
                yp = "yp" if "yp" in signature else "y"
                cj = "cj" if "cj" in signature else "0.0"
                lines.append(f"_X_{name}(t, y, {yp}, p, {cj}, {out})")
        else:
            if kernel.energy is not None:  # H first, into a scratch entry, as `hamiltonian` computes it
                lines.append("_e = np.zeros(1)")
                lines += ModulePrinter._body(self, kernel.energy.expressions(),
                                             ["_e[0]"] + [f"_k{j}" for j in range(len(kernel.energy.sums))])
                for j, op in enumerate(kernel.energy.sums):
                    lines += self._sum_text(op, "_e", f"_k{j}")
                lines.append("_H = _e[0]")
            saved = self.accumulate
            self.accumulate = set(saved) | {f"{out}[{i}]" for i, _, acc in targets if acc}
            coefficients = [f"_k{j}" for j in range(len(kernel.sums))]
            lines += ModulePrinter._body(self, [e for _, e, _ in targets] + [_coefficient(op) for op in kernel.sums],
                                         [f"{out}[{i}]" for i, _, _ in targets] + coefficients)
            self.accumulate = saved
            for op, c in zip(kernel.sums, coefficients):
                lines += self._sum_text(op, out, c)
        lines += list(tail)
        return "\n".join([f"def {signature}:"] + ["    " + line for line in lines]) + "\n"

    # -- the module -----------------------------------------------------------------------
    def print(self) -> str:
        ir = self.ir
        n, npar = len(ir.variables), self.n_parameters
        self.names[sp.Symbol("cj")] = "cj"
        head = [
            '"""Compiled-backend functions of a residual module (generated by phc): numba compiles\n'
            'them; the intrinsics _X_* are written as LLVM IR from the same expressions."""\n',
            "import base64\nimport math\n\nimport numpy as np\n\n\n"
            + packing.decoder_source(),
            f"N = {n}",
        ]
        for k, (times, values, kind) in enumerate(ir.input_tables):
            head += [f"_TABLE{k}_T = {_array([float(x) for x in times], 'float')}",
                     f"_TABLE{k}_V = {_array([float(x) for x in values], 'float')}",
                     f"_TABLE{k}_KIND = {_KIND.get(kind, 0)}"]
        parts = [_HELPERS]
        for k in range(len(ir.input_tables)):  # called by the emitted code (compile_internal)
            parts.append(f"def _table{k}_at(t):\n    return _table(_TABLE{k}_T, _TABLE{k}_V, _TABLE{k}_KIND, t)\n\n\n"
                         f"def _table{k}_slope_at(t):\n"
                         f"    return _table_slope(_TABLE{k}_T, _TABLE{k}_V, _TABLE{k}_KIND, t)\n")
        yyp = [("y", "N"), ("p", str(npar)), ("yp", "N")]
        y_p = [("y", "N"), ("p", str(npar))]
        signatures = {"yyp": "(t, y, yp, p{})", "yyp_cj": "(t, y, yp, p, cj{})", "y": "(t, y, p{})"}
        for f in function_kernels(ir):  # what each function computes (phc.codegen.kernels)
            arrays = y_p if f.args == "y" else yyp
            if f.returns == "out":
                parts.append(self._function(f.name, f"{f.name}{signatures[f.args].format(', out')}",
                                            arrays + [("out", str(f.size))], f.kernel, "out", zero=f.zero))
                continue
            local = "out" if f.returns == "array" else "_o"
            tail = {"array": "return out", "scalar": "return _o[0]", "pair": "return _o[0], _o[1]"}[f.returns]
            parts.append(self._function(f.name, f"{f.name}{signatures[f.args].format('')}", arrays, f.kernel,
                                        local, zero=f.zero, scratch=f.size, tail=[tail]))
        return "\n\n".join(head + self._text_constants + parts)


def kernel_source(ir: ResidualIR) -> tuple[str, dict]:
    """The numba-compilable text of the generated functions for `ir`, and the
    :class:`Kernel` of each intrinsic it calls."""
    printer = KernelPrinter(ir)
    return printer.print(), printer.kernels


# ---------------------------------------------------------------------------------------
# loading

def _make_intrinsic(name: str, kernel: Kernel, ir_: ResidualIR, tables: dict, printer):
    from numba.core import types
    from numba.extending import intrinsic

    def kernel_typer(typingctx, t, y, yp, p, cj, out):
        arrays = (y, yp, p, out)
        if not all(isinstance(a, types.Array) and a.ndim == 1 and a.dtype == types.float64 for a in arrays):
            return None
        if not out.mutable or not all(isinstance(s, (types.Float, types.Integer)) for s in (t, cj)):
            return None

        def codegen(context, builder, signature, args):
            _emit_kernel(context, builder, signature, args, kernel, ir_, tables, printer)
            return context.get_dummy_value()

        return types.none(t, y, yp, p, cj, out), codegen

    kernel_typer.__name__ = kernel_typer.__qualname__ = f"_X_{name}"
    return intrinsic(kernel_typer)


def _build(ir: ResidualIR, text: str, kernels: dict, trivial: set, printer, digest: str, folder: Optional[Path],
           signer: Optional[bytes], classes) -> tuple[dict, int, int]:
    """Execute the kernel text, make the intrinsics, and compile (or load) each function for
    its one signature (:func:`~phc.codegen.numba_cache.compile_functions`); returns
    (dispatchers, hits, misses)."""
    module = kernel_module(text, digest, folder)
    try:
        return _compile_all(ir, kernels, trivial, printer, module, signer, classes)
    except BaseException:
        sys.modules.pop(module.__name__, None)
        raise


def _compile_all(ir, kernels, trivial, printer, kernel_module, signer, classes):
    namespace = kernel_module.__dict__
    tables = {}
    for k in range(len(ir.input_tables)):
        tables[(k, False)] = namespace[f"_table{k}_at"]
        tables[(k, True)] = namespace[f"_table{k}_slope_at"]
    for name, kernel in kernels.items():
        namespace[f"_X_{name}"] = _make_intrinsic(name, kernel, ir, tables, printer)
    return compile_functions(namespace, trivial, signer, classes)


def load_compiled(ir: ResidualIR, reference: ModuleType, reference_source: str,
                  cache: Optional[bool] = None) -> tuple[ModuleType, CompileReport]:
    """The compiled module for `ir` (see the module docstring) and how it was obtained.

    Raises
    ------
    BackendUnavailable
        numba cannot be imported.
    BackendMismatch
        The compiled residual or Jacobian disagrees with the reference at a sample point
        (a phc bug; the caller falls back to the reference module).
    """
    ok, why = available()
    if not ok:
        raise BackendUnavailable(why)
    start, cpu = time.perf_counter(), time.process_time()
    kernel_printer = KernelPrinter(ir)
    text, kernels = kernel_printer.print(), kernel_printer.kernels
    digest = kernel_digest(text, reference_source)
    if cache is None:
        cache = os.environ.get("PHC_COMPILED_CACHE", "1").strip().lower() not in ("0", "no", "false", "off")
    note = ""
    signer = None
    folder = None
    classes = _cache_classes() if cache else None
    if not cache:
        note = "disk cache off (PHC_COMPILED_CACHE=0)"
    elif classes is None:
        note = "disk cache unavailable with this numba version"
    else:
        folder, signer, note = signed_cache_dir(compiled_cache_dir())
    loaded = numba_cache._LOADED.get(digest)
    if loaded is not None:
        _remember(digest, loaded)
        dispatchers, state, note = loaded, "memory", "compiled earlier in this process"
        hits = misses = 0
    else:
        dispatchers, hits, misses = _build(ir, text, kernels, kernel_printer.trivial, kernel_printer.printer,
                                           digest, folder, signer, classes)
        _remember(digest, dispatchers)
        if signer is None:
            state = "off"
        else:
            state = "warm" if misses == 0 else ("cold" if hits == 0 else "partial")
            try:
                from phc.codegen.load import enforce_cap
                enforce_cap()
            except OSError:
                pass
    report = CompileReport(time.perf_counter() - start, time.process_time() - cpu, state, digest,
                           tuple(sorted(kernels)), note, hits, misses)
    module = assemble(reference, dispatchers, report)
    # what the cached front end needs to load these functions again without the IR (phc.codegen.fastpath)
    module.KERNEL = {"text": text, "emitted": sorted(kernels), "trivial": sorted(kernel_printer.trivial)}
    mismatch = _cross_check(module, reference)
    if mismatch and (hits or state == "memory"):
        # functions from the cache (a race between writers, a restored or tampered cache):
        # a cache problem, not the model's and not phc's; compiled again without the cache
        numba_cache._LOADED.pop(digest, None)
        from phc.errors import CacheWarning

        warnings.warn(f"compiled functions loaded from the cache disagree with this model ({mismatch}); "
                      "compiled them again without the cache (`phc cache clean` empties it)", CacheWarning,
                      stacklevel=2)
        dispatchers, hits, misses = _build(ir, text, kernels, kernel_printer.trivial, kernel_printer.printer,
                                           digest, None, None, None)
        _remember(digest, dispatchers)
        report = CompileReport(time.perf_counter() - start, time.process_time() - cpu, "off", digest,
                               tuple(sorted(kernels)), "the cached copy disagreed with the model", 0, misses)
        module = assemble(reference, dispatchers, report)
        module.KERNEL = {"text": text, "emitted": sorted(kernels), "trivial": sorted(kernel_printer.trivial)}
        mismatch = _cross_check(module, reference)
    if mismatch:
        raise BackendMismatch(f"the compiled functions disagree with the reference module ({mismatch})")
    return module, report


__all__ = ["BackendMismatch", "BackendUnavailable", "CompileReport", "CompiledBackendWarning", "FUNCTIONS",
           "KernelPrinter", "available", "cache_key", "compiled_cache_dir", "emittable", "kernel_source",
           "load_compiled"]
