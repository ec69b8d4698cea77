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
