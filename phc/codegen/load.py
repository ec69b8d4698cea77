"""Load generated residual modules; keep a private on-disk cache of their source.

Input: the module's source text (from :mod:`phc.codegen.printer`). Output: the executed
module and the path of its cached copy.

The source is compiled *from the text in memory* (``compile(source, path, "exec")`` into a
fresh module object): the file on disk is written for people and tools to read or import
on their own, never read back by phc. So nobody who can write the cache directory can make
phc run other code by swapping the file between a check and an import, or by planting a
``__pycache__`` entry (an unchecked hash-based ``.pyc``, PEP 552) that an importer would
prefer; and phc never writes bytecode for generated modules.

The cache lives in ``$PHC_CACHE_DIR``, else ``$XDG_CACHE_HOME/phc``, else ``~/.cache/phc``.
It is created private (mode 0700) and refused when another user owns it or others may
write it, or when a directory on the way to it (as written or resolved) is owned by
another user or writable by others without the sticky bit (they could swap it for a
link); phc then uses a private temporary directory for the run and says so (there is no
shared ``/tmp`` fallback). Files are named by the SHA-256 of their content; the cache is
capped (``$PHC_CACHE_MAX_MB``, default 512 MiB) by evicting the least recently used files.
``phc cache info`` and ``phc cache clean`` show and empty it.
"""

from __future__ import annotations

import atexit
import hashlib
import math
import os
import shutil
import stat
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Optional

from phc.errors import CacheWarning
from phc.io import write_bytes as write_atomic  # temporary file + rename

DEFAULT_CAP_MB = 512
"""Default size cap of the cache in MiB (``$PHC_CACHE_MAX_MB`` overrides it)."""

_PRIVATE_FALLBACK: Path | None = None


def configured_cache_dir() -> Path:
    """The cache directory phc is configured to use (it may not exist yet)."""
    root = os.environ.get("PHC_CACHE_DIR")
    if root:
        return Path(root)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "phc"


def _problem(path: Path) -> str | None:
    """Why `path` is not a private cache directory, or None if it is."""
    try:
        st = os.lstat(path)
    except OSError as err:
        return f"cannot be used ({err.strerror})"
    if stat.S_ISLNK(st.st_mode):
        return "is a symbolic link"
    if not stat.S_ISDIR(st.st_mode):
        return "is not a directory"
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        return f"is owned by another user (uid {st.st_uid})"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"is writable by other users (mode {stat.S_IMODE(st.st_mode):o}); run `chmod go-w {path}`"
    if not os.access(path, os.W_OK | os.X_OK):
        return "is not writable"
    return _unsafe_parent(path)


def _parents(path: str) -> list[str]:
    """The directories above the absolute `path`, nearest first (``Path(path).parents`` as strings,
    without pathlib's parsing: a run checks its cache directories several times)."""
    out = []
    parent = os.path.dirname(path)
    while parent != path:
        out.append(parent)
        path, parent = parent, os.path.dirname(parent)
    return out


def _unsafe_parent(path: Path) -> str | None:
    """Why a directory on the way to `path` (as written or resolved) lets another user
    rename or replace `path` — owned by another user (not root), or writable by others
    without the sticky bit (``/tmp`` has it) — or None. Checking only `path` itself left a
    race: its parent's other writers could swap it for a link between check and use."""
    seen: set[str] = set()
    for candidate in (os.path.abspath(path), os.path.realpath(path)):
        for parent in _parents(candidate):
            if parent in seen:
                continue
            seen.add(parent)
            try:
                st = os.stat(parent)
            except OSError as err:
                return f"cannot be used ({parent}: {err.strerror})"
            if hasattr(os, "getuid") and st.st_uid not in (0, os.getuid()):
                return f"lies inside {parent}, which another user owns (uid {st.st_uid})"
            sticky = st.st_mode & stat.S_ISVTX
            others = st.st_mode & stat.S_IWOTH or (
                st.st_mode & stat.S_IWGRP and hasattr(os, "getgid") and st.st_gid != os.getgid())
            if others and not sticky:
                return (f"lies inside {parent}, which is writable by other users (mode {stat.S_IMODE(st.st_mode):o}) "
                        "who could replace it; use a directory inside a private one")
    return None


def cache_dir() -> Path:
    """The private cache directory (created with mode 0700 if missing).

    A directory that another user owns or others may write is refused: phc then uses a
    private temporary directory for the rest of the process and warns once.
    """
    global _PRIVATE_FALLBACK
    path = configured_cache_dir()
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        problem = _problem(path)
    except OSError as err:
        problem = f"cannot be created ({err.strerror})"
    if problem is None:
        return path
    if _PRIVATE_FALLBACK is None or not _PRIVATE_FALLBACK.is_dir():
        _PRIVATE_FALLBACK = Path(tempfile.mkdtemp(prefix="phc-cache-"))  # mode 0700, ours
        atexit.register(shutil.rmtree, _PRIVATE_FALLBACK, ignore_errors=True)
        warnings.warn(f"cache directory {path} {problem}; using the private temporary directory "
                      f"{_PRIVATE_FALLBACK} for this run (set PHC_CACHE_DIR to a private directory)",
                      CacheWarning, stacklevel=2)
    return _PRIVATE_FALLBACK


def source_hash(source: str) -> str:
    return hashlib.sha256(source.encode()).hexdigest()[:20]


