"""The compiled backend's light half: whether numba can be used, the signed disk cache of
compiled functions, and loading a model's compiled functions from that cache alone.

:mod:`phc.codegen.numba_backend` builds the compiled functions from a model's
intermediate representation (sympy expressions; importing it costs about a second). What
a run needs once they are built lives here and imports neither sympy nor the model
language: the cached front end of ``phc simulate`` (:mod:`phc.codegen.fastpath`) loads a model's
compiled functions with :func:`load_cached`, from the kernel text its record keeps, and
the compiled step loop (:mod:`phc.simulation.compiled_steps`) keeps its own code in the
same signed cache. How the cache is keyed, signed and kept private:
:mod:`phc.codegen.numba_backend`.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import pickle
import secrets
import stat
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Optional

import numpy as np

from phc import __version__
from phc.codegen.load import KEY_BYTES, state_dir as _state_dir
from phc.codegen.load import read_key as _read_key
from phc.errors import BackendMismatch, BackendUnavailable, CompiledBackendWarning

NUMBA_MIN = (0, 59)
"""Oldest numba version this backend supports."""

EMITTER_VERSION = "2"
"""Changes whenever the code the emitter writes changes (part of the cache key)."""

FUNCTIONS = ("residual", "residual_t", "jacobian", "hamiltonian", "energy_scale", "powers", "invariants",
             "velocity_invariants", "outputs")
"""The generated functions the compiled module replaces (the rest is the reference module's)."""

_AVAILABLE: Optional[tuple[bool, str]] = None


def why_unavailable() -> Optional[str]:
    """Why numba could not be used, if that was found out already (never imports it)."""
    return _AVAILABLE[1] if _AVAILABLE is not None and not _AVAILABLE[0] else None


def available() -> tuple[bool, str]:
    """(True, numba version) when numba can be used, else (False, why not). Imports numba
    (~0.3 s) the first time."""
    global _AVAILABLE
    if _AVAILABLE is None:
        try:
            import numba
        except ImportError:
            _AVAILABLE = (False, "numba is not installed (pip install \"port-hamiltonian-compiler[fast]\")")
        except Exception as err:  # a broken installation (llvmlite mismatch, ...)
            _AVAILABLE = (False, f"numba cannot be imported ({type(err).__name__}: {err})")
        else:
            try:
                version = tuple(int(x) for x in numba.__version__.split(".")[:2])
            except ValueError:
                version = NUMBA_MIN
            if version < NUMBA_MIN:
                _AVAILABLE = (False, f"numba {numba.__version__} is too old (need ≥ {NUMBA_MIN[0]}.{NUMBA_MIN[1]})")
            else:
                _AVAILABLE = (True, numba.__version__)
    return _AVAILABLE


HELPER_NAMES = ("_csr_add", "_scatter_add", "_csr_quad", "_csr_grad_add", "_table", "_table_slope")
"""The kernel text's helper functions (jitted before the functions that call them)."""


# ---------------------------------------------------------------------------------------
# the signed on-disk cache

def _private_dir(path: Path) -> Optional[str]:
    """Create `path` (0700) if missing; None when it is a private directory, else why not."""
    from phc.codegen.load import _problem

    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as err:
        return f"cannot be created ({err.strerror})"
    return _problem(path)


def cache_key() -> tuple[Optional[bytes], str]:
    """(the per-user key signing compiled artefacts, "") or (None, why there is none)."""
    folder = _state_dir()
    problem = _private_dir(folder)
    if problem:
        return None, f"state directory {folder} {problem}"
    path = folder / "cache-key"
    key = _read_key(path)
    if key is not None:
        return key, ""
    if path.exists() or path.is_symlink():
        return None, f"{path} is not a private {KEY_BYTES}-byte key file (remove it to make a new one)"
    tmp = folder / f".cache-key.{os.getpid()}.{secrets.token_hex(4)}"
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
        try:
            os.write(fd, secrets.token_bytes(KEY_BYTES))
        finally:
            os.close(fd)
        try:
            os.link(tmp, path)  # never replaces a key another process made meanwhile
        except FileExistsError:
            pass
        finally:
            os.unlink(tmp)
    except OSError as err:
        return None, f"cannot write {path} ({err.strerror})"
    key = _read_key(path)
    return (key, "") if key is not None else (None, f"{path} could not be read back")


_MAGIC = b"phc-numba-2\n"
"""Each file is signed over its own name and its content: a signed file copied or renamed
over another function's name does not verify (``phc-numba-1`` files signed the content only)."""


def _tag(key: bytes, name: str, payload: bytes) -> bytes:
    return hmac.new(key, name.encode("utf-8", "surrogateescape") + b"\0" + payload, hashlib.sha256).digest()


def _signed(key: bytes, payload: bytes, name: str) -> bytes:
    """`payload` signed for the file named `name` (its last path component)."""
    return _MAGIC + _tag(key, os.path.basename(name), payload) + payload


def _verified(key: bytes, data: bytes, name: str) -> Optional[bytes]:
    """The payload of `data` read from the file named `name` when its signature is for that
    name and content under `key`; else None."""
    head = len(_MAGIC) + 32
    if len(data) < head or not data.startswith(_MAGIC):
        return None
    tag, payload = data[len(_MAGIC):head], data[head:]
    return payload if hmac.compare_digest(tag, _tag(key, os.path.basename(name), payload)) else None


_WARNED: set[str] = set()


def _damaged(path: str, data: bytes, stamp: str) -> None:
    """A cache file that does not verify is a miss (compiled again) and says so, once per
    model (`stamp`) and cache directory in this process; never blamed on the model. Files
    of an older layout (another magic line) are a silent miss."""
    if not data.startswith(_MAGIC) and data.startswith(b"phc-numba-"):
        return
    group = f"{os.path.dirname(path)}\0{stamp}"
    if group in _WARNED:
        return
    _WARNED.add(group)
    from phc.errors import CacheWarning

    warnings.warn(f"compiled-function cache file {path} does not verify (damaged, renamed or copied from another "
                  "name, or signed under another key); ignored, the model's functions that do not verify are "
                  "compiled again (`phc cache clean` empties the cache)", CacheWarning, stacklevel=2)


def _read_private(path: str) -> Optional[bytes]:
    """The bytes of a regular file of ours (not a link; a special file is never opened for
    a blocking read), else None."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
                     | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or (hasattr(os, "getuid") and st.st_uid != os.getuid()):
            return None
        with os.fdopen(os.dup(fd), "rb") as f:
            data = f.read()
    except OSError:
        return None
    finally:
        os.close(fd)
    try:
        os.utime(path)  # most recently used, for the cache's size cap
    except OSError:
        pass
    return data


_REGISTRY: dict[str, tuple[str, str]] = {}
"""Pseudo file name of a kernel text -> (cache directory, source stamp), for the locator."""

_CACHE_CLASSES = None


def _cache_classes():
    """The numba cache classes phc uses (built once; None when this numba's internals differ)."""
    global _CACHE_CLASSES
    if _CACHE_CLASSES is not None:
        return _CACHE_CLASSES or None
    try:
        from numba.core import config
        from numba.core.caching import (CompileResultCacheImpl, FunctionCache, IndexDataCacheFile,
                                        _CacheLocator)
        from numba.core.serialize import dumps
    except ImportError:
        _CACHE_CLASSES = ()
        return None

    class PhcLocator(_CacheLocator):
        def __init__(self, path: str, stamp: str):
            self._path, self._stamp = path, stamp

        def ensure_cache_path(self):
            problem = _private_dir(Path(self._path))
            if problem:
                raise OSError(problem)

        def get_cache_path(self):
            return self._path

        def get_source_stamp(self):
            return self._stamp

        def get_disambiguator(self):
            return self._stamp[:12]

        @classmethod
        def from_function(cls, py_func, py_file):
            entry = _REGISTRY.get(py_file)
            return cls(*entry) if entry else None

    class PhcImpl(CompileResultCacheImpl):
        _locator_classes = [PhcLocator]

    class SignedFile(IndexDataCacheFile):
        """numba's index and data files, each signed; unverified files are never unpickled."""

        def __init__(self, cache_path, filename_base, source_stamp, key):
            super().__init__(cache_path, filename_base, source_stamp)
            self._key = key

        def _load_index(self):
            data = _read_private(self._index_path)
            if data is None:
                return {}
            payload = _verified(self._key, data, self._index_path)
            if payload is None:
                _damaged(self._index_path, data, self._source_stamp)
                return {}
            version, stamp, overloads = pickle.loads(payload)
            if version != self._version or stamp != self._source_stamp:
                return {}
            return overloads

        def _save_index(self, overloads):
            payload = pickle.dumps((self._version, self._source_stamp, overloads), protocol=-1)
            with self._open_for_write(self._index_path) as f:
                f.write(_signed(self._key, payload, self._index_path))

        def _load_data(self, name):
            path = self._data_path(name)
            data = _read_private(path)
            payload = _verified(self._key, data, path) if data is not None else None
            if payload is None:
                if data is not None:
                    _damaged(path, data, self._source_stamp)
                raise OSError("missing or unsigned artefact")  # numba: treated as a miss
            return pickle.loads(payload)

        def _save_data(self, name, data):
            payload = dumps(data)
            path = self._data_path(name)
            with self._open_for_write(path) as f:
                f.write(_signed(self._key, payload, path))

    class PhcCache(FunctionCache):
        _impl_class = PhcImpl

        def __init__(self, py_func, key):
            super().__init__(py_func)
            self._cache_file = SignedFile(self._cache_path, self._impl.filename_base,
                                          self._impl.locator.get_source_stamp(), key)

        def save_overload(self, sig, data):
            """A cache that cannot be written (a directory found unsafe or full meanwhile)
            costs the saved copy, with one warning; never the compilation."""
            try:
                super().save_overload(sig, data)
            except OSError as err:
                where = self._cache_path
                if where not in _WARNED:
                    _WARNED.add(where)
                    from phc.errors import CacheWarning

                    warnings.warn(f"compiled functions not saved to the cache {where}: "
                                  f"{err.strerror or err}", CacheWarning, stacklevel=2)

    if config.CACHE_LOCATOR_CLASSES:  # a user override would bypass phc's locator
        _CACHE_CLASSES = ()
        return None
    _CACHE_CLASSES = (PhcCache,)
    return _CACHE_CLASSES


def signed_cache_dir(folder: Path) -> tuple[Optional[Path], Optional[bytes], str]:
    """``(folder, key, note)`` for a cache of signed artefacts in `folder` (the numba and the
    C back end's): the folder and this user's signing key when both are usable, else
    ``(None, None, why)`` with why the cache is not used (a directory others can write, no
    key)."""
    problem = _private_dir(folder)
    key, why = cache_key()
    if problem:
        return None, None, f"cache directory {folder} {problem}"
    if key is None:
        return None, None, why
    return folder, key, ""


def compiled_cache_dir() -> Path:
    from phc.codegen.load import cache_dir

    return cache_dir() / "numba"


# ---------------------------------------------------------------------------------------
# loading

@dataclass
class CompileReport:
    """How the compiled module was obtained."""

    seconds: float
    """Wall time to build (or load) the compiled functions."""
    cpu_seconds: float
    """CPU time of this process for the same (robust to a loaded machine)."""
    cached: str
    """``"warm"`` (every function loaded from the cache), ``"cold"`` (compiled and saved),
    ``"partial"`` or ``"off"`` (no disk cache; `note` says why)."""
    digest: str
    emitted: tuple[str, ...] = ()
    """Functions whose expressions were written as LLVM IR (the others went through numba's compiler)."""
    note: str = ""
    hits: int = 0
    misses: int = 0

    def describe(self) -> str:
        """One phrase: how long it took and whether the cache was used."""
        what = {"warm": "loaded from the cache", "cold": "compiled and cached", "partial": "partly from the cache",
                "off": "compiled, not cached", "memory": "compiled earlier in this process"}.get(self.cached,
                                                                                               self.cached)
        note = f"; {self.note}" if self.note and self.cached == "off" else ""
        return f"{what} in {self.seconds:.2f} s{note}"


def _signature(name: str):
    """The one signature each function is compiled for: float64 scalars, read-only arrays of
    any layout in, a writable array out. Every 1-D float64 array converts to it (numba's
    dispatcher resolves the conversion once per argument types, in C), so no call compiles
    a second specialization in the middle of a run (IDA passes read-only arrays)."""
    from numba.core import types

    given = types.Array(types.float64, 1, "A", readonly=True)
    out = types.Array(types.float64, 1, "A")
    f64 = types.float64
    if name in ("residual", "residual_t"):
        return (f64, given, given, given, out)
    if name == "jacobian":
        return (f64, given, given, given, f64, out)
    if name in ("hamiltonian", "energy_scale", "invariants", "velocity_invariants"):
        return (f64, given, given)
    return (f64, given, given, given)


def _cross_check(compiled: ModuleType, reference: ModuleType) -> Optional[str]:
    """Compare residual and Jacobian at one fixed sample point; None when they agree."""
    n, njac = reference.N, len(reference.JAC_ROWS)
    rng = np.random.default_rng(20240611)
    y, yp = rng.uniform(0.2, 0.8, n), rng.uniform(-0.5, 0.5, n)
    p = np.asarray(reference.full_parameters(), dtype=float)
    t = 0.125
    with np.errstate(all="ignore"):
        try:
            ref_r, ref_j = np.zeros(n), np.zeros(njac)
            reference.residual(t, y, yp, p, ref_r)
            reference.jacobian(t, y, yp, p, 2.5, ref_j)
        except (ArithmeticError, ValueError, TypeError):
            return None  # the reference cannot be evaluated there: nothing to compare
        out_r, out_j = np.zeros(n), np.zeros(njac)
        compiled.residual(t, y, yp, p, out_r)
        compiled.jacobian(t, y, yp, p, 2.5, out_j)
    for what, a, b in (("residual", ref_r, out_r), ("Jacobian", ref_j, out_j)):
        bad = ~np.isclose(a, b, rtol=1e-9, atol=1e-12 * max(1.0, float(np.nanmax(np.abs(a), initial=0.0))),
                          equal_nan=True)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            return f"{what} entry {k}: compiled {b[k]!r}, reference {a[k]!r}"
    return None


_LOADED: dict[str, dict] = {}
"""Compiled functions by digest, for this process (a model compiled again is not rebuilt);
the most recently used :data:`LOADED_MAX` are kept."""
LOADED_MAX = 16


def _remember(digest: str, dispatchers: dict) -> None:
    _LOADED.pop(digest, None)
    _LOADED[digest] = dispatchers
    while len(_LOADED) > LOADED_MAX:
        old = next(iter(_LOADED))
        del _LOADED[old]
        sys.modules.pop(f"phc_numba_{old}", None)


def kernel_digest(text: str, reference_source: str) -> str:
    """The name of a model's compiled functions in the cache: the SHA-256 of everything that
    determines the code (kernel text, reference module text, phc, emitter, numba and Python
    versions); numba adds the CPU to its own key."""
    import numba

    material = "\0".join((text, reference_source, __version__, EMITTER_VERSION, numba.__version__, sys.version))
    return hashlib.sha256(material.encode()).hexdigest()[:24]


def assemble(reference: ModuleType, dispatchers: dict, report: "CompileReport") -> ModuleType:
    """The compiled module: the reference module's constants and functions, the compiled
    functions over them, ``BACKEND``, ``REFERENCE`` and ``COMPILE_REPORT``."""
    module = ModuleType(f"phc_numba_{report.digest}", reference.__doc__)
    module.__dict__.update({k: v for k, v in reference.__dict__.items() if not k.startswith("__")})
    module.__dict__.update(dispatchers)
    module.__file__ = getattr(reference, "__file__", None)
    module.BACKEND = "numba"
    module.REFERENCE = reference
    module.COMPILE_REPORT = report
    return module


def kernel_module(text: str, digest: str, folder: Optional[Path]) -> ModuleType:
    """Execute the kernel text (phc's own printer output, kept in memory or in a signed
    record: no model text as code) as the module numba's cache locator knows by name."""
    modname = f"phc_numba_{digest}"
    filename = str((folder or Path("<memory>")) / f"{modname}.py")
    if folder is not None:
        _REGISTRY[filename] = (str(folder), digest)
    module = ModuleType(modname, "Compiled-backend functions of a generated residual module.")
    module.__file__ = filename
    exec(compile(text, filename, "exec", dont_inherit=True), module.__dict__)  # safe: phc's printer output, signed
    # numba finds a cached function's globals by importing its module's name: the module
    # must be known (it is never imported from a file)
    sys.modules[modname] = module
    return module


def compile_functions(namespace: dict, trivial, signer: Optional[bytes], classes) -> tuple[dict, int, int]:
    """Jit the kernel text's helpers and compile (or load from the signed cache, with `signer`)
    each function of :data:`FUNCTIONS` but the `trivial` ones for its one signature
    (:func:`_signature`), in the executed kernel module's `namespace`; returns (dispatchers,
    cache hits, cache misses)."""
    import numba

    jit = numba.njit(error_model="numpy")
    for name in HELPER_NAMES:
        namespace[name] = jit(namespace[name])
    dispatchers = {}
    for name in FUNCTIONS:
        if name in trivial:
            continue
        disp = numba.njit(error_model="numpy")(namespace[name])
        if signer is not None:
            try:
                disp._cache = classes[0](namespace[name], signer)
            except Exception:  # numba internals differ: compile without the disk cache
                pass
        namespace[name] = dispatchers[name] = disp
    from numba.core.errors import NumbaWarning

    with warnings.catch_warnings():
        # numba's NumbaWarning about uncachable functions (large constants); phc's own
        # CacheWarning about a damaged cache file is shown
        warnings.simplefilter("ignore", NumbaWarning)
        for name, disp in dispatchers.items():
            disp.compile(_signature(name))
            disp.disable_compile()
    hits = sum(sum(d._cache_hits.values()) for d in dispatchers.values())
    misses = sum(sum(d._cache_misses.values()) for d in dispatchers.values())
    return dispatchers, hits, misses


class NotInCache(Exception):
    """A function of the cached front end's kernel text has to be compiled (it is not in the
    disk cache), which needs the model's intermediate representation: the full path runs."""


def _needs_ir(*args):
    raise NotInCache("compiled from the intermediate representation only")


def load_cached(kernel: dict, reference: ModuleType, reference_source: str) -> Optional[ModuleType]:
    """The compiled module of a model from phc's disk cache alone, or None.

    `kernel` is what :func:`phc.codegen.numba_backend.load_compiled` kept as the module's
    ``KERNEL`` (its kernel text, the functions whose expressions were written as LLVM IR,
    the functions left to the reference module). Those LLVM-IR functions can only be
    compiled from the model's intermediate representation: here each is a stub, so a
    function missing from the cache (evicted, or signed under another key) makes this a
    miss instead of a compilation. The result is checked against the reference module at a
    sample point, as a fresh compilation is."""
    ok, _ = available()
    if not ok or os.environ.get("PHC_COMPILED_CACHE", "1").strip().lower() in ("0", "no", "false", "off"):
        return None
    classes = _cache_classes()
    if classes is None:
        return None
    folder = compiled_cache_dir()
    signer, _ = cache_key()
    if _private_dir(folder) or signer is None:
        return None
    start, cpu = time.perf_counter(), time.process_time()
    text, emitted, trivial = str(kernel["text"]), tuple(kernel["emitted"]), set(kernel["trivial"])
    digest = kernel_digest(text, reference_source)
    dispatchers = _LOADED.get(digest)
    state, hits = "memory", 0
    if dispatchers is None:
        module = kernel_module(text, digest, folder)
        namespace = module.__dict__
        try:
            for name in emitted:
                namespace[f"_X_{name}"] = _needs_ir
            dispatchers, hits, _ = compile_functions(namespace, trivial, signer, classes)
        except Exception:  # noqa: BLE001 — not in the cache (or numba's internals differ): the full path
            sys.modules.pop(module.__name__, None)
            return None
        state = "warm"
    _remember(digest, dispatchers)
    report = CompileReport(time.perf_counter() - start, time.process_time() - cpu, state, digest, emitted,
                           "", hits, 0)
    module = assemble(reference, dispatchers, report)
    module.KERNEL = dict(kernel)
    if _cross_check(module, reference):
        return None
    return module


__all__ = ["BackendMismatch", "BackendUnavailable", "CompileReport", "CompiledBackendWarning", "FUNCTIONS",
           "HELPER_NAMES", "assemble", "available", "cache_key", "compiled_cache_dir", "kernel_digest",
           "kernel_module", "load_cached", "why_unavailable"]
