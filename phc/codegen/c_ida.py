"""phc's native IDA driver: ``c_runtime/ida_driver.c`` built against the machine's SUNDIALS.

A run on the C back end (:mod:`phc.codegen.c_backend`) can have IDA call the model's compiled
residual and Jacobian directly, in C, and take its steps in a C loop
(:mod:`phc.simulation.ida_native` runs it). This module finds SUNDIALS (:func:`find_sundials`),
builds the driver once per machine, SUNDIALS and phc version (phc's signed cache of compiled
code, as the C step loop's library: :func:`phc.codegen.c_backend.runtime_library`), and says
why it cannot when it cannot (:func:`library` returns None, :func:`why_not` the reason).

SUNDIALS is the machine's own, reached through its public C API (headers and shared libraries;
version 6 or 7, in double precision): Debian/Ubuntu ``apt install libsundials-dev``,
conda-forge ``sundials``, Homebrew ``sundials``. scikit-sundae's copy inside its wheel is not
used (its libraries' names are its private packaging). Where SUNDIALS is looked for, in order:
``$SUNDIALS_DIR``, ``$CONDA_PREFIX``, the prefix ``pkg-config`` gives for ``sundials_ida`` (kept in
phc's cache until pkg-config's search directories change: :func:`pkg_config_prefix`),
``/usr/local``, ``/usr``, ``/opt/homebrew``, ``/usr/local/opt/sundials``: the first prefix with
``include/ida/ida.h`` and ``libsundials_ida`` in ``lib``, ``lib64`` or the platform's
multiarch directory (looked at in each process).
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
import sys
import sysconfig
import threading
from pathlib import Path
from typing import Optional

SOURCE = Path(__file__).resolve().parent / "c_runtime" / "ida_driver.c"
"""The driver's C text (shipped in the package)."""

ABI = 2
"""``PHC_IDA_ABI`` of the ida_driver.c this module binds."""

LOOK_MARKER = "/* PHC_LOOK_LOGIC */"
"""The line of ida_driver.c that :func:`source` replaces with the routine look's decisions
(:data:`LOOK_TRANSLATED` of :mod:`phc.simulation.look_cadence`, translated)."""

LOOK_TRANSLATED = ("cadence_after", "brackets_minimum", "crawls", "hermite", "golden_search")
"""The functions of :mod:`phc.simulation.look_cadence` the driver's routine look calls."""

LI_N, LF_N = 10, 8
"""Sizes of the routine look's state arrays (ida_driver.c's ``LI_N``, ``LF_N``; checked when the driver
is loaded). Their entries: :mod:`phc.simulation.ida_native` (``LI_*``, ``LF_*``)."""

PHC_LOOK = 2
"""What ``phc_ida_advance`` returns when a look is Python's monitor's to make."""

LOOK_NOT_CLEAR, LOOK_MINIMUM, LOOK_CRAWL = 1, 2, 3
"""Why (``li[LI_FLAG]``): the condition estimate does not clear the look; the look and the two before
bracket a minimum of the conditioning; IDA crawls."""

_SOURCE_TEXT: Optional[str] = None

TRANSLATOR = Path(__file__).resolve().parent / "c_translate.py"
"""phc.codegen.c_translate's file (a key of the cached translation; the module is imported only to translate)."""


def make_source() -> str:
    """The driver's whole C text, translated anew (:func:`source` keeps it)."""
    from phc.codegen import c_steps, c_translate
    from phc.simulation import look_cadence

    text = SOURCE.read_text(encoding="utf-8")
    if text.count(LOOK_MARKER) != 1:
        raise RuntimeError(f"{SOURCE} must have the line {LOOK_MARKER} once (a phc bug: please report it)")
    ops = {"_ratio_at_time": c_translate.Op("op_ratio_at_time", ("ws", "f"), ("f", "b", "b"))}
    logic = (c_translate.PRELUDE + "\n"
             + c_translate.Translator(look_cadence, look_cadence.C_SIGNATURES, ops).translate(LOOK_TRANSLATED))
    return c_steps.with_dense_lu(text.replace(LOOK_MARKER, logic.rstrip("\n")), SOURCE.name)


def source() -> str:
    """The driver's whole C text: ida_driver.c with the dense LU and routine look shared with the
    fixed-step loop (:func:`phc.codegen.c_steps.with_dense_lu`) and the translated
    :data:`LOOK_TRANSLATED` in place of its marker lines; once per process, and kept in the signed
    cache keyed by the files it is made from (:func:`phc.codegen.c_backend.translated_text`)."""
    global _SOURCE_TEXT
    if _SOURCE_TEXT is None:
        from phc.codegen import c_backend, c_steps
        from phc.simulation import look_cadence

        _SOURCE_TEXT = c_backend.translated_text(
            "ida_driver", (SOURCE, c_steps.DENSE_LU, __file__, c_steps.__file__, TRANSLATOR, look_cadence.__file__),
            make_source)
    return _SOURCE_TEXT

FLAGS = ("-std=c99", "-O2", "-fPIC", "-shared", "-ffp-contract=off")
"""The driver's flags (before SUNDIALS' ``-I``): it is glue around IDA's own code, which SUNDIALS'
build compiled."""

