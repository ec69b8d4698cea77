"""phc reaches scikit-sundae and NumPy only through their public interfaces: loading the
IDA backend leaves NumPy's namespace and ``sys.modules`` as the libraries make them, and
phc's simulation package calls no C function of a dependency by address."""

import ast
import subprocess
import sys
import textwrap
from pathlib import Path
from time_limits import SUBPROCESS_TIMEOUT

SIMULATION = Path(__file__).resolve().parents[2] / "phc" / "simulation"


def _run(code: str) -> str:
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                         timeout=SUBPROCESS_TIMEOUT)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_loading_ida_leaves_numpy_and_the_module_table_as_the_libraries_make_them():
    out = _run("""
        import sys
        import numpy
        before = (list(numpy.__all__), sorted(dir(numpy)))
        from phc.simulation.ida import _import_ida
        IDA = _import_ida()
        print(before == (list(numpy.__all__), sorted(dir(numpy))))
        # every module scikit-sundae's import brought in is the library's own file
        numdiff = sys.modules.get("scipy.optimize._numdiff")
        print(numdiff is None or numdiff.__file__.startswith(__import__("scipy").__path__[0]))
        print(IDA.__module__)
    """)
    assert out.splitlines() == ["True", "True", "sksundae.ida._solver"]


def test_the_simulation_package_never_mentions_ctypes():
    """``grep ctypes phc/simulation`` finds nothing: phc's simulation package reaches compiled
    code only through the back ends' interfaces. The C back end's step-loop library is bound
    by :mod:`phc.codegen.c_steps` (beside the model libraries of :mod:`phc.codegen.c_backend`),
    and the numba loop's LAPACK calls through NumPy's ``array.ctypes`` pointers are in its
    kernel, :mod:`phc.codegen.numba_steps_kernel`. Read as text, so a comment, a docstring or
    an attribute counts as much as an import."""
    found = [f"{path.relative_to(SIMULATION.parents[1])}:{n}" for path in sorted(SIMULATION.rglob("*"))
             if path.is_file() and path.suffix in (".py", ".pyi", ".c", ".h", ".txt", ".md")
             for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if "ctypes" in line]
    assert found == []


def test_the_step_loop_library_comes_from_the_c_back_end():
    """:mod:`phc.codegen.c_steps` binds phc's own step-loop library (phc/codegen/c_runtime/steps.c)
    and opens no library itself (no ``CDLL``, ``cdll``, ``find_library``): the C back end builds
    and loads it in its signed cache (``c_backend.runtime_library``)."""
    path = SIMULATION.parents[1] / "phc" / "codegen" / "c_steps.py"
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names = {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
    names |= {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    opened = names & {"CDLL", "PyDLL", "cdll", "pydll", "LibraryLoader", "find_library", "dlopen"}
    assert not opened, f"{path}: opens a library itself ({sorted(opened)})"
    assert "runtime_library" in names and "c_backend" in names
