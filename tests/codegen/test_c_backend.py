"""The C back end (:mod:`phc.codegen.c_backend`) against the reference NumPy module.

The C file prints the same expressions as the NumPy module, in the same evaluation order,
with the same ``math.h`` functions CPython's ``math`` calls and literals that read back as
the same doubles; it is compiled without fused multiply-adds or ``-ffast-math``. What may
differ is the order of some sums: common subexpressions can regroup a sum's terms, and the
linear blocks are summed term by term in the C file where the NumPy module adds all of a
row's entries in one scipy product. Each regrouping changes a result by at most a few units
in the last place of the largest partial sums, i.e. by (number of terms)·ε·(magnitude of the
terms); at random states of order 1 the terms are of the order of the vector's largest entry
and rows have at most a few hundred terms, so 1e-12 of the vector's largest entry bounds it
with margin (ε = 2.2e-16; the same bound holds on x86-64 CPUs with or without FMA units,
as none is used). Points where the reference raises (a domain error that C turns into a
NaN) are skipped; non-finite entries must be non-finite in both.

Without a C compiler these tests are skipped, except the refusals, which need none.
"""

from __future__ import annotations

import ctypes
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.codegen import backends, c_backend
from phc.errors import CacheWarning, SimulationSetupError
from compiled_loading import assert_close, call, load_with  # shared with tests/codegen/test_backends.py
from model_texts import EVERY_FUNCTION  # shared with tests/codegen/test_backends.py

ROOT = Path(__file__).resolve().parents[2]
MODELS = sorted((ROOT / "models").glob("*.yaml"))

_OK, _WHY = c_backend.available()
needs_cc = pytest.mark.skipif(not _OK, reason=f"C backend not tested: {_WHY}")

TOL = 1e-12
"""Agreement required, relative to the largest entry of the vector (see the module docstring)."""


def _assert_same(ref, fast, functions=c_backend.FUNCTIONS, seed=0, points=6, p=None):
    rng = np.random.default_rng(seed)
    p = np.asarray(ref.full_parameters() if p is None else p, dtype=float)
    checked = 0
    for _ in range(points):
        t, cj = float(rng.uniform(0.0, 2.0)), float(rng.uniform(0.1, 50.0))
        y, yp = rng.uniform(-1.0, 1.0, ref.N), rng.uniform(-1.0, 1.0, ref.N)
        for name in functions:
            with np.errstate(all="ignore"):
                try:
                    a = call(ref, name, t, y, yp, p, cj)
                except (ArithmeticError, ValueError, TypeError):
                    continue  # outside the reference's domain (Python raises; C gives NaN)
                b = call(fast, name, t, y, yp, p, cj)
            assert_close(name, a, b, TOL)
            checked += 1
    assert checked


@needs_cc
@pytest.mark.parametrize("path", MODELS, ids=[p.stem for p in MODELS])
def test_c_functions_equal_the_reference_on_every_shipped_model(path):
    compiled = phc.compile_model(path, certify=False, backend="c")
    assert compiled.backend == "c"
    fast = compiled.module
    ref = fast.REFERENCE
    assert backends.name_of(ref) == "numpy"
    assert "phc_residual(" in fast.C_SOURCE and "static double phc_sign" in fast.C_SOURCE
    _assert_same(ref, fast)


