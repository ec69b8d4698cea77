"""The C back end: the generated functions compiled by the system C compiler, called through ctypes.

Input: a :class:`~phc.codegen.lower.ResidualIR` and the NumPy module printed from it (the
reference back end). Output: a module with the reference module's constants and
``full_parameters`` (and ``events``), and ``residual``, ``residual_t``, ``jacobian``,
``hamiltonian``, ``energy_scale``, ``powers``, ``invariants``, ``velocity_invariants`` and
``outputs`` of the same signatures, each a thin Python wrapper around a function of a shared
library (``BACKEND`` is ``"c"``, ``REFERENCE`` the NumPy module, ``C_SOURCE`` the C text,
``C_REPORT`` how the library was obtained). Every solver runs on it as on the NumPy module.

The C text is :func:`phc.codegen.c_printer.c_source`; it is compiled with the system C
compiler (``$CC``, else ``cc``, ``gcc`` or ``clang`` on the PATH) with :data:`FLAGS`:
``-O1`` without ``-ffast-math`` and with ``-ffp-contract=off`` (no fused multiply-adds), so
each operation is the IEEE operation the NumPy module performs. The wrappers check the
arrays' lengths (the C code does not), pass them as pointers (a non-contiguous or non-float64
array is copied first) and release the GIL during the call (ctypes does): the library keeps
no state, so threads may call one module at once.

Caching
-------
Libraries are cached in ``<phc cache>/c/`` — the private directory of
:mod:`phc.codegen.load`, checked as the numba back end's is (created 0700; refused when
another user owns it or others may write it, it or a directory on the way to it) — as
``phc_c_<digest>.so`` next to the C text it was compiled from, ``<digest>`` the SHA-256 of
everything that determines the machine code (the C text, the compiler and its version, the
flags, phc's version, the platform). Beside each library, ``phc_c_<digest>.sig`` holds an
HMAC-SHA256 tag over the library's file name and bytes under the per-user key that signs
numba's artefacts (kept outside the cache: :func:`phc.codegen.numba_cache.cache_key`). A
library is loaded only from bytes whose tag verifies — read once, checked, and handed to the
dynamic loader from memory (a ``memfd`` on Linux), so the file cannot change between the
check and the load. A library that does not verify is compiled again and replaced, with one
:class:`~phc.errors.CacheWarning`; one missing its tag is a silent miss. Without a usable
cache directory or key (or with ``PHC_COMPILED_CACHE=0``) the library is compiled in a
private temporary directory and not kept. Every library is checked against the NumPy module
at a sample point when loaded (:func:`phc.codegen.numba_cache._cross_check`).
"""

from __future__ import annotations

import ctypes
import hashlib
import hmac
import os
import platform
import shutil
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Optional

import numpy as np

from phc import __version__
from phc.errors import BackendUnsupported as CUnsupported  # noqa: F401 — the API's name

# The printer (phc.codegen.c_printer) imports sympy; loading a library from C text does not
# need it (a cached front end loads one: phc.codegen.fastpath), so it is imported where C is printed.
ABI = 1
"""Version of the library's interface (the functions of phc.codegen.c_printer's C text and
``phc_sizes``)."""
# the compiler's discovery lives with its runner (phc.codegen.cc imports no sympy: the `auto`
# rule asks for a compiler from a cached front end); its names stay importable from here
from phc.codegen.cc import _COMPILERS, available, compile_library, find_compiler  # noqa: F401
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imports sympy
    from phc.codegen.lower import ResidualIR
from phc.codegen.numba_cache import FUNCTIONS, _cross_check, _read_private, _tag, signed_cache_dir
from phc.errors import BackendMismatch, BackendUnavailable, CacheWarning, CodegenError

FLAGS = ("-std=c99", "-O1", "-fPIC", "-shared", "-ffp-contract=off")
"""Compiler flags: optimized, position-independent, no fused multiply-adds, no ``-ffast-math``.
``-O1``, not ``-O2``: the generated functions are straight-line code (common subexpressions,
then one assignment per entry) that ``-O2``'s extra passes barely speed up, while they double
the compiler's time. On the flexible slider–crank (48 kB of C), gcc 12 takes 0.19 s CPU at
``-O1`` against 0.34-0.45 s at ``-O2``; the implicit midpoint step (``phc.codegen.c_steps``,
whose own library keeps ``-O3``) and the residual and Jacobian called from Python cost the same
within the machine's noise (17.7-19.2 µs per step, 0.84-0.87 µs and 1.0-1.06 µs per call at
either level; measured by interleaving both libraries in one process, best of 4)."""

