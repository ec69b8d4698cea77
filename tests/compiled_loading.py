"""The numba and C back ends checked the same way (tests/codegen/test_backends.py,
tests/codegen/test_c_backend.py): a model compiled straight from its file past phc's
per-process and front-end caches (the disk-cache tests), one generated function called at a
point, and a compiled value compared with the NumPy reference's; and the compiled step loops
(tests/simulation/test_compiled_steps.py, test_c_steps.py) against the Python loop."""

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


def call(mod, name, t, y, yp, p, cj):
    """One of a generated module's functions (`name` in its FUNCTIONS) at one point, as an
    array: the output-argument functions fill a fresh one."""
    import numpy as np

    if name in ("residual", "residual_t"):
        out = np.zeros(mod.N)
        getattr(mod, name)(t, y, yp, p, out)
        return out
    if name == "jacobian":
        out = np.zeros(len(mod.JAC_ROWS))
        mod.jacobian(t, y, yp, p, cj, out)
        return out
    if name in ("hamiltonian", "energy_scale", "invariants", "velocity_invariants"):
        return np.atleast_1d(np.asarray(getattr(mod, name)(t, y, p), dtype=float))
    return np.atleast_1d(np.asarray(getattr(mod, name)(t, y, yp, p), dtype=float))


def assert_close(name, a, b, tol, floor=0.0):
    """`b` (a compiled back end's value of function `name`) equals `a` (the NumPy
    reference's): the same shape, non-finite where `a` is, and the finite entries within
    `tol` of the largest of them (at least `floor`)."""
    import numpy as np

    assert a.shape == b.shape, name
    finite = np.isfinite(a)
    assert np.array_equal(finite, np.isfinite(b)), f"{name}: non-finite entries differ"
    if finite.any():
        scale = max(floor, float(np.abs(a[finite]).max()))
        err = float(np.abs(a[finite] - b[finite]).max())
        assert err <= tol * scale, f"{name}: compiled and reference differ by {err:.3e} (scale {scale:.3e})"


def both_loops(monkeypatch, model, **options):
    """(compiled loop, Python loop) results of one simulation: ``PHC_COMPILED_LOOP`` on, then
    off (the numba loop on the numba back end, the C loop on the C back end)."""
    import phc

    monkeypatch.setenv("PHC_COMPILED_LOOP", "1")
    fast = phc.simulate(model, **options)
    monkeypatch.setenv("PHC_COMPILED_LOOP", "0")
    slow = phc.simulate(model, **options)
    monkeypatch.setenv("PHC_COMPILED_LOOP", "1")
    return fast, slow


def assert_same_trajectory(fast, slow, h):
    """The compiled loop took the Python loop's steps to its Newton tolerance."""
    import numpy as np

    assert fast.success and slow.success, (fast.message, slow.message)
    assert fast.message == slow.message
    assert np.array_equal(fast.t, slow.t) and fast.steps == slow.steps
    diff = fast.differential & (np.array(fast.variables) != "energy.supplied")
    size = 1.0 + np.abs(slow.y).max(axis=0)
    err = np.abs(fast.y - slow.y) / size
    # differential variables: the Newton tolerance (1e-14), accumulated over at most 1000 steps
    # with margin for the growth of a perturbation along the motion
    assert err[:, diff].max() <= 1e-9, err[:, diff].max()
    # algebraic ones (multipliers at the step ends) are differences of them over h
    assert err[:, ~diff].max(initial=0.0) <= 1e-9 / h, err[:, ~diff].max(initial=0.0)