def load_generated(source: str, name: str = "model") -> tuple[ModuleType, Path]:
    """Execute the generated module from `source` (in memory); returns (module, path).

    The cached copy at `path` is (re)written when missing or different, for readers; the
    module object is built from `source` itself, so the file's content never matters.
    """
    digest = source_hash(source)
    folder = cache_dir()
    path = folder / f"phc_{digest}.py"
    data = source.encode()
    try:
        same = path.is_file() and not path.is_symlink() and path.read_bytes() == data
        if same:
            os.utime(path)  # most recently used
        else:
            if path.is_symlink() or path.exists():
                path.unlink()
            write_atomic(path, data)
            enforce_cap(folder)
    except OSError as err:  # a full or read-only disk costs the readable copy, not the run
        warnings.warn(f"could not write the generated module to {path}: {err.strerror}", CacheWarning,
                      stacklevel=2)
    module = ModuleType(f"phc_generated_{digest}", None)
    module.__file__ = str(path)
    code = compile(source, str(path), "exec", dont_inherit=True)
    exec(code, module.__dict__)  # safe: phc's own printer output (no model text as code), from memory
    return module, path


# ---------------------------------------------------------------------------------------
# size cap, info and clean


CAP_ENV = "PHC_CACHE_MAX_MB"
MAX_CAP_MB = 2**40
"""The largest size cap of the cache in MiB (1 EiB)."""


def cap_problem() -> Optional[str]:
    """What is wrong with ``$PHC_CACHE_MAX_MB`` (the command line refuses it, in one line),
    or None when it is unset or a number of MiB from 0 to :data:`MAX_CAP_MB`."""
    text = os.environ.get(CAP_ENV)
    if text is None or not text.strip():
        return None
    try:
        mb = float(text)
    except ValueError:
        return f"{CAP_ENV}: `{text}` is not a number of MiB; write e.g. 512"
    if not 0 <= mb <= MAX_CAP_MB:
        return f"{CAP_ENV} must be a number of MiB from 0 to {MAX_CAP_MB}, got `{text}`"
    return None


def _cap_bytes() -> int:
    """The size cap in bytes; from Python, a malformed ``$PHC_CACHE_MAX_MB`` is the default
    and one out of range the nearest bound (the command line refuses both)."""
    try:
        mb = float(os.environ.get(CAP_ENV, DEFAULT_CAP_MB))
    except ValueError:
        mb = DEFAULT_CAP_MB
    if math.isnan(mb):
        mb = DEFAULT_CAP_MB
    return int(min(max(mb, 0), MAX_CAP_MB) * 2**20)


def _entries(folder: Path) -> list[tuple[float, int, Path]]:
    """(last use, size, path) of phc's files in the cache (generated modules, bench references,
    the signed artefacts of the compiled backends, the records of the cached front end, pint's
    parsed unit definitions)."""
    out = []
    for pattern in ("phc_*.py", "bench/ref_*.npz", "numba/phc_numba_*", "c/phc_c_*", "front/*.json",
                    "units/pint-*.bundle"):
        for p in folder.glob(pattern):
            try:
                st = p.lstat()
            except OSError:
                continue
            if stat.S_ISREG(st.st_mode):
                out.append((max(st.st_mtime, st.st_atime), st.st_size, p))
    return out


def enforce_cap(folder: Path | None = None, cap: int | None = None) -> int:
    """Evict least recently used entries until the cache is under its cap; returns bytes freed."""
    folder = cache_dir() if folder is None else folder
    cap = _cap_bytes() if cap is None else cap
    entries = sorted(_entries(folder))
    total = sum(size for _, size, _ in entries)
    freed = 0
    for _, size, p in entries:
        if total <= cap:
            break
        try:
            p.unlink()
        except OSError:
            continue
        total -= size
        freed += size
    return freed


@dataclass(frozen=True)
class CacheInfo:
    path: Path
    files: int
    bytes: int
    cap_bytes: int


def info() -> CacheInfo:
    folder = cache_dir()
    entries = _entries(folder)
    return CacheInfo(folder, len(entries), sum(size for _, size, _ in entries), _cap_bytes())


def clean() -> tuple[int, int]:
    """Remove every cached module, bench reference, compiled artefact, front-end record
    (:mod:`phc.codegen.fastpath`) and unit-definitions bundle (:mod:`phc.frontend.pint_cache`); returns (files,
    bytes) removed."""
    folder = cache_dir()
    files = size = 0
    for _, n, p in _entries(folder):
        try:
            p.unlink()
        except OSError:
            continue
        files += 1
        size += n
    pycache = folder / "__pycache__"  # left by an earlier phc that imported from the cache
    if pycache.is_dir() and not pycache.is_symlink():
        for p in pycache.glob("phc_*.pyc"):
            try:
                p.unlink()
            except OSError:
                pass
    return files, size


__all__ = ["CacheInfo", "CacheWarning", "cache_dir", "clean", "configured_cache_dir", "enforce_cap", "info",
           "load_generated", "source_hash", "write_atomic"]


def state_dir() -> Path:
    """phc's per-user state directory (`PHC_STATE_DIR`, else `$XDG_STATE_HOME/phc`, else
    `~/.local/state/phc`): where the key signing cached artefacts lives."""
    root = os.environ.get("PHC_STATE_DIR")
    if root:
        return Path(root)
    xdg = os.environ.get("XDG_STATE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".local" / "state") / "phc"


KEY_BYTES = 32


def read_key(path: Path) -> Optional[bytes]:
    """The signing key at `path` when it is a private regular file of :data:`KEY_BYTES` bytes
    owned by this user; None otherwise (a special file is refused without blocking:
    checked with ``lstat`` first, opened non-blocking)."""
    try:
        if not stat.S_ISREG(os.lstat(path).st_mode):
            return None  # a FIFO, device or socket is never opened (a FIFO would block)
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
                     | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if (not stat.S_ISREG(st.st_mode) or st.st_mode & 0o077
                or (hasattr(os, "getuid") and st.st_uid != os.getuid())):
            return None
        data = os.read(fd, KEY_BYTES + 1)
    finally:
        os.close(fd)
    return data if len(data) == KEY_BYTES else None
