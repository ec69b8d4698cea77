"""The compiled backend (:mod:`phc.codegen.numba_backend`) against the reference NumPy module.

Both backends evaluate the same printed expressions; the compiled one writes them as
machine code. They must agree to round-off on every shipped model, for every generated
function, at random states — including ones outside the expressions' domains, where both
must produce a non-finite value in the same entries. The emitter's rule for each function
of the model language is checked on a model that uses them all, a table input included.
Without numba these tests are skipped (and the NumPy module is what runs, tested below).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.codegen import backends, numba_backend, numba_cache
from phc.errors import CacheWarning, SimulationSetupError
from compiled_loading import assert_close, call, load_with  # shared with tests/codegen/test_c_backend.py
from model_texts import EVERY_FUNCTION  # shared with tests/codegen/test_c_backend.py

MODELS = sorted((Path(__file__).resolve().parents[2] / "models").glob("*.yaml"))

_OK, _WHY = numba_backend.available()
needs_numba = pytest.mark.skipif(not _OK, reason=f"compiled backend not tested: {_WHY}")

TOL = 1e-13
"""Agreement required, relative to the largest entry of the vector (round-off: the
compiled linear blocks sum in another order than scipy's sparse product)."""


def _points(mod, rng, k=6):
    n = mod.N
    p0 = np.asarray(mod.full_parameters(), dtype=float)
    for _ in range(k):
        y = rng.uniform(-1.0, 1.0, n)
        yp = rng.uniform(-1.0, 1.0, n)
        yield float(rng.uniform(0.0, 2.0)), y, yp, p0, float(rng.uniform(0.1, 50.0))


def _assert_same(ref, fast, functions=numba_backend.FUNCTIONS, seed=0):
    rng = np.random.default_rng(seed)
    checked = 0
    for t, y, yp, p, cj in _points(ref, rng):
        for name in functions:
            with np.errstate(all="ignore"):
                try:
                    a = call(ref, name, t, y, yp, p, cj)
                except (ArithmeticError, ValueError, TypeError):
                    continue  # outside the reference's domain (Python raises; compiled code gives NaN)
                b = call(fast, name, t, y, yp, p, cj)
            assert_close(name, a, b, TOL, floor=1.0)
            checked += 1
    assert checked


@needs_numba
@pytest.mark.parametrize("path", MODELS, ids=[p.stem for p in MODELS])
def test_compiled_functions_equal_the_reference_on_every_shipped_model(path):
    compiled = phc.compile_model(path, certify=False, backend="numba")
    assert compiled.backend == "numba"
    fast = compiled.module
    ref = fast.REFERENCE
    assert backends.name_of(ref) == "numpy"
    _assert_same(ref, fast)


@needs_numba
def test_every_function_of_the_language_is_compiled_like_the_printed_python(tmp_path):
    path = tmp_path / "every_function.yaml"
    path.write_text(EVERY_FUNCTION)
    compiled = phc.compile_model(path, certify=False, backend="numba")
    fast = compiled.module
    assert "outputs" in fast.COMPILE_REPORT.emitted  # written as LLVM IR, not left to numba's compiler
    _assert_same(fast.REFERENCE, fast, functions=("outputs", "residual", "jacobian"), seed=3)
    # with the switches' modes frozen to either side (the event driver's parameters), too
    ref = fast.REFERENCE
    modes = [j for j, name in enumerate(ref.PARAMETERS) if name.startswith("switch[")]
    assert len(modes) == 2  # sign(t - 0.3) and heaviside(spring.x - 0.05) in the residual rows
    for side in (-1.0, 1.0):
        frozen = types.SimpleNamespace(**{k: getattr(ref, k) for k in ("N", "JAC_ROWS")})
        base = np.asarray(ref.full_parameters(), dtype=float)
        base[modes] = side
        frozen.full_parameters = lambda base=base: base
        for name in ("residual", "jacobian", "residual_t"):
            setattr(frozen, name, getattr(ref, name))
        fast_frozen = types.SimpleNamespace(**vars(frozen))
        for name in ("residual", "jacobian", "residual_t"):
            setattr(fast_frozen, name, getattr(fast, name))
        _assert_same(frozen, fast_frozen, functions=("residual", "jacobian", "residual_t"), seed=4)
    # at the switching points themselves (x = 0.1 for the heaviside output, p = 0 for sign)
    p = np.asarray(ref.full_parameters(), dtype=float)
    for x, v in ((0.1, 0.0), (0.0, 0.0), (-0.2, 0.1)):
        y = np.zeros(ref.N)
        y[list(ref.VARIABLES).index("spring.x")] = x
        y[list(ref.VARIABLES).index("mass.p")] = v
        with np.errstate(all="ignore"):
            a, b = ref.outputs(0.5, y, y, p), fast.outputs(0.5, y, y, p)
        np.testing.assert_allclose(b, a, rtol=TOL, atol=TOL)


@needs_numba
def test_a_table_input_is_interpolated_like_the_reference(tmp_path):
    (tmp_path / "force.csv").write_text("t,f\n0,0\n0.25,1\n0.5,-0.5\n1,2\n")
    (tmp_path / "pulse.csv").write_text("t,f\n0,0\n0.3,1\n0.7,0\n")
    model = EVERY_FUNCTION.replace('force: {effort: "-0.1*sin(3*t)"}', "force: {effort: {file: force.csv, column: f}}")
    model = model.replace('pulse: {effort: "0.05*t**2"}',
                          "pulse: {effort: {file: pulse.csv, column: f, interpolation: previous}}")
    path = tmp_path / "tabled.yaml"
    path.write_text(model)
    compiled = phc.compile_model(path, certify=False, backend="numba")
    fast = compiled.module
    ref = fast.REFERENCE
    p = np.asarray(ref.full_parameters(), dtype=float)
    rng = np.random.default_rng(5)
    for t in [-0.1, 0.0, 0.1, 0.25, 0.4, 0.5, 0.9, 1.0, 1.5, *rng.uniform(0, 1, 5)]:
        y, yp = rng.uniform(-1, 1, ref.N), rng.uniform(-1, 1, ref.N)
        for name in ("residual", "residual_t"):
            a, b = call(ref, name, t, y, yp, p, 1.0), call(fast, name, t, y, yp, p, 1.0)
            np.testing.assert_allclose(b, a, rtol=TOL, atol=TOL, err_msg=f"{name} at t = {t}")


def _damped_string(folder: Path) -> Path:
    """The shipped string, 3 elements, with damping: sparse linear blocks, quadratic
    energies and a quadratic dissipation form."""
    text = (MODELS[0].parent / "vibrating_string.yaml").read_text()
    assert "    elements: 16\n" in text
    path = folder / "damped_string.yaml"
    path.write_text(text.replace("    elements: 16\n", "    elements: 3\n    damping: 0.05\n"))
    return path


@needs_numba
@pytest.mark.parametrize("emit", [True, False], ids=["emitted", "numba-front-end"])
def test_sparse_blocks_and_quadratic_forms_on_both_compilation_paths(tmp_path, monkeypatch, emit):
    """Expressions the emitter has no rule for go to numba's own compiler as Python text:
    that path must compute the same (forced here for every function)."""
    if not emit:
        monkeypatch.setattr(numba_backend, "emittable", lambda expr, known: False)
    compiled = phc.compile_model(_damped_string(tmp_path), certify=False, backend="numba")
    fast = compiled.module
    assert bool(fast.COMPILE_REPORT.emitted) == emit
    _assert_same(fast.REFERENCE, fast, seed=11)


NO_NUMBA = 'numba is not installed (pip install "port-hamiltonian-compiler[fast]")'


def test_auto_runs_c_first_then_numba_then_numpy(monkeypatch):
    """`auto`, for a model of AUTO_MIN_UNKNOWNS unknowns or more: the C module when a C
    compiler is found (cheapest to build, and no dearer to call than numba's through the
    call bridge), else numba's, else the NumPy module; the backend line says why whenever
    auto did not run C."""
    from phc.codegen import c_bridge, cc

    crank = MODELS[0].parent / "rigid_slider_crank.yaml"  # large enough for `auto` to want a compiled backend
    if cc.available()[0]:
        compiled = phc.compile_model(crank, certify=False, backend="auto")
        assert compiled.backend == "c"
        line = backends.describe(compiled.module, "auto")
        assert line.startswith("c: compiled functions") and "auto:" not in line
        assert ("called through ctypes" in line) == (c_bridge.bridge() is None)
        _assert_same(compiled.module.REFERENCE, compiled.module, seed=5)
    monkeypatch.setattr(cc, "available", lambda: (False, "no C compiler found (blocked by the test)"))
    if numba_cache.available()[0]:
        compiled = phc.compile_model(crank, certify=False, backend="auto")
        assert compiled.backend == "numba"
        assert backends.describe(compiled.module, "auto").endswith(
            "; auto: the C backend is not used (no C compiler found (blocked by the test))")
        assert "auto:" not in backends.describe(compiled.module, "numba")
    monkeypatch.setattr(numba_cache, "_AVAILABLE", (False, NO_NUMBA))
    compiled = phc.compile_model(crank, certify=False, backend="auto")
    assert compiled.backend == "numpy" and not hasattr(compiled.module, "REFERENCE")
    assert backends.describe(compiled.module, "auto") == (
        f"numpy (compiled backends unavailable: no C compiler found (blocked by the test); {NO_NUMBA})")
    with pytest.raises(SimulationSetupError, match=r"numba is not installed .*compiler\[fast\]"):
        phc.compile_model(crank, certify=False, backend="numba")
    with pytest.raises(SimulationSetupError, match="unknown backend `fortran`"):
        backends.check_choice("fortran")


def test_auto_runs_small_models_on_c_and_without_c_never_looks_for_numba(monkeypatch):
    """A small model runs on C under `auto` like any other (through the call bridge a call
    costs less than the NumPy module's). Without a C compiler it stays on the NumPy module
    below AUTO_MIN_UNKNOWNS, numba not even imported (its compilation costs more than a handful
    of float operations save), and the backend line gives both reasons."""
    from phc.codegen import cc

    pendulum = MODELS[0].parent / "pendulum.yaml"
    monkeypatch.setattr(numba_cache, "_AVAILABLE", None)
    for module in (numba_cache, numba_backend):
        monkeypatch.setattr(module, "available", lambda: pytest.fail("numba was looked for"))
    if cc.available()[0]:
        compiled = phc.compile_model(pendulum, certify=False, backend="auto")
        assert compiled.module.N < backends.AUTO_MIN_UNKNOWNS and compiled.backend == "c"
        _assert_same(compiled.module.REFERENCE, compiled.module, seed=3)
    monkeypatch.setattr(cc, "available", lambda: (False, "no C compiler found (blocked by the test)"))
    compiled = phc.compile_model(pendulum, certify=False, backend="auto")
    assert compiled.module.N < backends.AUTO_MIN_UNKNOWNS and compiled.backend == "numpy"
    line = backends.describe(compiled.module, "auto")
    assert line.startswith("numpy (auto: the C backend is not used (no C compiler found (blocked by the test)); "
                           f"7 unknowns, below {backends.AUTO_MIN_UNKNOWNS}"), line
    assert backends.describe(compiled.module, "numpy") == "numpy"


def test_auto_runs_a_mesh_of_many_nonzeros_on_numpy_and_says_why(monkeypatch):
    """Above AUTO_MAX_NONZEROS Jacobian nonzeros `auto` neither compiles C nor looks for numba:
    their code would carry the mesh's arrays. The backend line gives the count and the way to
    compile anyway, and an explicit `c` still compiles (shown here with the threshold lowered to
    below the rigid slider–crank's nonzeros)."""
    from phc.codegen import cc

    crank = MODELS[0].parent / "rigid_slider_crank.yaml"
    monkeypatch.setattr(backends, "AUTO_MAX_NONZEROS", 10)
    monkeypatch.setattr(cc, "available", lambda: pytest.fail("a C compiler was looked for"))
    monkeypatch.setattr(numba_cache, "_AVAILABLE", None)
    for module in (numba_cache, numba_backend):
        monkeypatch.setattr(module, "available", lambda: pytest.fail("numba was looked for"))
    compiled = phc.compile_model(crank, certify=False, backend="auto")
    nnz = len(compiled.module.JAC_ROWS)
    assert compiled.backend == "numpy" and nnz > 10
    assert backends.describe(compiled.module, "auto") == (
        f"numpy (auto: {nnz:,} Jacobian nonzeros, above 10, where compiling a mesh's arrays into C or numba costs "
        "more time and memory than its sparse products save; --backend c compiles it anyway)")
    assert backends.describe(compiled.module, "numpy") == "numpy"
    monkeypatch.undo()
    monkeypatch.setattr(backends, "AUTO_MAX_NONZEROS", 10)
    if cc.available()[0]:
        assert phc.compile_model(crank, certify=False, backend="c").backend == "c"


def test_a_fresh_process_without_numba_simulates_with_the_numpy_module(tmp_path):
    """`import numba` fails (as on a machine where it is not installed): phc still works."""
    blocker = tmp_path / "blocker"
    blocker.mkdir()
    (blocker / "numba.py").write_text("raise ImportError('No module named numba (blocked by the test)')\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(blocker), os.environ.get("PYTHONPATH", "")]),
               PHC_BACKEND="auto")
    model = MODELS[0].parent / "rigid_slider_crank.yaml"
    done = subprocess.run([sys.executable, "-m", "phc", "simulate", str(model), "--quiet", "--t-end", "0.01",
                           "--no-certify"], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    from phc.codegen import cc

    if cc.available()[0]:  # auto runs the C module, numba or not
        assert "backend  c: compiled functions" in done.stdout
    else:
        assert "backend  numpy (compiled backends unavailable: " in done.stdout and NO_NUMBA in done.stdout
    bad = subprocess.run([sys.executable, "-m", "phc", "simulate", str(model), "--quiet", "--backend", "numba"],
                         capture_output=True, text=True, env=env, timeout=300)
    assert bad.returncode == 2
    lines = bad.stderr.strip().splitlines()
    assert len(lines) == 1 and "numba backend is not available" in lines[0] and "Traceback" not in bad.stderr


@needs_numba
def test_simulating_on_either_backend_gives_the_same_trajectory():
    compiled = phc.compile_model(MODELS[0].parent / "mass_spring_damper.yaml", certify=False, backend="numpy")
    ref = phc.simulate(compiled, t_end=2.0, solver="midpoint", step=1e-2)
    fast = phc.simulate(compiled, t_end=2.0, solver="midpoint", step=1e-2, backend="numba")
    np.testing.assert_allclose(fast.y, ref.y, rtol=1e-10, atol=1e-12)
    assert compiled.backend == "numpy"  # asking a run for another backend leaves the compiled model as it was


# ---------------------------------------------------------------------------------------
# the signed cache of compiled artefacts

def _fresh(monkeypatch):
    """Forget what this process compiled, so the next load reads the disk cache."""
    monkeypatch.setattr(numba_cache, "_LOADED", {})


@needs_numba
def test_compiled_artefacts_are_cached_signed_and_never_trusted_unsigned(tmp_path, monkeypatch):
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    model = MODELS[0].parent / "mass_spring_damper.yaml"
    _fresh(monkeypatch)
    _, cold = load_with(numba_backend, model)
    assert cold.cached == "cold"
    folder = tmp_path / "cache" / "numba"
    files = sorted(folder.iterdir())
    assert files and all(f.read_bytes().startswith(b"phc-numba-2\n") for f in files)
    assert oct((folder.stat().st_mode) & 0o777) == oct(0o700)
    key = tmp_path / "state" / "cache-key"
    assert key.is_file() and key.stat().st_mode & 0o077 == 0
    assert not (folder / "__pycache__").exists()

    _fresh(monkeypatch)
    _, warm = load_with(numba_backend, model)
    assert warm.cached == "warm" and warm.misses == 0

    # a tampered artefact (one byte of the machine code's pickle) is not unpickled: compiled again
    data = next(f for f in files if f.suffix == ".nbc")
    raw = bytearray(data.read_bytes())
    raw[-10] ^= 0xFF
    data.write_bytes(bytes(raw))
    _fresh(monkeypatch)
    with pytest.warns(CacheWarning, match="does not verify"):  # one warning naming the file, not the model
        fast, again = load_with(numba_backend, model)
    assert again.misses >= 1
    _assert_same(fast.REFERENCE, fast, functions=("residual", "jacobian"))

    # a cache restored from another machine (signed with another key) costs a compilation
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "other-state"))
    _fresh(monkeypatch)
    _, foreign = load_with(numba_backend, model)
    assert foreign.cached == "cold"


