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


OWN_LIBRARIES = {
    "c_steps.py": "binds phc's own step-loop library (phc/codegen/c_runtime/steps.c), compiled by phc "
                  "through the C back end's signed cache, its struct layout checked against phc's at load",
}
"""Modules of the simulation package that may use ``ctypes``: each binds a library phc compiled
from its own C source, never a dependency's, and opens no library itself."""


def test_the_simulation_package_imports_no_ctypes():
    """No ``ctypes`` module (calls into a dependency's C library at addresses phc computes);
    NumPy's ``array.ctypes`` pointers handed to scipy's public LAPACK bindings in numba
    kernels are a documented interface and are not an import. The modules in
    :data:`OWN_LIBRARIES` bind phc's own compiled code and must not open a library
    themselves (no ``CDLL``, ``cdll``, ``find_library``): the C back end loads it."""
    for path in sorted(SIMULATION.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        if path.name in OWN_LIBRARIES:
            names = {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
            names |= {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
            opened = names & {"CDLL", "PyDLL", "cdll", "pydll", "LibraryLoader", "find_library", "dlopen"}
            assert not opened, f"{path}: opens a library itself ({sorted(opened)})"
            assert "c_backend" in names, f"{path}: its library must come from phc.codegen.c_backend"
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                assert all(a.name.split(".")[0] != "ctypes" for a in node.names), f"{path}:{node.lineno}"
            elif isinstance(node, ast.ImportFrom):
                assert (node.module or "").split(".")[0] != "ctypes", f"{path}:{node.lineno}"


def test_every_module_allowed_ctypes_exists():
    for name in OWN_LIBRARIES:
        assert (SIMULATION / name).is_file(), name
