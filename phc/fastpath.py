"""The cached front end of ``phc simulate`` (and ``phc validate``): a second run of an
unchanged model skips reading, elaboration, the symbolic passes and the certificate.

Input: the command-line arguments of ``phc simulate``. Output: on a hit, a
:class:`CachedModel` that :func:`phc.simulation.simulate` and the command line use like a
:class:`~phc.pipeline.CompiledModel` — the generated module (executed from the source
text kept in the record, as :func:`phc.codegen.load.load_generated` does) and a small
record of what a run needs after compilation: the simulation options, initial values,
equation labels and their places in the model file (for messages), units, outputs, the
certificate's verdict and the lines the full path prints. Neither sympy nor pint nor the
model-language classes are imported on a hit.

The record is JSON (never a pickle), signed with HMAC-SHA256 under the per-user key the
compiled backend signs its artefacts with (``$PHC_STATE_DIR``, else
``$XDG_STATE_HOME/phc``, else ``~/.local/state/phc``, file ``cache-key``), and lives in
the private cache directory of the generated modules (:mod:`phc.codegen.load`), under
``front/``; ``phc cache clean`` removes it, and the cache's size cap counts it.

It is found by a key over everything that decides the compilation: the model (or scene)
file's bytes, its path as given and the working directory (messages cite it), the
options that change compilation (``--no-certify``, ``--backend``, ``--allow-path``,
``--max-memory``), every ``PHC_*`` environment variable, phc's version and a hash of phc's
own source files, the Python version and the installed versions of the libraries the
compiler uses. The record then lists every further file the compilation read (nested
models, tables, matrices) with its SHA-256; a hit re-hashes them. Whatever does not match,
cannot be read or does not verify is a miss: the full path runs, silently, and writes a
fresh record.

The fast path is not taken (the full path runs) for ``--estimate-error`` and ``--profile``
(they need the model itself), for a ``--param`` of a compile-time parameter or of one an
initial value is written in, and when the compilation warned. ``PHC_FRONT_END_CACHE=0``
turns it off. On the compiled (numba) backend the record also keeps the kernel text of the
model's compiled functions, which a hit loads from their signed disk cache
(:func:`phc.codegen.numba_cache.load_cached`, without sympy); functions missing from that
cache make it a miss.

``phc validate`` keeps each file's result (its diagnostics as printed and as JSON, and
its status line) under the same kind of key (:func:`lookup_validate`); the text and JSON
formats use it.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import stat
import sys
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Iterator, Optional

FORMAT = 1
"""Version of the record layout (part of the key)."""
ENV_SWITCH = "PHC_FRONT_END_CACHE"
"""``0`` turns the cached front end off."""
FOLDER = "front"
"""Subdirectory of the cache directory holding the records."""
_MAGIC = b"phc-front-1\n"
_IGNORED_ENV = frozenset({"PHC_DEBUG", ENV_SWITCH})
_LIBRARIES = ("sympy", "pint", "numpy", "scipy", "pydantic", "yaml", "sksundae", "numba")
"""Libraries whose installed copy is part of the key (a changed one is a miss)."""
_MAX_RECORD = 256 * 2**20


# ---------------------------------------------------------------------------------------
# what a run needs, without sympy


@dataclass(frozen=True)
class _Span:
    file: str
    line: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}"


@dataclass(frozen=True)
class _Labelled:
    label: str
    span: Optional[_Span]


@dataclass(frozen=True)
class _Initial:
    name: str
    value: float
    guess: bool
    expr: None = None


class _Certificate:
    """The certificate's verdict as the full path printed it."""

    def __init__(self, summary: str, as_dict: dict) -> None:
        self._summary, self._dict = summary, as_dict

    def summary(self) -> str:
        return self._summary

    def to_dict(self) -> dict:
        return json.loads(json.dumps(self._dict))  # a copy