LIBS = ("-lm",)

BRIDGE_AFTER = 2000
"""A C module's residual, residual_t and jacobian go through ctypes for their first
``BRIDGE_AFTER`` calls (together) and through phc's call bridge (:mod:`phc.codegen.c_bridge`)
from then on: the same C functions, the same results to the bit. Building the bridge costs the
C compiler about 0.2 s CPU (Python's C headers; once per machine, Python and phc version,
then it is loaded from the signed cache), and it saves 1-2 µs a call. ``phc compile``
(its cross-check and certificate: 540 calls on the flexible slider–crank) does not need it;
a run of thousands of calls does, and pays at most ``BRIDGE_AFTER`` slower calls (a few ms)."""

COMPILE_TIMEOUT = 900.0
"""Seconds a compilation may take before it is abandoned (a phc bug or a broken compiler)."""

MAGIC = b"phc-c-1\n"
"""First bytes of a library's tag file."""


@dataclass
class CReport:
    """How the C library of a model was obtained."""

    seconds: float
    """Wall time to print, compile (or load) the library."""
    cpu_seconds: float
    """CPU time of this process and of the compiler it ran."""
    cached: str
    """``"warm"`` (loaded from the cache), ``"cold"`` (compiled and cached), ``"off"``
    (compiled, not cached: `note` says why) or ``"memory"`` (loaded earlier in this process)."""
    digest: str
    compiler: str
    note: str = ""

    def describe(self) -> str:
        what = {"warm": "loaded from the cache", "cold": "compiled and cached", "off": "compiled, not cached",
                "memory": "loaded earlier in this process"}.get(self.cached, self.cached)
        note = f"; {self.note}" if self.note and self.cached == "off" else ""
        return f"{what} in {self.seconds:.2f} s with {self.compiler}{note}"


def library_digest(text: str, argv: list[str], identity: str, flags: tuple = FLAGS, libs: tuple = ()) -> str:
    """The name of a library in the cache: the SHA-256 of everything that determines it."""
    material = "\0".join((text, " ".join(argv), identity, " ".join(tuple(flags) + LIBS + tuple(libs)), __version__,
                          str(ABI),
                          platform.machine(), sys.platform))
    return hashlib.sha256(material.encode()).hexdigest()[:24]


def c_cache_dir() -> Path:
    from phc.codegen.load import cache_dir

    return cache_dir() / "c"


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


# ---------------------------------------------------------------------------------------
# compiling, the signed cache, loading

def _compile(text: str, argv: list[str], digest: str, parent: Optional[Path], flags: tuple = FLAGS,
             libs: tuple = ()) -> bytes:
    """The bytes of the shared library compiled from `text` with `flags` (in a private temporary
    directory, inside `parent` when given); a failing compiler is one :class:`CodegenError`
    (:func:`phc.codegen.cc.compile_library`)."""
    work = Path(tempfile.mkdtemp(prefix="phc-c-build-", dir=parent))  # mode 0700
    try:
        src, lib = work / f"phc_c_{digest}.c", work / f"phc_c_{digest}.so"
        src.write_text(text, encoding="utf-8")
        compile_library(argv, flags, [src], lib, cwd=work, timeout=COMPILE_TIMEOUT, libs=tuple(libs) + LIBS)
        return lib.read_bytes()
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _paths(folder: Path, digest: str) -> tuple[Path, Path, Path]:
    stem = f"phc_c_{digest}"
    return folder / f"{stem}.so", folder / f"{stem}.sig", folder / f"{stem}.c"


def _cached(folder: Path, digest: str, key: bytes) -> tuple[Optional[bytes], Optional[str]]:
    """(the library's bytes when its tag verifies, None) or (None, why it was refused); a
    library or tag that is missing is (None, None): a plain miss."""
    lib, sig, _ = _paths(folder, digest)
    if not os.path.lexists(lib):
        return None, None
    data = _read_private(str(lib))
    if data is None:
        return None, "is not a regular file of this user"
    tag = _read_private(str(sig))
    if tag is None:
        return None, None
    if not (tag.startswith(MAGIC) and hmac.compare_digest(tag[len(MAGIC):], _tag(key, lib.name, data))):
        return None, "does not verify (damaged, or not written by phc under this user's key)"
    return data, None


