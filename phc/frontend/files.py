"""Files a model refers to: resolve them inside the model's tree and open them safely.

A model file travels (it is shared, and CI validates it in pull requests), so the files it
names — nested models (``type: model, file: ...``), CSV input tables and the ``.npz``
matrices of a ``linear_phs`` — are untrusted references. :class:`FileAccess` enforces:

* **containment**: a reference is resolved relative to the file that names it, symlinks
  resolved, and must lie inside the directory of the top-level model (for a scene: the
  scene's directory or its model's directory). Further directories are allowed with
  ``--allow-path DIR`` (repeatable; :func:`allow_paths` in the Python API) or the
  environment variable ``PHC_ALLOW_PATH`` (directories separated by ``os.pathsep``).
  Containment is checked before existence, so a model cannot probe which files exist
  outside its tree;
* **regular files only**: FIFOs, devices, sockets and directories are refused, checked
  with ``os.stat`` before opening and again with ``fstat`` on the opened descriptor (opened
  non-blocking, so a file swapped for a FIFO in between cannot hang the process);
* **bounded size**: :data:`SIZE_LIMITS` per kind of file, overridable with the environment
  variables in :data:`SIZE_LIMIT_ENV` (MiB);
* **bounded nesting**: :data:`MAX_INCLUDE_DEPTH` levels and :data:`MAX_MODEL_INSTANCES`
  copies of nested models in all (each ``type: model`` entry is a copy, so a diamond of
  includes multiplies them).

Refusals raise :class:`FileRefused`; the caller turns it into a located diagnostic at
the referencing ``file:`` key. No message quotes a referenced file's content.

Every reference looked up and every file opened is reported to the callbacks of
:func:`observe` (the path as written, before anything is checked), so a cache of the
result (:mod:`phc.codegen.fastpath`) can key on the files that were read *and* on those that
were absent or refused.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import stat
from pathlib import Path
from typing import BinaryIO, Callable, Iterable, Iterator, Optional

from phc.errors import FileRefused

__all__ = ["FileAccess", "FileRefused", "allow_paths", "observe", "allowed_extra_roots", "size_limit", "SIZE_LIMITS",
           "SIZE_LIMIT_ENV", "MAX_INCLUDE_DEPTH", "MAX_MODEL_INSTANCES", "ALLOW_HINT", "KIND_NAMES"]

MiB = 2 ** 20

SIZE_LIMITS: dict[str, int] = {"model": 16 * MiB, "table": 64 * MiB, "matrices": 256 * MiB}
"""Largest file phc reads per kind of reference, in bytes. For ``matrices`` the limit also
bounds the decompressed size of the arrays used (see :mod:`phc.library.linear`)."""

SIZE_LIMIT_ENV: dict[str, str] = {"model": "PHC_MAX_MODEL_FILE_MB", "table": "PHC_MAX_TABLE_MB",
                                  "matrices": "PHC_MAX_MATRICES_MB"}
"""Environment variables that override :data:`SIZE_LIMITS` (a number of MiB)."""

KIND_NAMES: dict[str, str] = {"model": "nested model file", "table": "table", "matrices": "matrices file"}

MAX_INCLUDE_DEPTH = 32
"""Deepest chain of nested model files (top-level file = depth 0)."""

MAX_MODEL_INSTANCES = 5000
"""Most copies of nested model files one top-level model may expand to."""

ALLOW_ENV = "PHC_ALLOW_PATH"
ALLOW_HINT = (f"move the file next to the model, or pass --allow-path DIR (or set {ALLOW_ENV}) to allow "
              "files under DIR")

_EXTRA_ROOTS: contextvars.ContextVar[tuple[str, ...]] = contextvars.ContextVar("phc_allow_path", default=())
_OBSERVERS: contextvars.ContextVar[tuple[Callable[[str], None], ...]] = contextvars.ContextVar(
    "phc_file_observers", default=())


@contextlib.contextmanager
def observe(callback: Callable[[str], None]) -> Iterator[None]:
    """Within the ``with`` block, `callback` is called with the path of every file a
    :class:`FileAccess` looks up or opens, whether it exists, is refused or is read."""
    token = _OBSERVERS.set(_OBSERVERS.get() + (callback,))
    try:
        yield
    finally:
        _OBSERVERS.reset(token)


def _note(path: str | os.PathLike) -> None:
    for callback in _OBSERVERS.get():
        callback(os.fspath(path))


@contextlib.contextmanager
def allow_paths(directories: Iterable[str | os.PathLike]) -> Iterator[None]:
    """Within the ``with`` block, files under `directories` may be referenced too (what
    ``--allow-path`` does on the command line)."""
    token = _EXTRA_ROOTS.set(tuple(str(d) for d in directories))
    try:
        yield
    finally:
        _EXTRA_ROOTS.reset(token)


def allowed_extra_roots() -> list[Path]:
    """Directories allowed besides the model's own: :func:`allow_paths` and
    ``PHC_ALLOW_PATH``, symlinks resolved."""
    entries = list(_EXTRA_ROOTS.get())
    entries += [e for e in os.environ.get(ALLOW_ENV, "").split(os.pathsep) if e.strip()]
    return [Path(os.path.realpath(e)) for e in entries]


def size_limit(kind: str) -> int:
    """The size limit in bytes for `kind` (``model``, ``table``, ``matrices``)."""
    env = SIZE_LIMIT_ENV.get(kind)
    value = os.environ.get(env, "") if env else ""
    if value.strip():
        try:
            mb = float(value)
        except ValueError:
            mb = float("nan")
        if mb > 0 and mb < 2 ** 40:
            return int(mb * MiB)
    return SIZE_LIMITS[kind]


def _mib(n: int) -> str:
    return f"{n / MiB:.3g} MiB" if n >= MiB else f"{n} bytes"


def _file_kind(mode: int) -> Optional[str]:
    """What a non-regular file is (None for a regular file)."""
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _within(path: Path, root: Path) -> bool:
    return path == root or root in path.parents


class FileAccess:
    """Resolves and opens the files one elaboration refers to (see the module docstring).

    `roots` are the directories references may point into (the directory of the top-level
    file); :func:`allowed_extra_roots` is added at each check. Without roots, a reference
    may point into the directory of the file that names it.
    """

    def __init__(self, roots: Iterable[str | os.PathLike] = ()) -> None:
        self.roots: list[Path] = []
        self._resolved: dict[tuple[str, str, str], tuple[Path, Path]] = {}
        for r in roots:
            self.add_root(r)

    def add_root(self, directory: str | os.PathLike) -> None:
        real = Path(os.path.realpath(directory))
        if real not in self.roots:
            self.roots.append(real)
            self._resolved.clear()

    def _roots_for(self, referrer: Path) -> list[Path]:
        own = self.roots or [Path(os.path.realpath(referrer.parent))]
        return [*own, *allowed_extra_roots()]

    def resolve(self, referrer: str | os.PathLike, ref: str, kind: str) -> tuple[Path, Path]:
        """``(shown, real)`` for reference `ref` written in file `referrer`: the path as
        joined (for messages) and the resolved path to open. Raises :class:`FileRefused`.
        A reference that was accepted once is not checked again (it is opened with
        :meth:`open`, which checks the opened file)."""
        cache_key = (os.path.dirname(os.fspath(referrer)), str(ref), kind)
        if cache_key in self._resolved:
            return self._resolved[cache_key]
        found = self._resolve(referrer, ref, kind)
        self._resolved[cache_key] = found
        return found

    def _resolve(self, referrer: str | os.PathLike, ref: str, kind: str) -> tuple[Path, Path]:
        what = KIND_NAMES[kind]
        if not isinstance(ref, str) or not ref.strip():
            raise FileRefused("name", f"{what} name is empty", "name a file relative to this model")
        if "\x00" in ref:
            raise FileRefused("name", f"{what} name contains a NUL character")
        referrer = Path(referrer)
        shown = referrer.parent / ref
        _note(shown)  # looked for: what becomes of it (read, absent, refused) is part of the result
        real = Path(os.path.realpath(shown))
        roots = self._roots_for(referrer)
        if not any(_within(real, root) for root in roots):
            raise FileRefused("outside", f"{what} `{ref}` lies outside the directory of the top-level file "
                              "(symlinks resolved); phc reads referenced files only inside it", ALLOW_HINT)
        try:
            st = os.stat(real)
        except FileNotFoundError:
            raise FileRefused("missing", f"{what} `{ref}` not found"
                              + (f" (looked for `{shown}`)" if str(shown) != ref else "")) from None
        except OSError as err:
            raise FileRefused("unreadable", f"cannot read {what} `{ref}`: {err.strerror or type(err).__name__}"
                              ) from None
        self._check_stat(st, ref, kind)
        return shown, real

    def _check_stat(self, st: os.stat_result, ref: str, kind: str) -> None:
        what = KIND_NAMES[kind]
        other = _file_kind(st.st_mode)
        if other is not None:
            raise FileRefused("kind", f"{what} `{ref}` is {other}; phc reads only regular files",
                              "name a regular file")
        limit = size_limit(kind)
        if st.st_size > limit:
            raise FileRefused("size", f"{what} `{ref}` is {_mib(st.st_size)}, above the limit of {_mib(limit)}",
                              f"set {SIZE_LIMIT_ENV[kind]} (MiB) to raise the limit")

    def open(self, real: Path, ref: str, kind: str) -> BinaryIO:
        """Open a resolved path for reading: non-blocking, not following a final symlink,
        and refused unless the opened descriptor is a regular file within the size limit."""
        what = KIND_NAMES[kind]
        _note(real)
        flags = (os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0)
                 | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_BINARY", 0))
        try:
            fd = os.open(real, flags)
        except OSError as err:
            raise FileRefused("unreadable", f"cannot read {what} `{ref}`: {err.strerror or type(err).__name__}"
                              ) from None
        try:
            self._check_stat(os.fstat(fd), ref, kind)
            return os.fdopen(fd, "rb")
        except BaseException:
            os.close(fd)
            raise

    def read_bytes(self, real: Path, ref: str, kind: str) -> bytes:
        """The whole content of a resolved path (see :meth:`open`), at most the size limit."""
        limit = size_limit(kind)
        with self.open(real, ref, kind) as fh:
            try:
                data = fh.read(limit + 1)
            except OSError as err:
                raise FileRefused("unreadable", f"cannot read {KIND_NAMES[kind]} `{ref}`: "
                                  f"{err.strerror or type(err).__name__}") from None
        if len(data) > limit:
            raise FileRefused("size", f"{KIND_NAMES[kind]} `{ref}` is larger than the limit of {_mib(limit)}",
                              f"set {SIZE_LIMIT_ENV[kind]} (MiB) to raise the limit")
        return data
