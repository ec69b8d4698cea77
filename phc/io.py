"""Result files: checked before the work, written atomically.

Every file phc writes (simulation results ``.csv``/``.npz``, the generated module of
``phc compile -o``, graphs, plots, animations, benchmark tables) goes through
:func:`atomic_write`: the content is written to a temporary file in the target's
directory (named ``.<target name>.<random>.part``, never the target's own name), flushed
to disk and renamed over the target with :func:`os.replace`. A process killed while
writing therefore leaves either the previous file or the complete new one, never a
truncated file; at most a hidden ``.part`` file remains.

:func:`check_output_file` and :func:`check_output_dir` are called by the command line
before a run, so that a wrong ``--out`` is reported at once instead of after the whole
simulation.
"""

from __future__ import annotations

import csv
import os
import signal
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Iterable, Iterator, Sequence, Union

from phc.errors import OutputPathError

PathLike = Union[str, os.PathLike]

__all__ = ["OutputPathError", "check_output_file", "check_output_dir", "atomic_write", "write_text",
           "write_bytes", "TEMP_SUFFIX", "csv_rows"]

TEMP_SUFFIX = ".part"
"""Suffix of the temporary files (hidden: their names start with a dot)."""

_CSV_FIELD_LIMIT = 2**31 - 1  # a C long everywhere (the csv module refuses more on Windows)
_CSV_LOCK = threading.Lock()


def csv_rows(lines: Iterable[str]) -> list[list[str]]:
    """The rows of CSV text (``csv.reader(lines)``), fields of any length.

    The csv module refuses a field longer than ``csv.field_size_limit()`` (131 072
    characters by default) with ``csv.Error``; phc's own files (a sweep's messages) may
    hold longer ones. The limit is raised for this read only and then restored: the
    process keeps its own setting. Raises ``csv.Error`` for other malformed CSV."""
    with _CSV_LOCK:
        previous = csv.field_size_limit()
        csv.field_size_limit(max(previous, _CSV_FIELD_LIMIT))
        try:
            return list(csv.reader(lines))
        finally:
            csv.field_size_limit(previous)


def _probe_directory(folder: Path, option: str, shown: str) -> None:
    """Raise unless `folder` is an existing directory in which a file can be created."""
    if not folder.exists():
        raise OutputPathError(f"{option} `{shown}`: the folder `{folder}` does not exist; create it first")
    if not folder.is_dir():
        raise OutputPathError(f"{option} `{shown}`: `{folder}` is not a folder")
    try:  # os.access is not enough (root, read-only file systems, ACLs): create a file
        fd, probe = tempfile.mkstemp(prefix=".phc-probe.", suffix=TEMP_SUFFIX, dir=folder)
    except OSError as err:
        reason = err.strerror or type(err).__name__
        raise OutputPathError(f"{option} `{shown}`: cannot write into the folder `{folder}` ({reason.lower()}); "
                              "choose another place") from None
    os.close(fd)
    os.unlink(probe)


@contextmanager
def _path_errors(option: str, shown: str) -> Iterator[None]:
    """An error of the file system about the path itself (a name too long, a loop of
    symbolic links) as an OutputPathError."""
    try:
        yield
    except OSError as err:
        reason = (err.strerror or type(err).__name__).lower()
        raise OutputPathError(f"{option} `{shown}` cannot be used ({reason}); choose another name") from None


def check_output_file(path: PathLike, option: str, suffixes: Sequence[str]) -> Path:
    """Check, before any work, that `path` can be written as a result file.

    Parameters
    ----------
    path : str or PathLike
        The target file.
    option : str
        The command-line option that named it (for the message), e.g. ``"--out"``.
    suffixes : sequence of str
        Accepted extensions, with the dot (``(".csv", ".npz")``).

    Returns
    -------
    Path
        The target.

    Raises
    ------
    OutputPathError
        The extension is not one of `suffixes`, the target is a directory, or its folder
        does not exist or is not writable.
    """
    shown = os.fspath(path)
    target = Path(path)
    if target.suffix.lower() not in tuple(s.lower() for s in suffixes):
        raise OutputPathError(f"{option} must end in {' or '.join(suffixes)}, got `{shown}`")
    with _path_errors(option, shown):
        if target.is_dir():
            raise OutputPathError(f"{option} `{shown}` is a folder; give a file name such as "
                                  f"`{target / ('results' + suffixes[0])}`")
        if target.exists() and not target.is_file():
            raise OutputPathError(f"{option} `{shown}` exists and is not a regular file; choose another name")
        _probe_directory(target.parent, option, shown)
    return target


def check_output_dir(path: PathLike, option: str) -> Path:
    """Check that `path` is a writable folder, or can be created as one (its nearest
    existing ancestor is a writable folder). Nothing is created.

    Raises
    ------
    OutputPathError
        `path` exists and is not a folder, or nothing can be created where it would go.
    """
    shown = os.fspath(path)
    with _path_errors(option, shown):
        return _check_output_dir(Path(path), option, shown)


def _check_output_dir(folder: Path, option: str, shown: str) -> Path:
    if folder.exists():
        if not folder.is_dir():
            raise OutputPathError(f"{option} `{shown}` is a file, not a folder; give a folder (it is created "
                                  "if missing)")
        _probe_directory(folder, option, shown)
        return folder
    ancestor = folder.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputPathError(f"{option} `{shown}`: `{ancestor}` is a file, so the folder cannot be created")
    _probe_directory(ancestor, option, shown)
    return folder


def _file_mode(target: Path) -> int:
    """Permission bits for a new file: the replaced file's, else the default under the umask."""
    try:
        return target.stat().st_mode & 0o7777
    except OSError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask


@contextmanager
def finish_before_interrupt() -> Iterator[list]:
    """Hold Ctrl-C (SIGINT) until the block ends, then raise ``KeyboardInterrupt``: a results
    file being written is finished, not lost (the block's list holds the signal if one came,
    for the caller's message). Outside the main thread, or under a handler that is not
    Python's default one (a caller's own), the block runs as it is."""
    held: list = []
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield held
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        yield held
    finally:
        signal.signal(signal.SIGINT, previous)
    if held:
        raise KeyboardInterrupt


@contextmanager
def atomic_write(path: PathLike, mode: str = "wb", *, encoding: str | None = None,
                 newline: str | None = None) -> Iterator[IO]:
    """Open a temporary file next to `path` for writing; on a clean exit it replaces `path`.

    Parameters
    ----------
    path : str or PathLike
        The target. Its folder must exist.
    mode : {"wb", "w"}
        Binary or text.
    encoding, newline : optional
        As for :func:`open` (text mode; the encoding defaults to UTF-8).

    Yields
    ------
    file object
        Write the content into it. If the block raises (``KeyboardInterrupt`` included),
        the temporary file is removed and `path` is left as it was.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write: mode must be 'w' or 'wb', not {mode!r}")
    target = Path(path)
    folder = target.parent
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=TEMP_SUFFIX, dir=folder)
    try:
        if mode == "w":
            fh = os.fdopen(fd, "w", encoding=encoding or "utf-8", newline=newline)
        else:
            fh = os.fdopen(fd, "wb")
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, _file_mode(target))
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def write_text(path: PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write `text` to `path` atomically; returns the path."""
    with atomic_write(path, "w", encoding=encoding) as fh:
        fh.write(text)
    return Path(path)


def write_bytes(path: PathLike, data: bytes) -> Path:
    """Write `data` to `path` atomically; returns the path."""
    with atomic_write(path, "wb") as fh:
        fh.write(data)
    return Path(path)