def _store(folder: Path, digest: str, key: bytes, data: bytes, text: str) -> None:
    """Write the library, its tag and its C text (for readers) into the cache."""
    from phc.codegen.load import enforce_cap, write_atomic

    lib, sig, src = _paths(folder, digest)
    try:
        for path in (lib, sig):
            if path.is_symlink():
                path.unlink()
        write_atomic(src, text.encode("utf-8"))
        write_atomic(lib, data)
        write_atomic(sig, MAGIC + _tag(key, lib.name, data))
        enforce_cap()
    except OSError as err:  # a full or read-only disk costs the cached copy, not the run
        warnings.warn(f"could not write the C library to {folder}: {err.strerror or err}", CacheWarning,
                      stacklevel=3)


_OPEN_FDS: list[int] = []
"""Memory files holding loaded libraries, kept open for the life of the process (the dynamic
loader knows each library by its /proc path, which must not name another file later)."""


def _dlopen(data: bytes, digest: str, fallback: Optional[Path]) -> ctypes.CDLL:
    """The library of `data` loaded from memory (Linux: a memfd), else from
    `fallback`, the verified file."""
    if hasattr(os, "memfd_create") and os.path.isdir("/proc/self/fd"):
        fd = os.memfd_create(f"phc_c_{digest}", getattr(os, "MFD_CLOEXEC", 0))
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            lib = ctypes.CDLL(f"/proc/self/fd/{fd}")
        except OSError:
            os.close(fd)  # memfds not executable here (vm.memfd_noexec): the verified file
        else:
            _OPEN_FDS.append(fd)
            return lib
    if fallback is None:
        raise CodegenError("the C library cannot be loaded from memory here, and no cache directory holds it")
    return ctypes.CDLL(str(fallback))


_LOADED: dict[str, ctypes.CDLL] = {}
"""Libraries loaded in this process, by digest (a model compiled again is not reloaded)."""


def _obtain(text: str, argv: list[str], digest: str, cache: bool,
            flags: tuple = FLAGS, libs: tuple = ()) -> tuple[ctypes.CDLL, str, str]:
    """(library, state, note) for `text` (compiled with `flags`, which `digest` covers): from this
    process, the signed cache, or the compiler."""
    lib = _LOADED.get(digest)
    if lib is not None:
        return lib, "memory", ""
    folder, key, note = None, None, ""
    if not cache:
        note = "disk cache off (PHC_COMPILED_CACHE=0)"
    else:
        folder, key, note = signed_cache_dir(c_cache_dir())
    data = None
    if folder is not None:
        data, refused = _cached(folder, digest, key)
        if refused:
            warnings.warn(f"C library cache file {_paths(folder, digest)[0]} {refused}; compiled it again "
                          "(`phc cache clean` empties the cache)", CacheWarning, stacklevel=4)
    if data is not None:
        state = "warm"
    else:
        data = _compile(text, argv, digest, folder, flags, libs)
        state = "cold" if folder is not None else "off"
        if folder is not None:
            _store(folder, digest, key, data, text)
    lib = _dlopen(data, digest, _paths(folder, digest)[0] if folder is not None else None)
    _LOADED[digest] = lib
    return lib, state, note


def _cache_on() -> bool:
    """Whether compiled libraries go through the disk cache (not ``PHC_COMPILED_CACHE=0``)."""
    return os.environ.get("PHC_COMPILED_CACHE", "1").strip().lower() not in ("0", "no", "false", "off")


def translated_text(name: str, inputs, make) -> str:
    """``make()``, phc's C text `name` that is translated from Python (the step loop's, the IDA
    driver's), kept in the signed cache under a digest of the files it is made from (`inputs`:
    the C files and the Python modules the translation reads) and phc's version: a process
    that loads the library from the cache no longer translates its text first (10–25 ms).
    A cached text that does not verify, a cache that is off or unusable: made anew."""
    from phc.codegen.load import write_atomic
    from phc.codegen.numba_cache import _signed, _verified

    h = hashlib.sha256("\0".join((name, __version__, str(ABI))).encode())
    for path in inputs:
        h.update(b"\0" + Path(path).read_bytes())
    folder = signed_cache_dir(c_cache_dir())[:2] if _cache_on() else (None, None)
    if folder[0] is None:
        return make()
    (folder, key), file = folder, folder[0] / f"phc_text_{name}_{h.hexdigest()[:24]}.c"
    data = _read_private(str(file))
    text = _verified(key, data, file.name) if data is not None else None
    if text is not None:
        return text.decode("utf-8")
    made = make()
    try:
        write_atomic(file, _signed(key, made.encode("utf-8"), file.name))
    except OSError:  # a full or read-only disk costs the cached text, not the run
        pass
    return made