class CachedModel:
    """What `simulate` and the command line read of a compiled model, from a record."""

    cached = True

    def __init__(self, record: dict, module, module_path: Path, seconds: float) -> None:
        d = record["dae"]
        self.name = record["name"]
        self.module, self.module_path, self.source = module, module_path, record["source"]
        self.timings = {"load": seconds}
        self.diagnostics = tuple(StoredDiagnostic(sev, line) for sev, line in record.get("warnings", ()))
        self.written_options = record.get("written_options")
        """The accuracy settings the file writes, where (the solver of a run may ignore them)."""
        self.start_state = None
        self.dae = SimpleNamespace(
            name=d["name"], n_states=d["n_states"], options=d["options"], units=d["units"], parameters=(),
            equations=tuple(_Labelled(lab, _span(s)) for lab, s in d["equations"]),
            invariants=tuple(_Labelled(lab, _span(s)) for lab, s in d["invariants"]),
            velocity_invariants=tuple(_Labelled(lab, _span(s)) for lab, s in d["velocity_invariants"]),
            initial=tuple(_Initial(n, float(v), bool(g)) for n, v, g in d["initial"]),
            topology=SimpleNamespace(connections=tuple((a, b, lab, _span(s)) for a, b, lab, s in d["connections"])),
            left_out=tuple(tuple(x) for x in d["left_out"]))
        cert = record["certificate"]
        self.certificate = _Certificate(cert["summary"], cert["dict"]) if cert is not None else None
        scene = record["scene"]
        self.scene = (SimpleNamespace(name=scene["name"], spec=SimpleNamespace(model=scene["model"]))
                      if scene is not None else None)
        self.output_spans = {k: _span(s) for k, s in record["output_spans"].items()}
        # the line the full path printed; on the compiled backend it says how the functions
        # were loaded this time (phc.codegen.backends.describe)
        self.backend_line = record["backend_line"] if record.get("numba") is None else None
        self._full_size = record["full_size"]

    @property
    def n_states(self) -> int:
        return self.dae.n_states - 1

    @property
    def n_equations(self) -> int:
        return len(self.dae.equations)

    @property
    def jacobian_nnz(self) -> int:
        return len(self.module.JAC_ROWS)

    @property
    def left_out(self) -> tuple:
        return self.dae.left_out

    @property
    def backend(self) -> str:
        return getattr(self.module, "BACKEND", "numpy")

    @property
    def compile_time(self) -> float:
        return sum(self.timings.values())

    def size(self) -> dict[str, int]:
        return {"states": self.n_states, "equations": self.n_equations, "jacobian_nnz": self.jacobian_nnz}

    def full_size(self) -> Optional[dict[str, int]]:
        return dict(self._full_size) if self._full_size is not None else None


def _span(s) -> Optional[_Span]:
    return _Span(str(s[0]), int(s[1])) if s else None


def _span_of(span) -> Optional[list]:
    return [str(span.file), int(span.line)] if span is not None else None


# ---------------------------------------------------------------------------------------
# the key


def enabled(args) -> bool:
    """Whether this `phc simulate` may use (and write) the cached front end."""
    return (os.environ.get(ENV_SWITCH, "1").strip() != "0" and not getattr(args, "estimate_error", False)
            and not getattr(args, "profile", False))


_PHC_HASH: Optional[str] = None


def phc_source_hash() -> str:
    """SHA-256 over phc's own files (names and bytes): a changed phc is a miss."""
    global _PHC_HASH
    if _PHC_HASH is None:
        root = Path(__file__).resolve().parent
        h = hashlib.sha256()
        for path in sorted(p for p in root.rglob("*") if "__pycache__" not in p.parts and p.suffix != ".pyc"):
            if path.is_file():
                h.update(path.relative_to(root).as_posix().encode() + b"\0")
                h.update(hashlib.sha256(path.read_bytes()).digest())
        _PHC_HASH = h.hexdigest()
    return _PHC_HASH


def _libraries() -> dict:
    """Where each library the compiler uses is installed, with its file's size and time (a
    reinstalled or upgraded library changes them); found without importing it."""
    from importlib.util import find_spec

    out = {}
    for name in _LIBRARIES:
        try:
            spec = find_spec(name)
        except (ImportError, ValueError):
            spec = None
        origin = getattr(spec, "origin", None) if spec is not None else None
        if origin and os.path.isfile(origin):
            st = os.stat(origin)
            out[name] = [origin, st.st_size, st.st_mtime_ns]
        else:
            out[name] = None
    return out


