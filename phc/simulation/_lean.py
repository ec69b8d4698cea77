"""Importing scipy.sparse and scikit-SUNDAE without the parts phc never uses.

Start-up of a cached ``phc simulate`` is mostly imports (``benchmarks/bench_startup.py``).
Two of them load much more than phc needs, for reasons inside the libraries:

* scipy vendors ``array_api_compat``, whose NumPy namespace is a copy of ``numpy``'s made
  when ``scipy.sparse`` first loads: ``from numpy import *`` and a ``getattr`` of every
  name in ``dir(numpy)``. NumPy lists its lazily loaded submodules there (``f2py``,
  ``testing``, ``ma``, ``random``, ``polynomial``, ``char``, …), so the copy imports all of
  them: 200 modules, about 0.1 s. :func:`import_scipy_sparse` makes the copy with NumPy's
  loaded names only, then gives the copy a module ``__getattr__`` that forwards any other
  name to ``numpy`` — ``xp.testing`` still works, loaded when first asked for.
* scikit-SUNDAE's extension imports ``scipy.optimize`` (see :func:`import_ida`).

Both are undone right after: NumPy's ``__all__`` and ``__dir__`` are restored, the stand-in
for ``scipy.optimize._numdiff`` is removed from ``sys.modules``. Python's import lock is
held meanwhile, so another thread never sees the narrowed NumPy. If anything fails, the
plain import runs. ``tests/simulation/test_ida_import.py`` checks both and that nothing
leaks.
"""

from __future__ import annotations

import sys

_COMPAT = "scipy._lib.array_api_compat.numpy"
_NUMDIFF = "scipy.optimize._numdiff"


def _group_columns(*args, **kwargs):
    """scipy's ``group_columns``, imported when first called (see :func:`import_ida`)."""
    from importlib import import_module

    return import_module(_NUMDIFF).group_columns(*args, **kwargs)


def _forward_to_numpy(numpy):
    def __getattr__(name):  # PEP 562: only names the copy does not have get here
        try:
            return getattr(numpy, name)
        except AttributeError:
            raise AttributeError(f"module {_COMPAT!r} has no attribute {name!r}") from None

    return __getattr__


def _narrowed_numpy_import(load):
    """Run `load()` (an import that loads ``scipy.sparse`` first) with NumPy's star-import
    and ``dir`` listing only the names NumPy has loaded; returns what `load` returns."""
    import _imp

    import numpy

    if "scipy.sparse" in sys.modules or _COMPAT in sys.modules:
        return load()
    names = vars(numpy)
    all_before, had_dir = names.get("__all__"), "__dir__" in names
    dir_before = names.get("__dir__")
    _imp.acquire_lock()
    try:
        try:
            loaded = [n for n in (dir_before() if callable(dir_before) else dir(numpy)) if n in names]
            numpy.__all__ = [n for n in (all_before or ()) if n in names]
            numpy.__dir__ = lambda: list(loaded)
        except Exception:  # noqa: BLE001 - an unexpected NumPy: the plain import
            return load()
        try:
            out = load()
        finally:
            if all_before is not None:
                numpy.__all__ = all_before
            else:
                names.pop("__all__", None)
            if had_dir:
                numpy.__dir__ = dir_before
            else:
                names.pop("__dir__", None)
        compat = sys.modules.get(_COMPAT)
        if compat is not None and "__getattr__" not in vars(compat):
            compat.__getattr__ = _forward_to_numpy(numpy)
        return out
    finally:
        _imp.release_lock()


def import_scipy_sparse():
    """``scipy.sparse``, loaded without NumPy's unused submodules (module docstring)."""
    def load():
        import scipy.sparse

        return scipy.sparse

    try:
        return _narrowed_numpy_import(load)
    except ImportError:
        raise
    except Exception:  # noqa: BLE001 - any surprise: the plain import
        import scipy.sparse

        return scipy.sparse


def import_ida():
    """scikit-SUNDAE's IDA class.

    scikit-SUNDAE's extension imports ``group_columns`` from ``scipy.optimize._numdiff`` when
    it loads, and with it all of ``scipy.optimize`` (``scipy.fft``, ``scipy.special``,
    ``scipy.linalg``'s interpolative decompositions): about 0.35 s, more than half of a small
    model's cached ``phc simulate``. The function is only called for a finite-difference
    sparse Jacobian, which phc never asks for (it passes the generated Jacobian). So the
    first import is served a stand-in module whose ``group_columns`` imports scipy's on its
    first call; the stand-in is removed from ``sys.modules`` right after, so a later
    ``import scipy.optimize`` loads scipy's own. Python's global import lock is held
    meanwhile, so that another thread importing ``scipy.optimize`` waits instead of finding
    the stand-in. If the stand-in import fails in any way, the plain import runs instead."""
    import _imp
    import types

    import_scipy_sparse()
    if "sksundae.ida" not in sys.modules and _NUMDIFF not in sys.modules:
        stand_in = types.ModuleType(_NUMDIFF)
        stand_in.group_columns = _group_columns
        _imp.acquire_lock()
        sys.modules[_NUMDIFF] = stand_in
        try:
            from sksundae.ida import IDA

            return IDA
        except Exception:  # noqa: BLE001 - fall back to the plain import below
            for name in [m for m in sys.modules if m == "sksundae" or m.startswith("sksundae.")]:
                del sys.modules[name]
        finally:
            if sys.modules.get(_NUMDIFF) is stand_in:
                del sys.modules[_NUMDIFF]
            _imp.release_lock()
    from sksundae.ida import IDA

    return IDA