@needs_cc
def test_every_function_of_the_language_is_printed_in_c_like_the_python(tmp_path):
    """Every function and condition of the model language, switches frozen to either side
    (the event driver's parameters) and at the switching points themselves."""
    path = tmp_path / "every_function.yaml"
    path.write_text(EVERY_FUNCTION)
    fast = phc.compile_model(path, certify=False, backend="c").module
    ref = fast.REFERENCE
    _assert_same(ref, fast, seed=3, points=20)
    modes = [j for j, name in enumerate(ref.PARAMETERS) if name.startswith("switch[")]
    assert len(modes) == 2  # sign(t - 0.3) and heaviside(spring.x - 0.05) in the residual rows
    for side in (-1.0, 1.0):
        p = np.asarray(ref.full_parameters(), dtype=float)
        p[modes] = side
        _assert_same(ref, fast, functions=("residual", "jacobian", "residual_t"), seed=4, p=p)
    p = np.asarray(ref.full_parameters(), dtype=float)
    for x, v in ((0.1, 0.0), (0.0, 0.0), (-0.2, 0.1), (0.05, -1.0)):
        y = np.zeros(ref.N)
        y[list(ref.VARIABLES).index("spring.x")] = x
        y[list(ref.VARIABLES).index("mass.p")] = v
        with np.errstate(all="ignore"):
            a, b = ref.outputs(0.3, y, y, p), fast.outputs(0.3, y, y, p)
        assert np.array_equal(np.isfinite(a), np.isfinite(b))
        np.testing.assert_allclose(b[np.isfinite(a)], a[np.isfinite(a)], rtol=TOL, atol=0)


@needs_cc
def test_sparse_blocks_and_quadratic_forms(tmp_path):
    """The vibrating string, 3 elements, damped: sparse linear blocks, quadratic energies and a
    quadratic dissipation form as loops over constant CSR arrays of the C file."""
    text = (ROOT / "models" / "vibrating_string.yaml").read_text()
    assert "    elements: 16\n" in text
    path = tmp_path / "damped_string.yaml"
    path.write_text(text.replace("    elements: 16\n", "    elements: 3\n    damping: 0.05\n"))
    fast = phc.compile_model(path, certify=False, backend="c").module
    for helper in ("phc_matvec_add(", "phc_scatter_add(", "phc_quadratic(", "phc_gradient_add("):
        assert fast.C_SOURCE.count(helper) >= 2, helper  # defined, and called
    _assert_same(fast.REFERENCE, fast, seed=11)


@needs_cc
def test_arrays_of_any_layout_and_short_arrays(tmp_path):
    """Read-only and strided inputs, a strided output (written back), and a short array
    refused before the C code could read past its end."""
    fast = phc.compile_model(ROOT / "models" / "pendulum.yaml", certify=False, backend="c").module
    ref = fast.REFERENCE
    rng = np.random.default_rng(7)
    n = ref.N
    y, yp = rng.uniform(-1, 1, 2 * n)[::2], rng.uniform(-1, 1, n)
    yp.setflags(write=False)
    p = np.asarray(ref.full_parameters(), dtype=float)
    a, b = np.zeros(n), np.zeros(2 * n)[::2]
    ref.residual(0.1, y, yp, p, a)
    fast.residual(0.1, y, yp, p, b)
    np.testing.assert_allclose(b, a, rtol=TOL, atol=0)
    with pytest.raises(ValueError, match="`y` has shape"):
        fast.residual(0.1, y[:-1], yp, p, b)
    with pytest.raises(ValueError, match="`out` has"):
        fast.jacobian(0.1, y, yp, p, 1.0, np.zeros(len(ref.JAC_ROWS) - 1))


