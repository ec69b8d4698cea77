"""Tests for the generated residual modules (:mod:`phc.codegen.printer`, :mod:`phc.codegen.lower`,
:mod:`phc.codegen.load`), run on every shipped model in ``models/``.

The generated module is checked as a product of its own: importable without phc,
its analytic Jacobian and explicit time derivative against central finite
differences of its residual, its sparsity pattern in compressed-sparse-column order,
its parameter handling, and the determinism and content-hash caching of the source.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.errors import SimulationSetupError
from phc.simulation import parameter_vector
from time_limits import SUBPROCESS_TIMEOUT

REPO = Path(__file__).resolve().parents[2]
MODEL_FILES = sorted((REPO / "models").glob("*.yaml"))
MODEL_IDS = [path.stem for path in MODEL_FILES]

_COMPILED: dict[Path, phc.CompiledModel] = {}


def compiled_model(path: Path) -> phc.CompiledModel:
    """Compile each model once per test session (compilation is deterministic)."""
    if path not in _COMPILED:
        _COMPILED[path] = phc.compile_model(path)
    return _COMPILED[path]


def random_point(mod, seed: int):
    """A random point (t, y, yp) and a random cj in [1e-2, 1e4] (log-uniform)."""
    rng = np.random.default_rng(seed)
    t = float(rng.uniform(0.0, 2.0))
    y = rng.uniform(-1.0, 1.0, mod.N)
    yp = rng.uniform(-1.0, 1.0, mod.N)
    cj = float(10.0 ** rng.uniform(-2.0, 4.0))
    return t, y, yp, cj


def evaluate_residual(mod, t, y, yp, p) -> np.ndarray:
    out = np.full(len(mod.EQUATIONS), np.nan)
    mod.residual(t, y, yp, p, out)
    return out


def dense_jacobian(mod, t, y, yp, p, cj) -> np.ndarray:
    data = np.full(len(mod.JAC_ROWS), np.nan)
    mod.jacobian(t, y, yp, p, cj, data)
    dense = np.zeros((len(mod.EQUATIONS), mod.N))
    np.add.at(dense, (np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)), data)
    return dense


def fd_derivatives(mod, t, y, yp, p) -> tuple[np.ndarray, np.ndarray]:
    """(dF/dy, dF/dyp) by central differences of `residual`."""
    dfdy = np.zeros((len(mod.EQUATIONS), mod.N))
    dfdyp = np.zeros((len(mod.EQUATIONS), mod.N))
    for j in range(mod.N):
        step = np.zeros(mod.N)
        step[j] = h = FD_STEP * max(1.0, abs(y[j]))
        dfdy[:, j] = (evaluate_residual(mod, t, y + step, yp, p) - evaluate_residual(mod, t, y - step, yp, p)) / (2 * h)
        step[j] = h = FD_STEP * max(1.0, abs(yp[j]))
        dfdyp[:, j] = (evaluate_residual(mod, t, y, yp + step, p) - evaluate_residual(mod, t, y, yp - step, p)) / (2 * h)
    return dfdy, dfdyp


FD_STEP = 1e-6
"""Relative step of the central differences."""


def fd_noise(mod, t, y, yp, p, dfdy, dfdyp) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the round-off in :func:`fd_derivatives`' columns: a residual row whose terms are
    of size T_i is evaluated to about eps·T_i (T_i: |F_i| plus each term's size, |dF_i/dy_j|·|y_j|
    and |dF_i/dyp_j|·|yp_j|), and a central difference divides two such errors by 2h. 16·eps
    allows for the dozens of roundings of a row. Negligible in a well-scaled model; it is what
    decides a model whose rows add terms of very different sizes (the woodpecker: a moment of
    inertia of 5e-9 kg m² beside gravity forces)."""
    terms = np.abs(evaluate_residual(mod, t, y, yp, p)) + np.abs(dfdy) @ np.abs(y) + np.abs(dfdyp) @ np.abs(yp)
    bound = 16 * np.finfo(float).eps * terms[:, None]
    return bound / (FD_STEP * np.maximum(1.0, np.abs(y)))[None, :], bound / (FD_STEP * np.maximum(1.0, np.abs(yp)))[None, :]


def assert_close_to_fd(analytic, numeric, noise=0.0):
    # Central differences with h = 1e-6 are accurate to ~1e-9 relative to the entries, plus the
    # round-off of the residual's evaluation (`noise`, from fd_noise).
    scale = max(1.0, float(np.abs(numeric).max()))
    off = np.abs(analytic - numeric) - (1e-6 * np.abs(numeric) + 1e-8 * scale + noise)
    assert (off <= 0).all(), (np.argwhere(off > 0)[:5].tolist(), analytic[off > 0][:5], numeric[off > 0][:5])


