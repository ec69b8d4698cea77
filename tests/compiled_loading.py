"""A model compiled by one compiled back end straight from its file, past phc's per-process
and front-end caches: the disk-cache tests of the numba and C back ends
(tests/codegen/test_backends.py, tests/codegen/test_c_backend.py) load through it."""

from __future__ import annotations


def load_with(backend, path):
    """(module, report) of `backend` (``phc.codegen.numba_backend`` or ``c_backend``) for the
    model at `path`: its `load_compiled` on the lowered IR, the NumPy reference module and the
    printed source."""
    from phc.codegen.load import load_generated
    from phc.codegen.lower import lower_residual
    from phc.codegen.printer import print_module
    from phc.pipeline import build_dae

    dae, _ = build_dae(path)
    ir = lower_residual(dae)
    source = print_module(ir)
    reference, _ = load_generated(source)
    return backend.load_compiled(ir, reference, source)
