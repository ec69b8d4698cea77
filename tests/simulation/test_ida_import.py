"""Loading scikit-SUNDAE without ``scipy.optimize`` (phc.simulation.ida._import_ida)."""

import subprocess
import sys
import textwrap


def _run(code: str) -> str:
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_ida_loads_without_scipy_optimize_and_leaves_it_importable():
    out = _run("""
        import sys
        import numpy as np
        from phc.simulation.ida import _import_ida
        IDA = _import_ida()
        print("optimize" if "scipy.optimize" in sys.modules else "no-optimize")
        print("stand-in" if "scipy.optimize._numdiff" in sys.modules else "clean")
        import scipy.optimize  # scipy's own module now loads, in full
        from scipy.optimize._numdiff import group_columns
        print(type(scipy.optimize.minimize).__name__)
        # what scikit-SUNDAE's extension bound forwards to scipy's function
        from sksundae import _cy_ida
        bound = _cy_ida.group_columns
        A = np.array([[1, 0, 0], [0, 1, 0], [1, 0, 1]])
        print(bound(A).tolist() == group_columns(A).tolist())
    """)
    assert out.splitlines() == ["no-optimize", "clean", "function", "True"]


def test_ida_loads_normally_when_scipy_optimize_is_already_imported():
    out = _run("""
        import scipy.optimize
        from phc.simulation.ida import _import_ida
        _import_ida()
        from sksundae import _cy_ida
        from scipy.optimize._numdiff import group_columns
        print(_cy_ida.group_columns is group_columns)
    """)
    assert out == "True"


def test_direct_ida_calls_give_what_scikit_sundae_step_gives(monkeypatch):
    """IDASolve called through ctypes (phc.simulation.ida._IdaCounters.advance) integrates
    exactly as scikit-SUNDAE's own ``step``: same states, steps and evaluations."""
    from pathlib import Path

    import numpy as np

    import phc
    from phc.simulation import ida

    model = Path(__file__).resolve().parents[2] / "models" / "pendulum.yaml"
    compiled = phc.compile_model(model, certify=False, backend="numpy")
    used = []
    advance = ida._IdaCounters.advance

    def spy(self, t):
        used.append(t)
        return advance(self, t)

    monkeypatch.setattr(ida._IdaCounters, "advance", spy)
    direct = phc.simulate(compiled, t_end=2.0, n_out=41, rtol=1e-8, atol=1e-8)
    assert direct.success and len(used) >= 40
    monkeypatch.setattr(ida._IdaCounters, "can_advance", property(lambda self: False))
    used.clear()
    stepped = phc.simulate(compiled, t_end=2.0, n_out=41, rtol=1e-8, atol=1e-8)
    assert stepped.success and not used
    assert np.array_equal(direct.y, stepped.y)
    assert (direct.steps, direct.n_residual_evals, direct.n_jacobian_evals) == \
        (stepped.steps, stepped.n_residual_evals, stepped.n_jacobian_evals)


def test_scipy_sparse_loads_without_numpys_unused_submodules_and_numpy_is_left_as_it_was():
    """phc.simulation loads scipy.sparse with NumPy's star-import narrowed to its loaded names
    (phc/simulation/_lean.py): scipy's copy of the NumPy namespace then skips f2py, testing,
    ma, … — and still hands them out, loaded on first use; NumPy itself is restored."""
    out = _run("""
        import sys
        import numpy
        all_before, dir_before = list(numpy.__all__), sorted(dir(numpy))
        import phc.simulation  # noqa: F401
        print("lean" if "numpy.f2py" not in sys.modules and "numpy.testing" not in sys.modules else "full")
        print(numpy.__all__ == all_before and sorted(dir(numpy)) == dir_before)
        from scipy._lib.array_api_compat import numpy as xp
        print(xp.testing is numpy.testing and xp.ma is numpy.ma)  # forwarded, loaded now
        try:
            xp.no_such_name
        except AttributeError as err:
            print("AttributeError", "no_such_name" in str(err))
        import scipy.sparse, scipy.linalg
        A = scipy.sparse.random(6, 6, density=0.5, random_state=1) + scipy.sparse.eye(6)
        print(abs(scipy.linalg.pinv(A.toarray()) @ A.toarray() - numpy.eye(6)).max() < 1e-12)
    """)
    assert out.splitlines() == ["lean", "True", "True", "AttributeError True", "True"]


def test_scipy_already_imported_is_left_alone():
    out = _run("""
        import sys
        import scipy.sparse
        had = "numpy.f2py" in sys.modules
        import phc.simulation  # noqa: F401
        from scipy._lib.array_api_compat import numpy as xp
        print(had, "__getattr__" in vars(xp))
    """)
    assert out == "True False"
