"""The public API (`phc/__init__.py`): every listed name resolves, importing phc is cheap,
and the command line goes through the listed names."""

from __future__ import annotations

import ast
import importlib.util
import subprocess
import sys
from pathlib import Path

import phc

CLI = Path(phc.__file__).with_name("cli.py")
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
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout


def test_the_command_line_imports_phc_names_only_from_the_public_api():
    tree = ast.parse(CLI.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module == "phc":
            for alias in node.names:
                is_module = importlib.util.find_spec(f"phc.{alias.name}") is not None
                assert alias.name in phc.__all__ or is_module, alias.name
        if isinstance(node, ast.ImportFrom) and node.module in ("phc.pipeline", "phc.simulation", "phc.errors",
                                                                "phc.accuracy", "phc.checks"):
            names = [a.name for a in node.names]
            assert all(n not in phc.__all__ for n in names), f"{node.module}: {names} are public: use `from phc`"