# -- standalone --------------------------------------------------------------------

STANDALONE_SCRIPT = textwrap.dedent(
    """
    import importlib.util, json, sys

    BLOCKED = {"phc", "sympy", "networkx", "pydantic", "yaml", "sksundae"}  # numpy and scipy are allowed

    class Blocker:
        def find_spec(self, name, path=None, target=None):
            if name.partition(".")[0] in BLOCKED:
                raise ImportError(f"generated module must not import {name}")
            return None

    sys.meta_path.insert(0, Blocker())
    import numpy as np

    spec = importlib.util.spec_from_file_location("generated_model", sys.argv[1])
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    p = mod.full_parameters()
    y = np.linspace(0.1, 0.9, mod.N)
    yp = np.linspace(-0.5, 0.5, mod.N)
    res = np.full(len(mod.EQUATIONS), np.nan)
    mod.residual(0.3, y, yp, p, res)
    jac = np.full(len(mod.JAC_ROWS), np.nan)
    mod.jacobian(0.3, y, yp, p, 2.0, jac)
    print(json.dumps({
        "model": mod.MODEL,
        "phc_imported": "phc" in sys.modules,
        "residual_finite": bool(np.all(np.isfinite(res))),
        "jacobian_finite": bool(np.all(np.isfinite(jac))),
    }))
    """
)


@pytest.mark.parametrize("path", MODEL_FILES, ids=MODEL_IDS)
def test_generated_module_imports_and_runs_without_phc(path, tmp_path):
    compiled = compiled_model(path)
    module_file = tmp_path / f"{compiled.name}.py"
    module_file.write_text(compiled.source)
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, "-c", STANDALONE_SCRIPT, str(module_file)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT, env=env)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report == {"model": compiled.name, "phc_imported": False, "residual_finite": True,
                      "jacobian_finite": True}


# -- Jacobian ----------------------------------------------------------------------


@pytest.mark.parametrize("path", MODEL_FILES, ids=MODEL_IDS)
def test_jacobian_pattern_is_csc_ordered_without_duplicates(path):
    mod = compiled_model(path).module
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    assert len(rows) == len(cols) > 0
    assert len(mod.EQUATIONS) == mod.N == len(mod.VARIABLES)
    assert rows.min() >= 0 and rows.max() < len(mod.EQUATIONS)
    assert cols.min() >= 0 and cols.max() < mod.N
    keys = list(zip(cols.tolist(), rows.tolist()))
    assert keys == sorted(set(keys))  # strictly increasing: sorted by (column, row), no duplicates


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("path", MODEL_FILES, ids=MODEL_IDS)
def test_jacobian_matches_central_differences(path, seed):
    mod = compiled_model(path).module
    p = mod.full_parameters()
    t, y, yp, cj = random_point(mod, seed)
    dfdy, dfdyp = fd_derivatives(mod, t, y, yp, p)
    noise_y, noise_yp = fd_noise(mod, t, y, yp, p, dfdy, dfdyp)
    # Comparing the full dense matrices also checks that the pattern misses no nonzero.
    assert_close_to_fd(dense_jacobian(mod, t, y, yp, p, cj), dfdy + cj * dfdyp, noise_y + cj * noise_yp)
    # Each part on its own, so that a small cj cannot hide an error in dF/dyp.
    j0 = dense_jacobian(mod, t, y, yp, p, 0.0)
    assert_close_to_fd(j0, dfdy, noise_y)
    assert_close_to_fd(dense_jacobian(mod, t, y, yp, p, 1.0) - j0, dfdyp, noise_yp)