@needs_cc
def test_the_call_bridge_and_ctypes_compute_the_same_on_arrays_of_any_layout(monkeypatch):
    """The call bridge (phc.codegen.c_bridge: the buffer protocol in C) and the ctypes
    wrappers (PHC_C_BRIDGE=0) call the same C functions: bit-for-bit equal results on IDA's
    read-only state vectors, and vectors that are not contiguous float64 (strided, float32, a
    list) converted or refused alike. Without Python's C headers only ctypes is checked."""
    from phc.codegen import c_bridge

    fast = phc.compile_model(ROOT / "models" / "rigid_slider_crank.yaml", certify=False, backend="c").module
    ref = fast.REFERENCE
    monkeypatch.setenv("PHC_C_BRIDGE", "0")
    plain, _ = c_backend.load_source(fast.C_SOURCE, ref)  # the same library, ctypes wrappers
    assert "called through ctypes: switched off" in backends.describe(plain)
    monkeypatch.delenv("PHC_C_BRIDGE")
    c_bridge.bridge()  # built now: a module loaded after it calls through it from its first call
    bridged, _ = c_backend.load_source(fast.C_SOURCE, ref)
    rng = np.random.default_rng(3)
    n, m, nj = ref.N, len(ref.EQUATIONS), len(ref.JAC_ROWS)
    p = np.asarray(ref.full_parameters(), dtype=float)
    y, yp = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    y.setflags(write=False)
    yp.setflags(write=False)
    layouts = [(y, yp), (rng.uniform(-1, 1, 2 * n)[::2], yp), (y.astype(np.float32), list(yp))]
    for a, b in layouts:
        results = []
        for module in (bridged, plain):
            res, jac = np.empty(m), np.zeros(2 * nj)[::2]  # a strided output is written back
            module.residual(0.4, a, b, p, res)
            module.jacobian(0.4, a, b, p, 7.0, jac)
            results.append((res, jac))
        (r1, j1), (r2, j2) = results
        assert np.array_equal(r1, r2) and np.array_equal(j1, j2)
        expected = np.empty(m)
        ref.residual(0.4, np.asarray(a, float), np.asarray(b, float), p, expected)
        np.testing.assert_allclose(r1, expected, rtol=0, atol=TOL * max(1.0, np.abs(expected).max()))
    for module in (bridged, plain):
        with pytest.raises(ValueError, match="`y` has shape"):
            module.residual(0.1, y[:-1], yp, p, np.empty(m))
        with pytest.raises(ValueError, match="`out` has"):
            module.residual(0.1, y, yp, p, np.empty(m - 1))
        with pytest.raises((TypeError, ctypes.ArgumentError)):  # refused before any C code runs
            module.jacobian(0.1, y, yp, p, None, np.empty(nj))
    assert c_bridge.why_not() or c_bridge.bridge() is not None


@needs_cc
@pytest.mark.parametrize("model, step", [("mass_spring_damper", 1e-2), ("pendulum", 1e-2),
                                         ("rigid_slider_crank", 1e-3)])
def test_a_midpoint_run_on_c_equals_the_numpy_run(model, step):
    """The states (what the midpoint rule integrates) agree to 1e-10: each step's equations
    are the same to round-off and solved to the Newton tolerance 1e-14 (relative), and at most
    a few hundred steps accumulate that. The algebraic variables (constraint forces) are not
    integrated: they are recomputed from the states at each output time
    (:mod:`phc.simulation.polish`), a least-squares solve that amplifies round-off by the
    conditioning of the constraints (a multiplier moves by 1e-9 of its size between two runs
    whose residuals differ in the last bit). For them the test asks what that solve
    guarantees: the C run's values satisfy the model's equations as well as the NumPy run's."""
    compiled = phc.compile_model(ROOT / "models" / f"{model}.yaml", certify=False, backend="numpy")
    ref = phc.simulate(compiled, t_end=0.5, solver="midpoint", step=step)
    fast = phc.simulate(compiled, t_end=0.5, solver="midpoint", step=step, backend="c")
    assert ref.success and fast.success
    assert compiled.backend == "numpy"  # a run on another backend leaves the compiled model as it was
    states = np.asarray(ref.differential, dtype=bool)
    scale = np.maximum(np.abs(ref.y).max(axis=0), 1e-300)
    np.testing.assert_allclose(fast.y[:, states] / scale[states], ref.y[:, states] / scale[states], rtol=0,
                               atol=1e-10)
    mod = compiled.module
    p = np.asarray(mod.full_parameters(), dtype=float)
    # H may be ~0 (a pendulum's kinetic and potential energy cancel): measured against the sum of |terms|
    energy_scale = max(mod.energy_scale(float(t), y, p) for t, y in zip(ref.t, ref.y))
    np.testing.assert_allclose(fast.H, ref.H, rtol=0, atol=1e-10 * energy_scale)

    def worst_residual(run):
        worst, out = 0.0, np.zeros(mod.N)
        for k, t in enumerate(run.t):
            mod.residual(float(t), run.y[k], run.yp[k], p, out)
            worst = max(worst, float(np.abs(out).max()))
        return worst

    floor = 1e-12 * float(np.abs(ref.y).max())
    assert worst_residual(fast) <= 10.0 * worst_residual(ref) + floor