LIBRARIES = ("sundials_ida", "sundials_sunlinsoldense", "sundials_sunmatrixdense", "sundials_nvecserial")
"""SUNDIALS' libraries the driver links (and ``sundials_core`` where it exists: SUNDIALS 7)."""

_LOCK = threading.Lock()
_LIBRARY = None
"""The loaded driver once built; False when it cannot be built here (:data:`_WHY` says why)."""
_WHY = ""


def _pkg_config(*args: str) -> Optional[str]:
    """pkg-config's answer (stripped), or None when it fails or says nothing."""
    try:
        done = subprocess.run(["pkg-config", *args], capture_output=True, text=True, timeout=30,
                              stdin=subprocess.DEVNULL)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 and done.stdout.strip() else None


def _stat(path: str) -> Optional[list[int]]:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return [st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns]


PC_FILE = "sundials_ida.pc"
"""The pkg-config file whose ``prefix`` is looked up."""


def _pc_stats(dirs) -> dict[str, Optional[list[int]]]:
    """The stat of each of pkg-config's search directories and of :data:`PC_FILE` in it (None where
    absent): a SUNDIALS installed, removed or moved where pkg-config looks changes one of them (a
    directory's modification time changes when a file is added, removed or renamed in it)."""
    out = {}
    for folder in dirs:
        out[folder] = _stat(folder)
        out[os.path.join(folder, PC_FILE)] = _stat(os.path.join(folder, PC_FILE))
    return out


def pkg_config_prefix() -> Optional[Path]:
    """The prefix ``pkg-config --variable=prefix sundials_ida`` gives (None: no pkg-config, or it
    knows no SUNDIALS), kept in phc's signed cache so that a later process does not run pkg-config
    again (a child process of about 8 ms CPU): the record is named by a digest of pkg-config's
    executable (path and stat) and the ``PKG_CONFIG*`` environment variables, and holds the stat of
    every directory pkg-config searches and of ``sundials_ida.pc`` in each
    (:func:`_pc_stats`); any difference asks pkg-config again. A cache that is off or unusable:
    pkg-config is asked each time."""
    import hashlib
    import json

    from phc import __version__
    from phc.codegen import c_backend
    from phc.codegen.load import write_atomic
    from phc.codegen.numba_cache import _read_private, _signed, _verified, signed_cache_dir

    exe = shutil.which("pkg-config")
    if exe is None:
        return None
    env = sorted((k, v) for k, v in os.environ.items() if k.startswith("PKG_CONFIG"))
    material = json.dumps([__version__, exe, os.path.realpath(exe), _stat(exe), env])
    folder, key = signed_cache_dir(c_backend.c_cache_dir())[:2] if c_backend._cache_on() else (None, None)
    name = f"phc_sundials_pc_{hashlib.sha256(material.encode()).hexdigest()[:24]}.json"
    file = None if folder is None else folder / name
    if file is not None:
        data = _read_private(str(file))
        payload = _verified(key, data, file.name) if data is not None else None
        try:
            record = json.loads(payload.decode("utf-8")) if payload is not None else None
            if record is not None and _pc_stats(record["dirs"]) == record["stats"]:
                return None if record["prefix"] is None else Path(record["prefix"])
        except (ValueError, KeyError, TypeError):  # a record of another layout: asked again
            pass
    # where pkg-config looks: $PKG_CONFIG_PATH, then $PKG_CONFIG_LIBDIR or its built-in path
    searched = _pkg_config("--variable=pc_path", "pkg-config")
    dirs = None if searched is None else [
        d for var in ("PKG_CONFIG_PATH", "PKG_CONFIG_LIBDIR") for d in os.environ.get(var, "").split(os.pathsep) if d
    ] + [d for d in searched.split(os.pathsep) if d]
    stats = None if dirs is None else _pc_stats(dirs)  # (before asking: a change meanwhile is seen next time)
    prefix = _pkg_config("--variable=prefix", "sundials_ida")
    if file is not None and stats is not None:  # (a pkg-config that does not say where it looks: not kept)
        record = {"dirs": dirs, "stats": stats, "prefix": prefix}
        try:
            write_atomic(file, _signed(key, json.dumps(record).encode("utf-8"), file.name))
        except OSError:  # a full or read-only disk costs the kept answer, not the run
            pass
    return None if prefix is None else Path(prefix)


def _prefixes() -> list[Path]:
    found = []
    for var in ("SUNDIALS_DIR", "CONDA_PREFIX"):
        if os.environ.get(var):
            found.append(Path(os.environ[var]))
    prefix = pkg_config_prefix()
    if prefix is not None:
        found.append(prefix)
    found += [Path("/usr/local"), Path("/usr"), Path("/opt/homebrew"), Path("/usr/local/opt/sundials")]
    return found


def _lib_dirs(prefix: Path) -> list[Path]:
    dirs = [prefix / "lib", prefix / "lib64"]
    multiarch = sysconfig.get_config_var("MULTIARCH")
    if multiarch:
        dirs.insert(0, prefix / "lib" / multiarch)
    return dirs