def runtime_library(text: str, flags: tuple, libs: tuple = ()) -> tuple[Optional[ctypes.CDLL], str]:
    """(the library, "") of phc's own C text `text` (the step loop, the call bridge, the IDA
    driver) compiled with `flags` and linked with `libs` (before ``-lm``): from this process, the signed cache or the compiler, as a model's library;
    (None, why) when no C compiler is found. A compiler that fails raises
    :class:`CodegenError`."""
    argv, identity = find_compiler()
    if argv is None:
        return None, identity
    lib, _, _ = _obtain(text, argv, library_digest(text, argv, identity, flags, libs), _cache_on(), flags, libs)
    return lib, ""


def load_compiled(ir: "ResidualIR", reference: ModuleType, reference_source: Optional[str] = None,
                  cache: Optional[bool] = None) -> tuple[ModuleType, CReport]:
    """The C module for `ir` (see the module docstring) and how its library was obtained.

    Raises
    ------
    BackendUnavailable
        No C compiler was found.
    BackendUnsupported
        The model uses something the C back end does not print yet (an input table).
    CodegenError
        The compiler failed on the generated code (a phc bug).
    BackendMismatch
        The library disagrees with the reference module at a sample point (a phc bug).
    """
    from phc.codegen.c_printer import c_source

    return load_source(c_source(ir), reference, reference_source, cache)


def load_source(text: str, reference: ModuleType, reference_source: Optional[str] = None,
                cache: Optional[bool] = None) -> tuple[ModuleType, CReport]:
    """The C module of the C text `text` (a module's ``C_SOURCE``, which :func:`load_compiled`
    prints from the model's intermediate representation) and how its library was obtained:
    from this process, the signed cache, or the compiler. Raises as :func:`load_compiled`
    (but for `BackendUnsupported`)."""
    argv, identity = find_compiler()
    if argv is None:
        raise BackendUnavailable(identity)
    start, cpu = time.perf_counter(), _cpu()
    digest = library_digest(text, argv, identity)
    if cache is None:
        cache = _cache_on()
    lib, state, note = _obtain(text, argv, digest, cache)
    report = CReport(time.perf_counter() - start, _cpu() - cpu, state, digest, identity, note)
    module = assemble(reference, lib, report, text)
    mismatch = _cross_check(module, reference)
    if mismatch and state in ("warm", "memory"):  # a cache problem, not the model's: compiled again
        warnings.warn(f"the cached C library disagrees with this model ({mismatch}); compiled it again without "
                      "the cache (`phc cache clean` empties it)", CacheWarning, stacklevel=2)
        _LOADED.pop(digest, None)
        lib, state, note = _obtain(text, argv, digest, False)
        report = CReport(time.perf_counter() - start, _cpu() - cpu, "off", digest, identity,
                         "the cached copy disagreed with the model")
        module = assemble(reference, lib, report, text)
        mismatch = _cross_check(module, reference)
    if mismatch:
        _LOADED.pop(digest, None)
        raise BackendMismatch(f"the C functions disagree with the reference module ({mismatch})")
    return module, report


# ---------------------------------------------------------------------------------------
# the module: ctypes wrappers with the NumPy module's signatures

_F64 = np.dtype(np.float64)
_D = ctypes.c_double
_PTR = ctypes.POINTER(ctypes.c_double)


def _given(a, n: int, what: str):
    """A pointer to the entries of `a` as a contiguous float64 vector of at least `n` entries
    (``ctypes.c_double.from_buffer``: it keeps the array alive; a read-only, strided or
    non-float64 array is copied first), or None (NULL) for an empty one."""
    a = np.ascontiguousarray(a, dtype=_F64)
    if a.ndim != 1 or a.shape[0] < n:
        raise ValueError(f"`{what}` has shape {a.shape}; the model's C functions need a vector of {n} entries")
    if not a.shape[0]:
        return None
    if not a.flags.writeable:
        a = a.copy()  # from_buffer wants a writable buffer; the C code only reads it
    return _D.from_buffer(a)