@needs_cc
def test_a_model_sent_to_a_worker_runs_on_the_c_backend_again():
    """`phc sweep` pickles the compiled model to its workers: the C module is rebuilt there."""
    import pickle

    compiled = phc.compile_model(ROOT / "models" / "rlc_circuit.yaml", certify=False, backend="c")
    again = pickle.loads(pickle.dumps(compiled))
    assert again.backend == "c" and again.module is not compiled.module
    _assert_same(again.module.REFERENCE, again.module, points=2)


# ---------------------------------------------------------------------------------------
# the signed cache


@needs_cc
def test_libraries_are_cached_signed_and_a_tampered_one_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    monkeypatch.setattr(c_backend, "_LOADED", {})
    compilations = []
    real_compile = c_backend._compile

    def counting(*args):
        compilations.append(args[2])
        return real_compile(*args)

    monkeypatch.setattr(c_backend, "_compile", counting)
    model = ROOT / "models" / "mass_spring_damper.yaml"
    fast, cold = load_with(c_backend, model)
    assert cold.cached == "cold" and len(compilations) == 1
    folder = tmp_path / "cache" / "c"
    assert oct(folder.stat().st_mode & 0o777) == oct(0o700)
    stem = f"phc_c_{cold.digest}"
    assert sorted(p.name for p in folder.iterdir()) == [f"{stem}.c", f"{stem}.sig", f"{stem}.so"]
    assert (folder / f"{stem}.c").read_text() == fast.C_SOURCE
    assert (folder / f"{stem}.sig").read_bytes().startswith(c_backend.MAGIC)

    # a second load (a new process: nothing in memory) takes the library from the cache
    monkeypatch.setattr(c_backend, "_LOADED", {})
    again, warm = load_with(c_backend, model)
    assert warm.cached == "warm" and len(compilations) == 1
    _assert_same(again.REFERENCE, again)

    # a tampered library (one byte of its code) is refused, compiled again, with one warning
    lib = folder / f"{stem}.so"
    raw = bytearray(lib.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    lib.write_bytes(bytes(raw))
    monkeypatch.setattr(c_backend, "_LOADED", {})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rebuilt, report = load_with(c_backend, model)
    cache_warnings = [w for w in caught if issubclass(w.category, CacheWarning)]
    assert len(cache_warnings) == 1 and "does not verify" in str(cache_warnings[0].message)
    assert report.cached == "cold" and len(compilations) == 2
    assert lib.read_bytes() != bytes(raw)  # replaced by the new build
    _assert_same(rebuilt.REFERENCE, rebuilt)

    # a library signed under another user's key (a cache restored from elsewhere) is never loaded
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "other-state"))
    monkeypatch.setattr(c_backend, "_LOADED", {})
    with pytest.warns(CacheWarning, match="does not verify"):
        _, foreign = load_with(c_backend, model)
    assert foreign.cached == "cold" and len(compilations) == 3

    # `phc cache clean` removes the libraries, their tags and C texts with the rest
    from phc.codegen.load import clean

    clean()
    assert list(folder.iterdir()) == []