@needs_numba
def test_a_cache_directory_others_can_write_is_not_used_for_compiled_code(tmp_path, monkeypatch):
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    (tmp_path / "cache" / "numba").mkdir(parents=True, mode=0o700)
    os.chmod(tmp_path / "cache" / "numba", 0o777)
    _fresh(monkeypatch)
    _, report = load_with(numba_backend, MODELS[0].parent / "mass_spring_damper.yaml")
    assert report.cached == "off" and "writable by other users" in report.note
    assert list((tmp_path / "cache" / "numba").iterdir()) == []


@needs_numba
def test_a_model_the_backend_cannot_compile_runs_on_the_numpy_module_with_a_warning(tmp_path, monkeypatch):
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    _fresh(monkeypatch)

    def broken(*args):
        raise RuntimeError("LLVM says no")

    monkeypatch.setattr(numba_backend, "_emit_kernel", broken)
    with pytest.warns(numba_backend.CompiledBackendWarning, match="could not build .*RuntimeError: LLVM says no"):
        compiled = phc.compile_model(MODELS[0].parent / "rigid_slider_crank.yaml", certify=False, backend="numba")
    assert compiled.backend == "numpy"
    assert phc.simulate(compiled, t_end=0.01).success


def test_the_compiled_backend_is_an_optional_extra():
    """numba is in the `fast` and `test` extras, never a core dependency."""
    import re

    text = (Path(__file__).resolve().parents[2] / "pyproject.toml").read_text()
    core, extras = text.split("[project.optional-dependencies]")
    extras = extras.split("\n[")[0]
    assert "numba" not in core

    def extra(name):
        return re.search(rf"^{name}\s*=\s*\[(.*?)\]\s*$", extras, re.M | re.S).group(1)

    assert "numba" in extra("fast") and "numba" in extra("test")


def test_emittable_refuses_what_it_has_no_rule_for():
    import sympy as sp

    x = sp.Symbol("x")
    assert numba_backend.emittable(sp.sin(x) + sp.Piecewise((x, x > 0), (-x, True)), {x})
    assert not numba_backend.emittable(sp.floor(x), {x})
    assert not numba_backend.emittable(sp.sin(sp.Symbol("unknown")), {x})
    assert "\n" not in textwrap.dedent(numba_backend.why_unavailable() or "")
