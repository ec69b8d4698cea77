"""The public API (`phc/__init__.py`): every listed name resolves, importing phc is cheap,
and the command line goes through the listed names."""

from __future__ import annotations

import ast
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import phc
from time_limits import SUBPROCESS_TIMEOUT

REPO = Path(__file__).resolve().parents[1]

CLI = sorted(Path(phc.__file__).with_name("cli").glob("*.py"))  # the phc.cli package
HEAVY = ("sympy", "scipy", "numpy", "pydantic", "networkx", "matplotlib")


def test_every_public_name_resolves():
    for name in phc.__all__:
        assert getattr(phc, name) is not None, name
    assert "compile_model" in dir(phc)


def test_an_unknown_name_is_an_attribute_error():
    try:
        phc.no_such_thing  # noqa: B018
    except AttributeError as err:
        assert "no_such_thing" in str(err)
    else:
        raise AssertionError("expected AttributeError")


def test_import_and_help_do_not_load_the_numerical_stack():
    code = ("import sys, contextlib, io\n"
            "import phc.cli\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try:\n"
            "        phc.cli.main(['--help'])\n"
            "    except SystemExit:\n"
            "        pass\n"
            f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout


COMPILE_NEVER = ("networkx", "numba", "sksundae", "matplotlib", "scipy.optimize", "scipy.integrate")
"""What ``phc compile`` of a model without a graph to draw or a run to make does not import:
networkx (about 0.3 s CPU of a cold compile; the interconnection graph's views import it),
the run's solvers and the plots."""


def test_a_cold_compile_imports_no_graph_library_and_no_solver(tmp_path):
    """`phc compile --backend c` (numpy without a C compiler) with empty caches, certificate
    included, in a fresh process: none of :data:`COMPILE_NEVER` is imported, and the files are
    written. Fails where the compile path imports networkx at the top of a module."""
    from phc.codegen import cc

    backend = "c" if cc.available()[0] else "numpy"
    code = ("import sys\nfrom phc.cli import main\n"
            f"code = main(['compile', 'models/pendulum.yaml', '--backend', {backend!r}, '-o', {str(tmp_path / 'out')!r}])\n"
            f"print(code, sorted(m for m in {COMPILE_NEVER!r} if m in sys.modules))\n")
    env = dict(os.environ, PHC_CACHE_DIR=str(tmp_path / "cache"), PHC_STATE_DIR=str(tmp_path / "state"))
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=REPO,
                         timeout=SUBPROCESS_TIMEOUT)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.strip().splitlines()[-1] == "0 []", run.stdout + run.stderr[-2000:]
    assert (tmp_path / "out" / "pendulum.py").is_file()


def test_the_command_line_imports_phc_names_only_from_the_public_api():
    assert CLI
    trees = [ast.parse(path.read_text()) for path in CLI]
    for node in (node for tree in trees for node in ast.walk(tree)):
        if isinstance(node, ast.ImportFrom) and node.module == "phc":
            for alias in node.names:
                is_module = importlib.util.find_spec(f"phc.{alias.name}") is not None
                assert alias.name in phc.__all__ or is_module, alias.name
        if isinstance(node, ast.ImportFrom) and node.module in ("phc.pipeline", "phc.simulation", "phc.errors",
                                                                "phc.study.accuracy", "phc.checks"):
            names = [a.name for a in node.names]
            assert all(n not in phc.__all__ for n in names), f"{node.module}: {names} are public: use `from phc`"


def test_importing_and_using_phc_changes_no_environment_variable(tmp_path):
    """`import phc` (and compiling and simulating) leaves the user's process environment as
    it was: no BLAS thread count, no PHC_* variable. Only the `phc` command sets the thread
    variables for its own process (phc/_entry.py)."""
    code = ("import os, json; before = dict(os.environ); import phc; after_import = dict(os.environ); "
            "r = phc.simulate(phc.compile_model('models/mass_spring_damper.yaml'), t_end=0.1); "
            "print(json.dumps([after_import == before, dict(os.environ) == before, r.success]))")
    # (KMP_DUPLICATE_LIB_OK: importing threadpoolctl sets it; a parent process that imported
    # it would hand it down and hide the change)
    env = {k: v for k, v in os.environ.items()
           if not k.endswith("_NUM_THREADS") and not k.startswith("PHC_") and k != "KMP_DUPLICATE_LIB_OK"}
    env["PHC_CACHE_DIR"] = str(tmp_path / "cache")
    env["PHC_STATE_DIR"] = str(tmp_path / "state")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=REPO,
                         timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout.splitlines()[-1]) == [True, True, True]


def test_only_the_phc_command_tunes_the_garbage_collector():
    """`import phc` leaves Python's collector as it was; the command (phc/_entry.py) freezes
    what the imports made and collects its youngest and middle generations less often."""
    code = ("import gc, json; before = gc.get_threshold(); import phc; from phc import _entry; "
            "untouched = [gc.get_threshold() == before, gc.get_freeze_count() == 0]\n"
            "try:\n    _entry.main(['--version'])\nexcept SystemExit:\n    pass\n"
            "print(json.dumps(untouched + [gc.get_threshold()[0] == _entry.GC_YOUNG, gc.get_freeze_count() > 0, "
            "gc.get_threshold()[1] == _entry.GC_MIDDLE, gc.get_threshold()[2:] == before[2:]]))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO,
                         timeout=SUBPROCESS_TIMEOUT)
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout.splitlines()[-1]) == [True, True, True, True, True, True]


def test_the_phc_command_runs_with_one_blas_thread_unless_told_otherwise():
    from phc import _entry

    assert _entry.THREAD_VARIABLES == ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
    code = "import os\nfrom phc._entry import main\ntry:\n    main(['--version'])\nexcept SystemExit:\n    pass\n"
    for preset, expected in ((None, "1"), ("3", "3")):
        env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
        if preset:
            env["OPENBLAS_NUM_THREADS"] = preset
        run = subprocess.run([sys.executable, "-c", code + "print(os.environ['OPENBLAS_NUM_THREADS'])"],
                             capture_output=True, text=True, env=env, timeout=SUBPROCESS_TIMEOUT)
        assert run.returncode == 0, run.stderr[-2000:]
        assert run.stdout.splitlines()[-1] == expected
