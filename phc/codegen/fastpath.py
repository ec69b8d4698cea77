"""The cached front end of ``phc simulate`` (and ``phc validate``): a second run of an
unchanged model skips reading, elaboration, the symbolic passes and the certificate.

Input: the command-line arguments of ``phc simulate``. Output: on a hit, a :class:`Hit`
holding a :class:`~phc.codegen.compiled.CompiledModel` — the one compiled-model type — built from
the record: the model's description exactly as compiling it made it
(:class:`~phc.codegen.description.ModelDescription`, stored as :meth:`~phc.codegen.description.ModelDescription.to_dict`:
options, initial values, equation labels and their places in the model file, units,
outputs, the certificate's verdict) and the generated module (executed from the source
text kept in the record, as :func:`phc.codegen.load.load_generated` does); beside them
the lines the full path printed (the model's warnings, the backend line, the accuracy
settings the file writes) and the size of a scene's full model. Such a model has no
assembled system (``compiled.dae`` is None). Neither sympy nor pint nor the
model-language classes are imported on a hit.

The record is JSON (never a pickle), signed with HMAC-SHA256 under the per-user key the
compiled backend signs its artefacts with (``$PHC_STATE_DIR``, else
``$XDG_STATE_HOME/phc``, else ``~/.local/state/phc``, file ``cache-key``), and lives in
the private cache directory of the generated modules (:mod:`phc.codegen.load`), under
``front/``; ``phc cache clean`` removes it, and the cache's size cap counts it.

It is found by a key over everything that decides the compilation: the model (or scene)
file's bytes, its path as given, resolved, and the symbolic links on the way (each link's
target text), the working directory (messages cite it), the options that change
compilation (``--no-certify``, ``--backend``, ``--allow-path``, ``--max-memory``), every
``PHC_*`` and ``NUMBA_*`` environment variable, phc's version and a hash of phc's own source files, the
Python version and the installed versions of the libraries the compiler uses. The record
then lists every further file the compilation read *or tried to read* (nested models,
tables, matrices, reference values; every reference :class:`phc.frontend.files.FileAccess` looked
up and every file opened for reading), each by its path as written with what that path
is now (:func:`file_state`): the symbolic links met resolving it, the resolved path, and
the SHA-256 of a regular file, or that it is absent, unreadable or of another kind (a
FIFO, a directory, ...). A hit computes each state again: a repointed link, a file
created where one was missing, a FIFO replaced by a file are all misses. Whatever does
not match, cannot be read or does not verify is a miss: the full path runs and writes a
fresh record. A record at the key's name that does not verify (damaged, renamed, signed
under another key) is reported with one :class:`~phc.errors.CacheWarning`.

The fast path is not taken (the full path runs) for ``--estimate-error`` and ``--profile``
(they need the model itself), for a ``--param`` of a compile-time parameter or of one an
initial value is written in, and when the compilation warned. ``PHC_FRONT_END_CACHE=0``
turns it off. On the compiled (numba) backend the record also keeps the kernel text of the
model's compiled functions, which a hit loads from their signed disk cache
(:func:`phc.codegen.numba_cache.load_cached`, without sympy); functions missing from that
cache make it a miss; on the C back end (``auto`` without numba) it keeps the C text, whose
library a hit loads from its signed cache (:func:`phc.codegen.c_backend.load_source`, which
compiles it again when it is missing). Likewise, when ``auto`` runs a long fixed-step run of a model on NumPy
on numba's compiled step loop (:func:`phc.codegen.backends.for_run`), the record keeps that
module's kernel text, written after the run; a hit for such a run loads it, and one whose
record keeps none (written by a shorter run) or cannot load it is a miss.

``phc compile`` keeps a record of the same kind for each file under a key of its own
(:func:`lookup_compile`): a hit writes the full path's ``.py`` (and ``.c``) text and prints its
lines (the model's warnings, the certificate's verdict, the backend line), with the C library
loaded from its signed cache as for ``phc simulate``.

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
from typing import Iterator, NamedTuple, Optional

from phc.codegen.compiled import CompiledModel, RunCache
from phc.codegen.description import ModelDescription

FORMAT = 3
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
# a hit


class Hit(NamedTuple):
    """What a hit gives the command line: the compiled model (its stored description and
    the generated module) and what the full path printed about it."""

    compiled: CompiledModel
    written_options: dict
    """The accuracy settings the file writes, where (:func:`phc.cli._written_options`)."""
    backend_line: Optional[str]
    """The backend line the full path printed; None on the compiled backend, whose line
    says how its functions were loaded this time (:func:`phc.codegen.backends.describe`)."""


# ---------------------------------------------------------------------------------------
# the key


def enabled(args) -> bool:
    """Whether this `phc simulate` (or `phc compile`) may use (and write) the cached front end."""
    return (os.environ.get(ENV_SWITCH, "1").strip() != "0" and not getattr(args, "estimate_error", False)
            and not getattr(args, "profile", False))


_PHC_HASH: Optional[str] = None


def phc_source_hash() -> str:
    """SHA-256 over phc's own files (names and bytes): a changed phc is a miss."""
    global _PHC_HASH
    if _PHC_HASH is None:
        root = Path(__file__).resolve().parents[1]
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
        "real": os.path.realpath(path), "links": _links(path), "cwd": os.getcwd(),
        "bytes": hashlib.sha256(data).hexdigest(),
        "no_certify": bool(getattr(args, "no_certify", False)), "backend": getattr(args, "backend", None),
        "allow_path": [[d, os.path.realpath(d)] for d in (getattr(args, "allow_path", None) or [])],
        "max_memory": getattr(args, "max_memory", None),
        "env": sorted((k, v) for k, v in os.environ.items()
                      if k.startswith(("PHC_", "NUMBA_")) and k not in _IGNORED_ENV),
    }
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