def _key(args, path: str, data: bytes, command: str) -> str:
    from phc import __version__

    parts = {
        "format": FORMAT, "phc": __version__, "phc_source": phc_source_hash(), "python": sys.version,
        "executable": sys.executable, "libraries": _libraries(), "command": command, "file": str(path),
        "real": os.path.realpath(path), "cwd": os.getcwd(), "bytes": hashlib.sha256(data).hexdigest(),
        "no_certify": bool(getattr(args, "no_certify", False)), "backend": getattr(args, "backend", None),
        "allow_path": [[d, os.path.realpath(d)] for d in (getattr(args, "allow_path", None) or [])],
        "max_memory": getattr(args, "max_memory", None),
        "env": sorted((k, v) for k, v in os.environ.items() if k.startswith("PHC_") and k not in _IGNORED_ENV),
    }
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


# ---------------------------------------------------------------------------------------
# files: private, regular, signed


def _read_regular(path, limit: int) -> Optional[bytes]:
    """The bytes of a regular file (not a link, not a FIFO), at most `limit`; else None."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
                     | getattr(os, "O_CLOEXEC", 0))
    except (OSError, TypeError, ValueError):
        return None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_size > limit:
            return None
        with os.fdopen(os.dup(fd), "rb") as fh:
            data = fh.read(min(limit, st.st_size) + 1)  # a file that grew meanwhile shows as longer
    except OSError:
        return None
    finally:
        os.close(fd)
    return data if len(data) <= min(limit, st.st_size) else None


def _read_key() -> Optional[bytes]:
    """The per-user signing key when it exists and is private."""
    from phc.codegen.load import read_key, state_dir

    return read_key(state_dir() / "cache-key")


def _folder() -> Optional[Path]:
    """The records' directory inside the private cache directory, or None when the cache
    directory is not private (the full path then warns about it as usual)."""
    from phc.codegen.load import _problem, configured_cache_dir

    root = configured_cache_dir()
    if not root.is_dir() or _problem(root) is not None:
        return None
    return root / FOLDER


def _record_path(key: str) -> Optional[Path]:
    folder = _folder()
    return folder / f"{key}.json" if folder is not None else None


# ---------------------------------------------------------------------------------------
# a hit


def lookup(args, params: dict) -> Optional[CachedModel]:
    """The cached front end of this `phc simulate`, or None (a miss, or not applicable).
    Never raises: anything unexpected is a miss."""
    try:
        return _lookup(args, params)
    except Exception:  # noqa: BLE001 — a broken record costs the full path, never the run
        return None


def _load(args, path: str, command: str) -> Optional[dict]:
    """The verified record of `command` on `path` whose inputs are unchanged, or None."""
    if not enabled(args):
        return None
    data = _read_regular(path, 16 * 2**20)
    if data is None:
        return None
    key = _key(args, path, data, command)
    where = _record_path(key)
    secret = _read_key()
    if where is None or secret is None:
        return None
    raw = _read_regular(where, _MAX_RECORD)
    head = len(_MAGIC) + 32
    if raw is None or len(raw) < head or not raw.startswith(_MAGIC):
        return None
    tag, payload = raw[len(_MAGIC):head], raw[head:]
    if not hmac.compare_digest(tag, hmac.new(secret, payload, hashlib.sha256).digest()):
        return None
    record = json.loads(payload)
    if record.get("format") != FORMAT or record.get("key") != key or record.get("command") != command:
        return None
    for name, digest in record["inputs"]:  # the files the compilation read, unchanged
        content = _read_regular(name, 2**40)
        if content is None or hashlib.sha256(content).hexdigest() != digest:
            return None
    try:
        os.utime(where)  # most recently used: the cache's size cap evicts the oldest first
    except OSError:
        pass
    return record


def _lookup(args, params: dict) -> Optional[CachedModel]:
    start = time.perf_counter()
    record = _load(args, args.file, "simulate")
    if record is None:
        return None
    depends = record["initial_depends"]
    if params and (depends is None or any(k in depends for k in params)):
        return None  # an initial value written in an overridden parameter: evaluated by the full path
    from phc.codegen.load import load_generated

    module, module_path = load_generated(record["source"], record["name"])
    fixed = set(getattr(module, "COMPILE_TIME_PARAMETERS", ()))
    for k, v in params.items():
        if k in fixed and float(v) != float(module.PARAMETER_DEFAULTS[module.PARAMETERS.index(k)]):
            return None  # recompiled by the full path
    if record.get("numba") is not None:  # the compiled backend: its functions from the disk cache, or a miss
        from phc.codegen.numba_cache import load_cached

        module = load_cached(record["numba"], module, record["source"])
        if module is None:
            return None
    return CachedModel(record, module, module_path, time.perf_counter() - start)


@dataclass(frozen=True)
class StoredDiagnostic:
    """A diagnostic as `phc validate` printed it (its line and its severity)."""

    severity: str
    line: str

    def render(self) -> str:
        return self.line


def lookup_validate(args, path: str) -> Optional[dict]:
    """The stored `phc validate` result of `path` (``valid``, ``kind``, ``json``: the
    diagnostics as JSON, ``diagnostics``: [severity, line], ``status``: the file's own line
    or None), or None. Never raises."""
    try:
        record = _load(args, path, "validate")
        return record["validate"] if record is not None else None
    except Exception:  # noqa: BLE001
        return None


# ---------------------------------------------------------------------------------------
# writing a record after the full path


class Recorder:
    """Watches one compilation: the files it reads and whether it warns."""

    def __init__(self, args, path: str, command: str) -> None:
        self.args, self.path, self.command = args, path, command
        self.data: Optional[bytes] = None
        self.files: dict[str, tuple] = {}
        self.warned = False

    def store(self, compiled) -> None:
        """Write the record of `compiled` (never raises; skipped when anything is unusual)."""
        try:
            self._store(compiled)
        except Exception:  # noqa: BLE001 — the cache is an optimisation
            if os.environ.get("PHC_DEBUG"):
                raise

    def _store(self, compiled) -> None:
        from phc.codegen.backends import name_of

        backend = name_of(compiled.module)
        if backend not in ("numpy", "numba") or (backend == "numba" and not hasattr(compiled.module, "KERNEL")):
            return
        self._write(_record(compiled, getattr(self.args, "backend", None)))

    def store_validate(self, entry: dict) -> None:
        """Write the record of one file's `phc validate` result (never raises)."""
        try:
            self._write({"validate": entry})
        except Exception:  # noqa: BLE001 — the cache is an optimisation
            if os.environ.get("PHC_DEBUG"):
                raise

    def _write(self, record: Optional[dict]) -> None:
        if record is None or self.data is None or self.warned:
            return
        if _read_regular(self.path, 16 * 2**20) != self.data:
            return  # changed while it was read
        inputs = []
        for name, (size, mtime) in sorted(self.files.items()):
            content = _read_regular(name, 2**40)
            if content is None:
                return
            st = os.stat(name)
            if (st.st_size, st.st_mtime_ns) != (size, mtime):
                return  # changed while it was compiled
            inputs.append([name, hashlib.sha256(content).hexdigest()])
        key = _key(self.args, self.path, self.data, self.command)
        record.update(format=FORMAT, key=key, command=self.command, inputs=inputs)
        payload = json.dumps(record, allow_nan=True).encode()
        if json.loads(payload) != record:
            return  # something JSON cannot carry exactly (tuples, ...)
        from phc.codegen.numba_cache import cache_key

        secret, _ = cache_key()  # created when missing
        from phc.codegen.load import configured_cache_dir

        configured_cache_dir().mkdir(mode=0o700, parents=True, exist_ok=True)  # checked by _record_path
        path = _record_path(key)
        if secret is None or path is None:
            return
        path.parent.mkdir(mode=0o700, exist_ok=True)
        from phc.codegen.load import enforce_cap
        from phc.io import write_bytes

        write_bytes(path, _MAGIC + hmac.new(secret, payload, hashlib.sha256).digest() + payload)
        enforce_cap()