def _target(out, n: int, what: str):
    """A pointer into `out` when the C function can write into it directly, else None (a
    vector is written and copied back)."""
    if (type(out) is np.ndarray and out.dtype == _F64 and out.ndim == 1 and out.flags.c_contiguous
            and out.flags.writeable):
        if out.shape[0] < n:
            raise ValueError(f"`{what}` has {out.shape[0]} entries; the model's C functions write {n}")
        return _D.from_buffer(out) if n else None
    return None


def _wrappers(lib: ctypes.CDLL, n: int, m: int, njac: int, npar: int, ninv: int, nvinv: int,
              nout: int) -> dict:
    from phc.codegen import c_bridge

    P = _PTR
    # the call bridge (phc.codegen.c_bridge) is asked for at the module's BRIDGE_AFTER-th call,
    # unless this process has it already: until then the calls go through ctypes (the same C
    # functions, the same results to the bit); `bridged` holds its two entry points (False: none)
    ready = c_bridge.built()  # built earlier in this process (or switched off): used from the start
    bridged = [ready.call, ready.call_cj] if ready else [None, None] if ready is None else [False, False]
    calls = [0]

    def ask_bridge() -> None:
        calls[0] += 1
        if calls[0] >= BRIDGE_AFTER:
            module = c_bridge.bridge()
            bridged[:] = (module.call, module.call_cj) if module is not None else (False, False)

    def c_function(name, argtypes, restype=None):
        f = getattr(lib, f"phc_{name}")
        f.argtypes, f.restype = argtypes, restype
        return f

    def into(name: str, size: int, with_cj: bool):
        f = c_function(name, [_D, P, P, P, _D, P] if with_cj else [_D, P, P, P, P])
        ndarray, F64, D = np.ndarray, _F64, _D
        state = D * n  # a copy of a read-only state vector (IDA hands y and ẏ over read-only)

        def given(a):
            if not n:
                return None
            return D.from_buffer(a) if a.flags.writeable else state.from_buffer_copy(a)

        def general(t, y, yp, p, rest):
            y_, yp_, p_ = _given(y, n, "y"), _given(yp, n, "yp"), _given(p, npar, "p")
            out = rest[-1]
            target = _target(out, size, "out")
            buf = None if target is not None or not size else np.empty(size)
            dest = target if buf is None else D.from_buffer(buf)
            if with_cj:
                f(t, y_, yp_, p_, rest[0], dest)
            else:
                f(t, y_, yp_, p_, dest)
            if buf is not None:
                out[...] = buf

        address = ctypes.cast(f, ctypes.c_void_p).value

        # Through the bridge once it is built (the buffer protocol in C, phc.codegen.c_bridge: no
        # conversions), else through ctypes: the common call (IDA's and the drivers': contiguous float64 vectors of the right
        # sizes; IDA's y and ẏ are read-only, so they are copied, n doubles, rather than
        # converted) is tested inline and passed straight on; anything else takes `general`,
        # which converts or refuses. Half the cost of a call from Python was this wrapper.
        if with_cj:
            def call(t, y, yp, p, cj, out):
                via = bridged[1]
                if via:
                    try:
                        via(address, n, npar, size, t, y, yp, p, cj, out)
                    except (TypeError, ValueError, BufferError):  # not float64 vectors (or cj not a number):
                        general(t, y, yp, p, (cj, out))            # converted, or refused by ctypes
                    return
                if via is None:
                    ask_bridge()
                if (type(y) is ndarray and type(yp) is ndarray and type(p) is ndarray and type(out) is ndarray
                        and y.dtype is F64 and yp.dtype is F64 and p.dtype is F64 and out.dtype is F64
                        and y.ndim == 1 and yp.ndim == 1 and p.ndim == 1 and out.ndim == 1
                        and y.shape[0] >= n and yp.shape[0] >= n and p.shape[0] >= npar and out.shape[0] >= size):
                    try:
                        f(t, given(y), given(yp), D.from_buffer(p) if npar else None, cj,
                          D.from_buffer(out) if size else None)
                        return
                    except (TypeError, ValueError, BufferError):  # strided (or a read-only `p`, `out`): converted below
                        pass
                general(t, y, yp, p, (cj, out))
        else:
            def call(t, y, yp, p, out):
                via = bridged[0]
                if via:
                    try:
                        via(address, n, npar, size, t, y, yp, p, out)
                    except (TypeError, ValueError, BufferError):  # not a float64 vector: converted or refused
                        general(t, y, yp, p, (out,))
                    return
                if via is None:
                    ask_bridge()
                if (type(y) is ndarray and type(yp) is ndarray and type(p) is ndarray and type(out) is ndarray
                        and y.dtype is F64 and yp.dtype is F64 and p.dtype is F64 and out.dtype is F64
                        and y.ndim == 1 and yp.ndim == 1 and p.ndim == 1 and out.ndim == 1
                        and y.shape[0] >= n and yp.shape[0] >= n and p.shape[0] >= npar and out.shape[0] >= size):
                    try:
                        f(t, given(y), given(yp), D.from_buffer(p) if npar else None,
                          D.from_buffer(out) if size else None)
                        return
                    except (TypeError, ValueError, BufferError):  # strided (or a read-only `p`, `out`): converted below
                        pass
                general(t, y, yp, p, (out,))

        call.__name__ = call.__qualname__ = name
        return call

    def returned(name: str, size: int, with_yp: bool):
        f = c_function(name, [_D, P, P, P, P] if with_yp else [_D, P, P, P])

        if with_yp:
            def call(t, y, yp, p):
                out = np.empty(size)
                f(t, _given(y, n, "y"), _given(yp, n, "yp"), _given(p, npar, "p"),
                  _D.from_buffer(out) if size else None)
                return out
        else:
            def call(t, y, p):
                out = np.empty(size)
                f(t, _given(y, n, "y"), _given(p, npar, "p"), _D.from_buffer(out) if size else None)
                return out
        call.__name__ = call.__qualname__ = name
        return call

    def scalar(name: str):
        f = c_function(name, [_D, P, P], _D)

        def call(t, y, p):
            return f(t, _given(y, n, "y"), _given(p, npar, "p"))

        call.__name__ = call.__qualname__ = name
        return call

    power_array = returned("powers", 2, True)

    def powers(t, y, yp, p):
        out = power_array(t, y, yp, p)
        return float(out[0]), float(out[1])

    functions = {
        "residual": into("residual", m, False), "residual_t": into("residual_t", m, False),
        "jacobian": into("jacobian", njac, True), "hamiltonian": scalar("hamiltonian"),
        "energy_scale": scalar("energy_scale"), "powers": powers,
        "invariants": returned("invariants", ninv, False),
        "velocity_invariants": returned("velocity_invariants", nvinv, False),
        "outputs": returned("outputs", nout, True),
    }
    assert set(functions) == set(FUNCTIONS)
    return functions