# ---------------------------------------------------------------------------------------
# what a path is now: the links on the way, where it leads, what is there

_MAX_LINKS = 40


def _absolute(path) -> str:
    """`path` joined to the working directory, nothing resolved (``..`` after a link is the
    link target's parent, as the operating system reads it)."""
    path = os.fsdecode(path)
    return path if os.path.isabs(path) else os.path.join(os.getcwd(), path)


def _links(path) -> list:
    """``[link, target text]`` of each symbolic link met resolving `path`, in order (a
    directory link on the way included); a loop ends the list with ``[link, None]``."""
    out: list = []
    pending = list(reversed(_absolute(path).split(os.sep)))
    resolved = os.sep
    while pending:
        part = pending.pop()
        if part in ("", "."):
            continue
        if part == "..":
            resolved = os.path.dirname(resolved)
            continue
        candidate = os.path.join(resolved, part)
        try:
            st = os.lstat(candidate)
        except OSError:
            resolved = candidate  # absent (or not searchable): the rest as written
            continue
        if not stat.S_ISLNK(st.st_mode):
            resolved = candidate
            continue
        if len(out) >= _MAX_LINKS:
            out.append([candidate, None])
            break
        target = os.readlink(candidate)
        out.append([candidate, target])
        if os.path.isabs(target):
            resolved = os.sep
        pending.extend(reversed(target.split(os.sep)))
    return out


def file_state(path, memo: Optional[dict] = None) -> list:
    """What `path` is now: ``[links, resolved path, content]`` where content is
    ``sha256:…`` for a regular file phc can read, else ``absent``, ``unreadable`` or
    ``mode …`` (a FIFO, a directory, a device, ...). Never opens anything but a regular
    file, and that non-blocking. `memo` (resolved path -> content) hashes a file named by
    several paths once."""
    links = _links(path)
    real = os.path.realpath(_absolute(path))
    if memo is not None:
        if real not in memo:
            memo[real] = _content(real)
        return [links, real, memo[real]]
    return [links, real, _content(real)]


def _content(real: str) -> str:
    try:
        st = os.stat(real)
    except FileNotFoundError:
        return "absent"
    except OSError as err:
        return f"unreadable {err.errno}"
    if not stat.S_ISREG(st.st_mode):
        return f"mode {stat.S_IFMT(st.st_mode):o}"
    content = _read_regular(real, 2**40)
    if content is None:
        return "unreadable"
    return "sha256:" + hashlib.sha256(content).hexdigest()


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
    from phc.codegen.load import _problem, read_key, state_dir

    folder = state_dir()
    if _problem(folder) is not None:  # as phc.codegen.numba_cache.cache_key checks it
        return None
    return read_key(folder / "cache-key")


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


def lookup(args, params: dict) -> Optional[Hit]:
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
    if raw is None:
        return None  # none yet (or not a private regular file: never opened for a blocking read)
    head = len(_MAGIC) + 32
    if len(raw) < head or not raw.startswith(_MAGIC):
        return _damaged(where)
    tag, payload = raw[len(_MAGIC):head], raw[head:]
    if not hmac.compare_digest(tag, hmac.new(secret, payload, hashlib.sha256).digest()):
        return _damaged(where)
    try:
        record = json.loads(payload)
    except ValueError:
        return _damaged(where)
    if (not isinstance(record, dict) or record.get("format") != FORMAT or record.get("key") != key
            or record.get("command") != command):
        return _damaged(where)  # a record copied or renamed over this key's name
    memo: dict = {}
    for name, state in record["inputs"]:  # the files the compilation read or looked for, as they were
        if file_state(name, memo) != state:
            return None
    try:
        os.utime(where)  # most recently used: the cache's size cap evicts the oldest first
    except OSError:
        pass
    return record