@contextmanager
def recording(args, path: Optional[str] = None, command: str = "simulate") -> Iterator[Recorder]:
    """Record the files `command` on `path` (default ``args.file``) opens for reading and
    whether it shows a warning."""
    path = args.file if path is None else path
    rec = Recorder(args, path, command)
    if not enabled(args):
        yield rec
        return
    rec.data = _read_regular(path, 16 * 2**20)
    from phc.codegen.load import state_dir

    skip = [str(p) for p in (state_dir(), _folder_root()) if p is not None]
    real_open, real_show = os.open, warnings.showwarning

    def open_(path, flags, *a, **k):
        fd = real_open(path, flags, *a, **k)
        try:
            if flags & os.O_ACCMODE == os.O_RDONLY and not k.get("dir_fd") and not a[1:]:
                st = os.fstat(fd)
                name = os.path.realpath(os.fsdecode(path))
                if stat.S_ISREG(st.st_mode) and not any(name.startswith(s + os.sep) for s in skip):
                    rec.files[name] = (st.st_size, st.st_mtime_ns)
        except Exception:  # noqa: BLE001
            rec.data = None  # cannot tell what was read: no record
        return fd

    def show(*a, **k):
        rec.warned = True
        return real_show(*a, **k)

    os.open, warnings.showwarning = open_, show
    try:
        yield rec
    finally:
        os.open = real_open
        if warnings.showwarning is show:
            warnings.showwarning = real_show