def sizes_of(reference: ModuleType) -> list[int]:
    """What ``phc_sizes`` of a library printed for `reference`'s model writes."""
    return [ABI, int(reference.N), len(reference.EQUATIONS), len(reference.JAC_ROWS),
            len(reference.PARAMETER_DEFAULTS), len(reference.INVARIANTS),
            len(getattr(reference, "VELOCITY_INVARIANTS", ())), len(reference.OUTPUTS)]


def assemble(reference: ModuleType, lib: ctypes.CDLL, report: CReport, text: str) -> ModuleType:
    """The C module: the reference module's constants and functions, the library's functions
    over them, ``BACKEND``, ``REFERENCE``, ``C_REPORT``, ``C_SOURCE`` and ``C_LIBRARY``."""
    sizes = (ctypes.c_longlong * 8)()
    lib.phc_sizes.argtypes, lib.phc_sizes.restype = [ctypes.c_void_p], None
    lib.phc_sizes(ctypes.addressof(sizes))
    expected = sizes_of(reference)
    if list(sizes) != expected:
        raise BackendMismatch(f"the C library was generated for sizes {list(sizes)}, the model has {expected}")
    module = ModuleType(f"phc_c_{report.digest}", reference.__doc__)
    module.__dict__.update({k: v for k, v in reference.__dict__.items() if not k.startswith("__")})
    module.__dict__.update(_wrappers(lib, *expected[1:]))
    module.__file__ = getattr(reference, "__file__", None)
    module.BACKEND = "c"
    module.REFERENCE = reference
    module.C_REPORT = report
    module.C_SOURCE = text
    module.C_LIBRARY = lib
    return module


__all__ = ["CReport", "CUnsupported", "FLAGS", "assemble", "available", "c_cache_dir", "find_compiler",
           "library_digest", "load_compiled", "load_source", "runtime_library", "sizes_of"]