def _damaged(where: Path) -> None:
    """A record at this key's name that does not verify: a miss, with one warning (the model
    is compiled again and the record written afresh)."""
    from phc.errors import CacheWarning

    warnings.warn(f"cached front-end record {where} does not verify (damaged, renamed or signed under another "
                  "key); ignored, the model is compiled again", CacheWarning, stacklevel=3)
    return None


def lookup_compile(args, path: str) -> Optional[Hit]:
    """The cached front end of `phc compile` on `path` (one of ``args.files``), or None (a
    miss, or not applicable): the record `phc compile` wrote for the unchanged file, with
    the generated module and, on the C back end, its library loaded from the signed cache
    (the full path's ``.py`` and ``.c`` texts and the lines it printed). Never raises."""
    try:
        return _lookup(args, {}, path, "compile")
    except Exception:  # noqa: BLE001 — a broken record costs the full path, never the command
        return None


def _lookup(args, params: dict, path: Optional[str] = None, command: str = "simulate") -> Optional[Hit]:
    start = time.perf_counter()
    record = _load(args, args.file if path is None else path, command)
    if record is None:
        return None
    description = ModelDescription.from_dict(record["description"])
    for iv in description.initial:
        if params and (iv.depends is None or any(k in iv.depends for k in params)):
            return None  # an initial value written in an overridden parameter: evaluated by the full path
    from phc.codegen.load import load_generated

    module, module_path = load_generated(record["source"], description.name)
    fixed = set(getattr(module, "COMPILE_TIME_PARAMETERS", ()))
    for k, v in params.items():
        if k in fixed and float(v) != float(module.PARAMETER_DEFAULTS[module.PARAMETERS.index(k)]):
            return None  # recompiled by the full path
    if record.get("numba") is not None:  # the compiled backend: its functions from the disk cache, or a miss
        from phc.codegen.numba_cache import load_cached

        module = load_cached(record["numba"], module, record["source"])
        if module is None:
            return None
    elif record.get("c") is not None:  # the C back end (auto without numba): its library from the signed cache
        from phc.codegen.c_backend import load_source

        try:
            module, _ = load_source(record["c"], module, record["source"])
        except Exception:  # noqa: BLE001 — no compiler now, or the library changed: a miss (the full path says why)
            return None
    cache = RunCache(full_size=(record["full_size"],), timings={"load": time.perf_counter() - start})
    warned = tuple(StoredDiagnostic(sev, line) for sev, line in record.get("warnings", ()))
    from phc.codegen.backends import check_choice

    compiled = CompiledModel.from_description(description, record["source"], module, module_path, warned, cache,
                                              backend_request=check_choice(getattr(args, "backend", None)))
    if command == "simulate" and not _run_module(compiled, args, record.get("run_modules") or {}):
        return None
    backend_line = record["backend_line"] if record.get("numba") is None and record.get("c") is None else None
    return Hit(compiled, record.get("written_options") or {}, backend_line)