def test_a_translated_text_is_kept_signed_and_made_again_when_tampered_or_its_inputs_change(tmp_path, monkeypatch):
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    source = tmp_path / "input.py"
    source.write_text("x = 1\n")
    made = []

    def make():
        made.append(1)
        return f"/* made {len(made)} */\n"

    first = c_backend.translated_text("probe", (source,), make)
    assert first == "/* made 1 */\n" and len(made) == 1
    assert c_backend.translated_text("probe", (source,), make) == first and len(made) == 1  # from the cache
    (kept,) = (tmp_path / "cache" / "c").glob("phc_text_probe_*.c")
    kept.write_bytes(kept.read_bytes().replace(b"made 1", b"made 9"))  # tampered: not used, made again
    assert c_backend.translated_text("probe", (source,), make) == "/* made 2 */\n"
    source.write_text("x = 2\n")  # another input: another text
    assert c_backend.translated_text("probe", (source,), make) == "/* made 3 */\n"
    monkeypatch.setenv("PHC_COMPILED_CACHE", "0")  # the cache off: always made
    assert c_backend.translated_text("probe", (source,), make) == "/* made 4 */\n"


def test_the_cached_translations_are_the_translations():
    from phc.codegen import c_ida, c_steps

    assert c_steps.source() == c_steps.make_source()
    assert c_ida.source() == c_ida.make_source()


@needs_cc
def test_a_cache_directory_others_can_write_is_not_used(tmp_path, monkeypatch):
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    monkeypatch.setattr(c_backend, "_LOADED", {})
    (tmp_path / "cache" / "c").mkdir(parents=True, mode=0o700)
    os.chmod(tmp_path / "cache" / "c", 0o777)
    fast, report = load_with(c_backend, ROOT / "models" / "mass_spring_damper.yaml")
    assert report.cached == "off" and "writable by other users" in report.note
    assert list((tmp_path / "cache" / "c").iterdir()) == []
    _assert_same(fast.REFERENCE, fast, functions=("residual", "jacobian"))


# ---------------------------------------------------------------------------------------
# refusals: one message each

TABLED = EVERY_FUNCTION.replace('force: {effort: "-0.1*sin(3*t)"}', "force: {effort: {file: force.csv, column: f}}")


def test_an_input_table_is_refused_with_one_message(tmp_path, monkeypatch):
    monkeypatch.setitem(c_backend._COMPILERS, (os.environ.get("CC", "").strip(), os.environ.get("PATH", "")),
                        (["cc"], "a compiler"))  # the refusal comes before any compilation
    (tmp_path / "force.csv").write_text("t,f\n0,0\n0.25,1\n0.5,-0.5\n1,2\n")
    path = tmp_path / "tabled.yaml"
    path.write_text(TABLED)
    with pytest.raises(SimulationSetupError) as err:
        phc.compile_model(path, certify=False, backend="c")
    message = str(err.value)
    assert "\n" not in message
    assert "does not support input tables" in message and "--backend numpy" in message
    assert phc.compile_model(path, certify=False, backend="numpy").backend == "numpy"


def test_without_a_c_compiler_the_c_backend_is_refused_with_one_message(tmp_path, monkeypatch):
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    with pytest.raises(SimulationSetupError) as err:
        phc.compile_model(ROOT / "models" / "pendulum.yaml", certify=False, backend="c")
    message = str(err.value)
    assert "\n" not in message and "no C compiler found" in message and "--backend numpy" in message
    done = subprocess.run([sys.executable, "-m", "phc", "simulate", str(ROOT / "models" / "pendulum.yaml"),
                           "--quiet", "--no-certify", "--t-end", "0.01", "--backend", "c"],
                          capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, CC=str(tmp_path / "no-such-cc")))
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "no C compiler found" in lines[0] and "Traceback" not in done.stderr


_BRIDGE_PROBE = r"""
import json, sys
import numpy as np
import phc
from phc.codegen import c_backend, c_bridge
compiled = phc.compile_model(sys.argv[1], backend="c")  # certified: its cross-check and certificate call C
after_compile = c_bridge.built()
mod = compiled.module
rng = np.random.default_rng(7)  # a state where every entry is finite, as the load's cross-check uses
y, yp = rng.uniform(0.2, 0.8, mod.N), rng.uniform(-0.5, 0.5, mod.N)
p = np.asarray(mod.full_parameters(), dtype=float)
out, jac = np.empty(len(mod.EQUATIONS)), np.empty(len(mod.JAC_ROWS))
for k in range(c_backend.BRIDGE_AFTER + 1):
    mod.residual(0.0, y, yp, p, out)
    if k == 0:
        first = out.copy()
print(json.dumps({"after_compile": after_compile is None, "after_calls": c_bridge.built() is not None,
                  "why": c_bridge.why_not(), "same": bool(np.array_equal(first, out)), "finite": bool(np.isfinite(out).all())}))
"""


