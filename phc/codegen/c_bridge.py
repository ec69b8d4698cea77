"""The call bridge: the C back end's model functions called from Python without ctypes'
per-argument conversions.

IDA and phc's drivers call a model's residual and Jacobian from Python once per evaluation.
Through ctypes, each call converts its four vectors (``ctypes.c_double.from_buffer``, or a
copy for a read-only vector: IDA hands y and ẏ over read-only), which costs several times
what the residual of a small model costs. ``phc/codegen/c_runtime/bridge.c`` makes the same
call through the buffer protocol (``call`` and ``call_cj`` of :func:`bridge`'s module). It is built with
the system C compiler and Python's C headers, once per machine, Python version and phc version,
into phc's signed cache of compiled code, and loaded as the model libraries are
(:func:`phc.codegen.c_backend.runtime_library`); its module object comes from an exported function
called through ``ctypes.PYFUNCTYPE`` (the GIL held), so nothing is imported by name. It is built
when a C module is called often (:data:`phc.codegen.c_backend.BRIDGE_AFTER`), not when one is
loaded: ``phc compile`` calls a module a few dozen times and does not pay for it.

Where it cannot be built (no C headers for this Python: ``python3-dev`` or the like is not
installed), :func:`bridge` is None, the ctypes wrappers run, and :func:`why_not` says why (the
C backend's line in ``phc simulate`` repeats it).
"""

from __future__ import annotations

import ctypes
import os
import sys
import sysconfig
import threading
from pathlib import Path

SOURCE = Path(__file__).resolve().parent / "c_runtime" / "bridge.c"
"""The C text of the bridge (shipped in the package)."""

_LOCK = threading.Lock()
_BRIDGE = None
"""The bridge's module once built; False when it cannot be built here (:data:`_WHY`)."""
_WHY = ""


def _include() -> str:
    return sysconfig.get_paths().get("include") or ""


def switched_off() -> bool:
    """``PHC_C_BRIDGE=0`` (or ``no``, ``false``, ``off``) is set."""
    return os.environ.get("PHC_C_BRIDGE", "1").strip().lower() in ("0", "no", "false", "off")


def built():
    """The bridge's module when this process has built or loaded it already, False when it
    cannot be built here (or is switched off), None when it was not asked for yet."""
    if switched_off():
        return False
    return _BRIDGE


def bridge():
    """The bridge's module (with ``call``), built or loaded once per process, or None when it
    cannot be built here (:func:`why_not`). ``PHC_C_BRIDGE=0`` switches it off."""
    global _BRIDGE, _WHY
    if switched_off():
        return None
    with _LOCK:
        if _BRIDGE is None:
            try:
                _BRIDGE = _build()
            except Exception as err:  # noqa: BLE001 — the ctypes wrappers run instead, and say why
                _BRIDGE, _WHY = False, f"the call bridge could not be built ({type(err).__name__}: " \
                                       f"{str(err).strip().splitlines()[0] if str(err).strip() else ''})"
        return _BRIDGE or None


_NO_HEADERS = "Python's C headers (Python.h) are not installed for this interpreter"


def _have_headers() -> bool:
    include = _include()
    return bool(include) and os.path.isfile(os.path.join(include, "Python.h"))


def _build():
    global _WHY
    from phc.codegen import c_backend

    include = _include()
    if not _have_headers():
        _WHY = _NO_HEADERS
        return False
    flags = ("-std=c99", "-O2", "-fPIC", "-shared", f"-I{include}")
    # the Python the module is built for is part of the text, so of the cache key
    text = f"/* built for {sys.implementation.cache_tag} {sys.version.split()[0]} */\n" + \
        SOURCE.read_text(encoding="utf-8")
    lib, why = c_backend.runtime_library(text, flags)
    if lib is None:
        _WHY = why
        return False
    make = ctypes.PYFUNCTYPE(ctypes.py_object)(ctypes.cast(lib.phc_bridge_module, ctypes.c_void_p).value)
    module = make()
    module._library = lib  # keeps the library loaded while the module lives
    return module


def why_not() -> str:
    """Why the bridge is not used in this process ("" when it is, or when it was not built yet
    and Python's C headers are there: a C module asks for it at its
    :data:`~phc.codegen.c_backend.BRIDGE_AFTER`-th call)."""
    if switched_off():
        return "switched off (PHC_C_BRIDGE=0)"
    if _BRIDGE is None and not _have_headers():
        return _NO_HEADERS
    return _WHY


__all__ = ["SOURCE", "bridge", "built", "switched_off", "why_not"]