def _run_module(compiled: CompiledModel, args, kept: dict) -> bool:
    """Whether this run of `compiled` can run from the record: under ``auto``, a long
    fixed-step run of a model on NumPy runs on numba's compiled step loop (the only target
    of :func:`phc.codegen.backends.run_targets`: ``auto`` runs a model on NumPy only when
    the C back end cannot take it), whose module is loaded here from the kernel text the
    record keeps (from numba's signed disk cache) into ``compiled.cache.run_modules``.
    False (a miss: the full path builds the module, and the record is written again with
    it) when the record keeps none or the one kept cannot be loaded."""
    from phc.codegen.backends import run_targets
    from phc.simulation import fixed_step_plan

    method, steps = fixed_step_plan(compiled, t_end=getattr(args, "t_end", None), n_out=getattr(args, "n_out", None),
                                    solver=getattr(args, "solver", None), step=getattr(args, "step", None))
    targets = run_targets(compiled, None, method, steps)
    if not targets:
        return True
    text = kept.get("numba") if "numba" in targets else None
    if text is None:
        return False
    start = time.perf_counter()
    from phc.codegen.numba_cache import load_cached

    module = load_cached(text, compiled.module, compiled.source)
    if module is None:
        return False
    compiled.cache.run_modules["numba"] = module
    timings = compiled.cache.timings
    timings["backend"] = timings.get("backend", 0.0) + time.perf_counter() - start
    return True


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
        self.files: dict[str, Optional[tuple]] = {}
        """Each path read or looked for (as written, made absolute) -> (resolved path, size,
        time) of the file opened, or None (looked up, absent, refused)."""
        self.warned = False

    def note(self, path, opened: Optional[tuple] = None) -> None:
        name = _absolute(path)
        if opened is not None or name not in self.files:
            self.files[name] = opened

    def store(self, compiled: CompiledModel, written_options: Optional[dict] = None) -> None:
        """Write the record of `compiled` and the accuracy settings its file writes (never
        raises; skipped when anything is unusual)."""
        try:
            self._store(compiled, written_options)
        except Exception:  # noqa: BLE001 — the cache is an optimisation
            if os.environ.get("PHC_DEBUG"):
                raise

    def _store(self, compiled: CompiledModel, written_options: Optional[dict]) -> None:
        from phc.codegen.backends import name_of

        backend = name_of(compiled.module)
        if backend not in ("numpy", "numba", "c") or (backend == "numba" and not hasattr(compiled.module, "KERNEL")):
            return
        self._write(_record(compiled, getattr(self.args, "backend", None), written_options))

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
        inputs, memo = [], {}
        for name, opened in sorted(self.files.items()):
            state = file_state(name, memo)
            if opened is not None:
                real, size, mtime = opened
                try:
                    st = os.stat(real)
                except OSError:
                    return
                if state[1] != real or (st.st_size, st.st_mtime_ns) != (size, mtime):
                    return  # changed while it was compiled
            inputs.append([name, state])
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

    skip = [os.path.realpath(p) for p in (state_dir(), _folder_root()) if p is not None]

    def ours(path) -> bool:  # phc's own state and cache: not inputs
        name = os.path.realpath(_absolute(path))
        return any(name == s or name.startswith(s + os.sep) for s in skip)

    def looked_up(path) -> None:  # phc.frontend.files.FileAccess: every reference, found or not
        try:
            if not ours(path):
                rec.note(path)
        except Exception:  # noqa: BLE001
            rec.data = None  # cannot tell what was looked for: no record

    real_open, real_show = os.open, warnings.showwarning

    def open_(path, flags, *a, **k):
        reading = flags & os.O_ACCMODE == os.O_RDONLY and not k.get("dir_fd") and not a[1:]
        try:
            fd = real_open(path, flags, *a, **k)
        except OSError:
            if reading:
                looked_up(path)  # absent or refused: its state is part of the result
            raise
        try:
            if reading and not ours(path):
                st = os.fstat(fd)
                if stat.S_ISREG(st.st_mode):
                    rec.note(path, (os.path.realpath(_absolute(path)), st.st_size, st.st_mtime_ns))
                else:
                    rec.note(path)
        except Exception:  # noqa: BLE001
            rec.data = None  # cannot tell what was read: no record
        return fd

    def show(*a, **k):
        rec.warned = True
        return real_show(*a, **k)

    from phc.frontend.files import observe

    os.open, warnings.showwarning = open_, show
    try:
        with observe(looked_up):
            yield rec
    finally:
        os.open = real_open
        if warnings.showwarning is show:
            warnings.showwarning = real_show


def _folder_root() -> Optional[Path]:
    from phc.codegen.load import configured_cache_dir

    return Path(os.path.realpath(configured_cache_dir()))


def _record(compiled: CompiledModel, backend: Optional[str], written_options: Optional[dict]) -> dict:
    """The record of a compiled model: its description (:mod:`phc.codegen.description`), the
    generated source, and what the command line printed about it."""
    from phc.cli import _backend_line  # the line the full path prints
    from phc.codegen.backends import kept_text

    mod = compiled.module
    runs = {name: kept_text(m) for name, m in compiled.cache.run_modules.items()}
    return {
        "description": compiled.description.to_dict(), "source": compiled.source,
        "full_size": compiled.full_size(),
        "backend_line": _backend_line(compiled, backend),
        # the compiled functions' kernel text (phc.codegen.numba_cache.load_cached): loaded from the cache
        "numba": getattr(mod, "KERNEL", None) if getattr(mod, "BACKEND", "numpy") == "numba" else None,
        # the C text (phc.codegen.c_backend.load_source): its library from the signed cache, or compiled again
        "c": getattr(mod, "C_SOURCE", None) if getattr(mod, "BACKEND", "numpy") == "c" else None,
        # the module a long fixed-step run under `auto` ran on (phc.codegen.backends.for_run), the same way
        "run_modules": {name: text for name, text in runs.items() if text is not None},
        "warnings": [[d.severity, d.render()] for d in compiled.diagnostics if d.severity == "warning"],
        "written_options": written_options,
    }


__all__ = ["ENV_SWITCH", "FOLDER", "Hit", "Recorder", "enabled", "file_state", "lookup", "lookup_compile", "phc_source_hash",
           "recording"]