@needs_cc
def test_compiling_does_not_build_the_call_bridge_a_run_of_calls_does(tmp_path):
    """Building phc's call bridge costs the C compiler about 0.2 s (Python's C headers), which
    a certified compilation (a few hundred calls) does not need: in a fresh process with an
    empty cache it is built at a module's BRIDGE_AFTER-th call, not before, and the calls
    give the same numbers before and after."""
    env = dict(os.environ, PHC_CACHE_DIR=str(tmp_path / "cache"), PHC_STATE_DIR=str(tmp_path / "state"))
    env.pop("PHC_C_BRIDGE", None)
    done = subprocess.run([sys.executable, "-c", _BRIDGE_PROBE, str(ROOT / "models" / "flexible_slider_crank.yaml")],
                          capture_output=True, text=True, timeout=600, env=env, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    assert seen["after_compile"], "the call bridge was built while compiling"
    assert seen["after_calls"] or seen["why"], "no bridge after BRIDGE_AFTER calls, and no reason given"
    assert seen["finite"] and seen["same"]  # through ctypes (first call) and the bridge (last): bit-equal


@needs_cc
def test_the_command_line_runs_and_writes_the_c_file(tmp_path):
    model = ROOT / "models" / "pendulum.yaml"
    done = subprocess.run([sys.executable, "-m", "phc", "compile", str(model), "--no-certify", "--backend", "c",
                           "-o", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "backend  c: compiled functions (" in done.stdout
    c_file = next(tmp_path.glob("*.c"))
    text = c_file.read_text()
    compiled = phc.compile_model(model, certify=False, backend="numpy")
    names = compiled.module.VARIABLES
    assert all(f"y[{j}]  {name}" in text for j, name in enumerate(names))  # the header lists them
    assert sum(f"  /* {name} */" in text for name in names) >= len(names) // 2  # and the functions' locals
    # the file compiles on its own, as C99, without warnings
    done = subprocess.run([*c_backend.find_compiler()[0], *c_backend.FLAGS, "-Wall", "-Werror", "-Wno-unused",
                           "-o", str(tmp_path / "alone.so"), str(c_file), "-lm"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    lib = ctypes.CDLL(str(tmp_path / "alone.so"))
    sizes = (ctypes.c_longlong * 8)()
    lib.phc_sizes(sizes)
    assert list(sizes) == c_backend.sizes_of(compiled.module)


# ---------------------------------------------------------------------------------------
# model text is data in the C file too

def test_model_names_in_comments_cannot_end_the_comment():
    from phc.codegen.c_printer import comment, number

    text = comment("a */ int evil; /* b\nc\x00")
    assert "*/" not in text and "/*" not in text and "\n" not in text and "\x00" not in text
    assert [number(x) for x in (0.1, -2.5, 1e-300, float("inf"), float("-inf"))] == [
        "0.1", "(-2.5)", "1e-300", "INFINITY", "(-INFINITY)"]
    assert number(float("nan")) == "NAN"


@needs_cc
def test_descriptions_and_units_do_not_reach_the_c_file(tmp_path):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    try:
        from test_injection import OSCILLATOR, _quoted
    finally:
        sys.path.pop(0)
    payload = "*/ #error injected /*"
    model = tmp_path / "osc.yaml"
    model.write_text(OSCILLATOR.format(description=_quoted(payload), unit="N/m"))
    fast = phc.compile_model(model, certify=False, backend="c").module
    assert "injected" not in fast.C_SOURCE
    _assert_same(fast.REFERENCE, fast, points=2)