@pytest.mark.parametrize("path", MODEL_FILES, ids=MODEL_IDS)
def test_jacobian_is_affine_in_cj(path):
    mod = compiled_model(path).module
    p = mod.full_parameters()
    t, y, yp, _ = random_point(mod, 7)
    j0, j1, j5 = (dense_jacobian(mod, t, y, yp, p, cj) for cj in (0.0, 1.0, 5.0))
    np.testing.assert_allclose(j5, j0 + 5.0 * (j1 - j0), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("path", MODEL_FILES, ids=MODEL_IDS)
def test_residual_t_matches_central_difference_in_t(path, seed):
    mod = compiled_model(path).module
    p = mod.full_parameters()
    t, y, yp, _ = random_point(mod, seed)
    analytic = np.full(len(mod.EQUATIONS), np.nan)
    mod.residual_t(t, y, yp, p, analytic)
    h = 1e-6 * max(1.0, abs(t))
    numeric = (evaluate_residual(mod, t + h, y, yp, p) - evaluate_residual(mod, t - h, y, yp, p)) / (2 * h)
    assert_close_to_fd(analytic, numeric)


def test_residual_t_is_nonzero_for_the_driven_slider_crank():
    # The drive imposes theta = omega*t: the time derivative must not be identically zero,
    # otherwise the previous test would be vacuous for every shipped model.
    mod = compiled_model(REPO / "models" / "rigid_slider_crank.yaml").module
    p = mod.full_parameters()
    t, y, yp, _ = random_point(mod, 3)
    out = np.zeros(len(mod.EQUATIONS))
    mod.residual_t(t, y, yp, p, out)
    assert np.count_nonzero(out) > 0


# -- parameters --------------------------------------------------------------------


@pytest.mark.parametrize("path", MODEL_FILES, ids=MODEL_IDS)
def test_full_parameters_of_defaults_are_the_defaults(path):
    mod = compiled_model(path).module
    defaults = np.asarray(mod.PARAMETER_DEFAULTS)
    base = defaults[list(mod.BASE_PARAMETERS)]
    assert mod.full_parameters().tolist() == defaults.tolist()
    assert mod.full_parameters(base).tolist() == defaults.tolist()
    assert len(mod.PARAMETERS) == len(defaults)


def test_derived_parameter_follows_its_base_parameters():
    mod = compiled_model(REPO / "models" / "rigid_slider_crank.yaml").module
    names = list(mod.PARAMETERS)
    base_names = [names[i] for i in mod.BASE_PARAMETERS]
    assert "Jr" not in base_names
    defaults = mod.full_parameters()
    assert defaults[names.index("Jr")] == pytest.approx(0.15 * 0.30**2 / 12, rel=1e-15)

    base = np.asarray(mod.PARAMETER_DEFAULTS)[list(mod.BASE_PARAMETERS)].copy()
    base[base_names.index("mr")] = 0.4
    base[base_names.index("L")] = 0.5
    p = mod.full_parameters(base)
    assert p[names.index("Jr")] == pytest.approx(0.4 * 0.5**2 / 12, rel=1e-15)
    assert p[names.index("mr")] == 0.4
    assert p[names.index("L")] == 0.5
    assert mod.full_parameters()[names.index("Jr")] == defaults[names.index("Jr")]  # defaults not mutated


def test_parameter_vector_by_name_updates_derived_and_rejects_derived_override():
    mod = compiled_model(REPO / "models" / "rigid_slider_crank.yaml").module
    p = parameter_vector(mod, {"mr": 0.6})
    assert p[mod.PARAMETERS.index("Jr")] == pytest.approx(0.6 * 0.30**2 / 12, rel=1e-15)
    with pytest.raises(SimulationSetupError, match="derived"):
        parameter_vector(mod, {"Jr": 1.0})


# -- determinism and caching -------------------------------------------------------


@pytest.mark.parametrize("path", MODEL_FILES, ids=MODEL_IDS)
def test_compilation_is_deterministic_and_cached_by_content(path):
    first = phc.compile_model(path)
    second = phc.compile_model(path)
    assert second.source == first.source
    assert second.module_path == first.module_path
    assert first.module_path.is_file()
    assert first.module_path.read_text() == first.source
    assert first.module_path.parent == Path(os.environ["PHC_CACHE_DIR"])
    assert hashlib.sha256(first.source.encode()).hexdigest()[:16] in first.module_path.name


def test_different_models_get_different_cache_files():
    paths = {compiled_model(path).module_path for path in MODEL_FILES}
    assert len(paths) == len(MODEL_FILES)


def test_generated_source_does_not_depend_on_the_hash_seed():
    # Set iteration order in sympy depends on PYTHONHASHSEED; the output must not.
    script = ("import hashlib, json, sys, phc\n"
              "print(json.dumps({p: hashlib.sha256(phc.compile_model(p).source.encode()).hexdigest() "
              "for p in sys.argv[1:]}))")
    expected = {str(p): hashlib.sha256(compiled_model(p).source.encode()).hexdigest() for p in MODEL_FILES}
    procs = [subprocess.Popen([sys.executable, "-c", script, *map(str, MODEL_FILES)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONHASHSEED=seed))
             for seed in ("1", "12345")]
    for proc in procs:
        stdout, stderr = proc.communicate(timeout=SUBPROCESS_TIMEOUT)
        assert proc.returncode == 0, stderr
        assert json.loads(stdout) == expected