def _folder_root() -> Optional[Path]:
    from phc.codegen.load import configured_cache_dir

    return Path(os.path.realpath(configured_cache_dir()))


def _record(compiled, backend: Optional[str]) -> Optional[dict]:
    """The record of a compiled model (sympy is loaded here: the full path ran)."""
    from phc.simulation import _output_span, initial_values, parameter_vector

    dae, mod = compiled.dae, compiled.module
    values, _ = initial_values(compiled, parameter_vector(mod))
    index = {name: j for j, name in enumerate(mod.VARIABLES)}
    symbols = {par.symbol: par for par in dae.parameters}
    depends: Optional[set] = set()
    for iv in dae.initial:
        if iv.expr is None:
            continue
        if not hasattr(iv.expr, "free_symbols"):
            depends = None  # not an expression in parameters: any --param takes the full path
            break
        todo = list(iv.expr.free_symbols)
        while todo and depends is not None:
            sym = todo.pop()
            par = symbols.get(sym)
            if par is None:
                depends = None
            elif par.name not in depends:
                depends.add(par.name)
                if par.expr is not None:
                    todo.extend(par.expr.free_symbols)
        if depends is None:
            break
    from phc.cli import _backend_line  # the line the full path prints

    scene = compiled.scene
    topology = getattr(dae, "topology", None)
    return {
        "name": compiled.name, "source": compiled.source,
        "dae": {
            "name": dae.name, "n_states": dae.n_states, "options": dict(dae.options),
            "units": dict(getattr(dae, "units", None) or {}),
            "equations": [[eq.label, _span_of(eq.span)] for eq in dae.equations],
            "invariants": [[x.label, _span_of(x.span)] for x in dae.invariants],
            "velocity_invariants": [[x.label, _span_of(x.span)] for x in dae.velocity_invariants],
            "initial": [[iv.name, float(values[index[iv.name]]), bool(iv.guess)] for iv in dae.initial],
            "connections": [[a, b, lab, _span_of(s)] for a, b, lab, s in getattr(topology, "connections", ()) or ()],
            "left_out": [list(x) for x in dae.left_out],
        },
        "initial_depends": sorted(depends) if depends is not None else None,
        "certificate": ({"summary": compiled.certificate.summary(), "dict": compiled.certificate.to_dict()}
                        if compiled.certificate is not None else None),
        "scene": {"name": scene.name, "model": str(scene.spec.model)} if scene is not None else None,
        "full_size": compiled.full_size(),
        "output_spans": {name: _span_of(_output_span(compiled, name)) for name in mod.OUTPUTS},
        "backend_line": _backend_line(compiled, backend),
        # the compiled functions' kernel text (phc.codegen.numba_cache.load_cached): loaded from the cache
        "numba": getattr(mod, "KERNEL", None) if getattr(mod, "BACKEND", "numpy") == "numba" else None,
        "warnings": [[d.severity, d.render()] for d in compiled.diagnostics if d.severity == "warning"],
        "written_options": getattr(compiled, "written_options", None),
    }


__all__ = ["CachedModel", "ENV_SWITCH", "FOLDER", "Recorder", "enabled", "lookup", "phc_source_hash",
           "recording"]