def _has(folder: Path, name: str) -> bool:
    suffix = ".dylib" if sys.platform == "darwin" else ".so"
    return (folder / f"lib{name}{suffix}").exists()


def find_sundials() -> tuple[Optional[tuple[Path, Path, tuple[str, ...]]], str]:
    """((include dir, library dir, the libraries to link), "") of the first SUNDIALS found
    (see the module docstring), else (None, why none was found)."""
    for prefix in _prefixes():
        include = prefix / "include"
        if not (include / "ida" / "ida.h").exists():
            continue
        for folder in _lib_dirs(prefix):
            if all(_has(folder, name) for name in LIBRARIES):
                names = LIBRARIES + (("sundials_core",) if _has(folder, "sundials_core") else ())
                return (include, folder, names), ""
    return None, ("SUNDIALS' headers and libraries were not found (looked in $SUNDIALS_DIR, $CONDA_PREFIX, "
                  "pkg-config's sundials_ida, /usr/local, /usr, Homebrew); install them (`apt install "
                  "libsundials-dev`, `conda install -c conda-forge sundials`, `brew install sundials`) or set "
                  "$SUNDIALS_DIR")


def library():
    """The driver's library (built, or loaded from phc's signed cache, once per process), or None
    when it cannot be built here (:func:`why_not`)."""
    global _LIBRARY, _WHY
    if switched_off():
        return None
    with _LOCK:
        if _LIBRARY is None:
            try:
                _LIBRARY = _build()
            except Exception as err:  # noqa: BLE001 — scikit-sundae runs instead, and the run says why once
                _LIBRARY, _WHY = False, f"{type(err).__name__}: {err}"
        return _LIBRARY or None


def switched_off() -> bool:
    """Whether ``PHC_NATIVE_IDA=0`` (or no, false, off) switches the driver off (read at each run)."""
    return os.environ.get("PHC_NATIVE_IDA", "1").strip().lower() in ("0", "no", "false", "off")


def why_not() -> str:
    """Why the driver is not used in this process ("" when it is, was not tried, or is switched off)."""
    return "" if switched_off() else _WHY


def _build():
    global _WHY
    from phc.codegen import c_backend

    found, why = find_sundials()
    if found is None:
        _WHY = why
        return False
    include, folder, names = found
    flags = FLAGS + (f"-I{include}",)
    libs = (f"-L{folder}", f"-Wl,-rpath,{folder}") + tuple(f"-l{name}" for name in names)
    lib, why = c_backend.runtime_library(source(), flags, libs)
    if lib is None:
        _WHY = why
        return False
    version = (ctypes.c_int64 * 10)()
    lib.phc_ida_version.argtypes, lib.phc_ida_version.restype = [ctypes.c_void_p], None
    lib.phc_ida_version(ctypes.addressof(version))
    if list(version[:1]) + list(version[4:]) != [ABI, LI_N, LF_N, PHC_LOOK, LOOK_NOT_CLEAR, LOOK_MINIMUM, LOOK_CRAWL]:
        _WHY = "ida_driver.c was written for another interface (a phc bug: please report it)"
        return False
    P, I, D = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
    lib.phc_ida_create.argtypes = [I, I, P, P, P, P, P, D, P, P, D, P, P, I, D, D, I, P]
    lib.phc_ida_create.restype = P
    lib.phc_ida_free.argtypes, lib.phc_ida_free.restype = [P], None
    lib.phc_ida_advance.argtypes = [P, P, I, P, I, P, P, P, P, P, P, P, P]
    lib.phc_ida_advance.restype = I
    lib.phc_ida_stats.argtypes, lib.phc_ida_stats.restype = [P, P, P, P, P], None
    lib.phc_ida_watch.argtypes, lib.phc_ida_watch.restype = [P] * 11, None
    lib.phc_ida_rcond.argtypes, lib.phc_ida_rcond.restype = [P, D, P, P, D], D
    lib.phc_ida_message.argtypes, lib.phc_ida_message.restype = [P], ctypes.c_char_p
    lib.sundials_version = (int(version[1]), int(version[2]))
    return lib


def address(a) -> int:
    """Where a contiguous NumPy array's data lies: what the driver's functions take for an array."""
    return a.ctypes.data


def model_functions(model_library) -> tuple[int, int]:
    """The addresses of a model library's ``phc_residual`` and ``phc_jacobian`` (a library of
    :mod:`phc.codegen.c_backend`): what ``phc_ida_create`` calls."""
    return (ctypes.cast(model_library.phc_residual, ctypes.c_void_p).value,
            ctypes.cast(model_library.phc_jacobian, ctypes.c_void_p).value)


__all__ = ["ABI", "FLAGS", "LF_N", "LI_N", "LIBRARIES", "LOOK_CRAWL", "LOOK_MARKER", "LOOK_MINIMUM",
           "LOOK_NOT_CLEAR", "LOOK_TRANSLATED", "PHC_LOOK", "SOURCE", "TRANSLATOR", "address", "find_sundials",
           "library", "make_source", "model_functions", "pkg_config_prefix", "source", "switched_off", "why_not"]
