"""phc.study.ode_form: a compiled model as ẋ = f(t, x) for scipy's solve_ivp methods (`phc bench`
runs Radau, BDF and DOP853 with it beside phc's solvers)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc
from phc.study.ode_form import NOT_AN_ODE, NotAnODE, OdeForm, integrate

MODELS = Path(__file__).resolve().parents[1] / "models"
L, C, R, V0 = 0.5, 0.02, 2.0, 12.0  # models/rlc_circuit.yaml


def rlc_closed_form(t):
    """L q'' + R q' + q/C = V0 from rest: α = R/2L, ω = sqrt(1/LC − α²)."""
    a = R / (2 * L)
    w = np.sqrt(1 / (L * C) - a * a)
    q = C * V0 * (1 - np.exp(-a * t) * (np.cos(w * t) + a / w * np.sin(w * t)))
    i = V0 / (L * w) * np.exp(-a * t) * np.sin(w * t)
    return q, i


@pytest.fixture(scope="module")
def rlc():
    return OdeForm(phc.compile_model(MODELS / "rlc_circuit.yaml"))


def test_radau_on_the_ode_form_reproduces_the_rlc_closed_form(rlc):
    t = np.linspace(0.0, 2.0, 41)
    run = integrate(rlc, "Radau", t, rtol=1e-10, atol=1e-12)
    assert run["success"], run["message"]
    assert run["steps"] > 0 and run["njev"] >= 1  # the Jacobian was used
    out = rlc.outputs(run["t"], run["y"], run["yp"], run["p"])
    q, i = rlc_closed_form(t)
    # Radau at rtol 1e-10 over ~3 decay times: a global error of a few 1e-10 of the amplitude
    # (q ≤ 0.4 C, i ≤ 2.4 A); 1e-7 absolute leaves three decades for its accumulation
    assert np.max(np.abs(out["charge"] - q)) < 1e-7
    assert np.max(np.abs(out["current"] - i)) < 1e-7


def test_rates_and_jacobian_are_the_circuit_equations(rlc):
    """f and ∂f/∂x at a state off the start: q̇ = φ/L, φ̇ = V0 − Rφ/L − q/C (round-off: the
    chord iteration stops at 1e-13 of |w|)."""
    mod = rlc.mod
    states = [v for v, d in zip(mod.VARIABLES, mod.DIFFERENTIAL) if d]
    iq, ip = states.index("capacitor.q"), states.index("inductor.phi")
    x = np.zeros(len(states))
    x[iq], x[ip] = 0.1, 0.3
    f = rlc.fun(0.7, x)
    assert f[iq] == pytest.approx(0.3 / L, rel=1e-12)
    assert f[ip] == pytest.approx(V0 - R * 0.3 / L - 0.1 / C, rel=1e-12)
    J = rlc.jac(0.7, x)
    assert J[iq, ip] == pytest.approx(1 / L, rel=1e-12)
    assert J[ip, ip] == pytest.approx(-R / L, rel=1e-12)
    assert J[ip, iq] == pytest.approx(-1 / C, rel=1e-12)
    assert J[iq, iq] == pytest.approx(0.0, abs=1e-12)


def test_a_constrained_pendulum_is_refused_not_integrated():
    with pytest.raises(NotAnODE) as err:
        OdeForm(phc.compile_model(MODELS / "pendulum.yaml"))
    message = str(err.value)
    assert message.startswith(NOT_AN_ODE)
    assert "singular" in message and "constraints" in message


def test_bench_rows_of_scipy_beside_phc(tmp_path, monkeypatch):
    """`run_bench` with scipy's methods: rows measured against the same closed form on the
    RLC circuit; on the pendulum one failed row per method that says it is not an ODE."""
    from phc.study.bench import run_bench, scipy_solver

    root = MODELS.parent
    monkeypatch.setenv("PHC_ALLOW_PATH", str(MODELS))
    solvers = ["ida", scipy_solver("Radau"), scipy_solver("DOP853")]
    rep = run_bench(root / "benchmarks/corpus/rlc_circuit.yaml", solvers=solvers, tolerances=[1e-4, 1e-6],
                    out_dir=tmp_path / "rlc", progress=False, plot=False, reference_cache=False)
    scipy_rows = [r for r in rep.rows if r.solver.startswith("scipy_")]
    assert len(scipy_rows) == 4 and all(r.success for r in scipy_rows)
    for r in scipy_rows:
        # rtol 1e-4 … 1e-6, atol rtol/100: a global error within 100× the tolerance of the
        # range (error control is local; over ~3 decay times it accumulates, it does not explode)
        assert r.error_relative < 100 * r.rtol, (r.solver, r.rtol, r.error_relative)
    assert "scipy_Radau" in (tmp_path / "rlc" / "bench.md").read_text()
    rep = run_bench(root / "benchmarks/corpus/pendulum.yaml", solvers=solvers, tolerances=[1e-3, 1e-4],
                    out_dir=tmp_path / "pendulum", progress=False, plot=False, reference_cache=False)
    scipy_rows = [r for r in rep.rows if r.solver.startswith("scipy_")]
    assert [r.solver for r in scipy_rows] == ["scipy_Radau", "scipy_DOP853"]
    assert all(not r.success and r.message.startswith(NOT_AN_ODE) for r in scipy_rows)


def test_scipy_methods_are_bench_solvers_in_the_cli_and_in_a_scene(tmp_path, monkeypatch, capsys):
    """`phc bench --solver scipy_BDF` and a scene's `bench.solvers: [scipy_Radau]` sweep them;
    a misspelt one is refused by the schema with its location."""
    import shutil

    from phc.cli import main
    from phc.names import PEER_SOLVER_NAMES
    from phc.study.ode_form import SCIPY_METHODS

    assert PEER_SOLVER_NAMES == tuple(f"scipy_{m}" for m in SCIPY_METHODS)
    root = MODELS.parent
    monkeypatch.setenv("PHC_ALLOW_PATH", str(MODELS))
    scene = root / "benchmarks/corpus/rlc_circuit.yaml"
    args = ["bench", str(scene), "--tol", "1e-4", "--no-plot", "--quiet", "--no-cache"]
    assert main([*args, "--solver", "scipy_BDF", "--out-dir", str(tmp_path / "cli")]) == 0
    assert "scipy_BDF" in (tmp_path / "cli" / "bench.md").read_text()
    capsys.readouterr()
    text = scene.read_text(encoding="utf-8").replace("model: ../../models/", f"model: {MODELS.as_posix()}/")
    for solvers, code in (("[scipy_Radau]", 0), ("[scipy_radau]", 1)):
        written = tmp_path / "scene.yaml"
        written.write_text(text.replace("bench:\n", f"bench:\n  solvers: {solvers}\n"), encoding="utf-8")
        assert main(["bench", str(written), "--tol", "1e-4", "--no-plot", "--quiet", "--no-cache",
                     "--out-dir", str(tmp_path / "scene")]) == code
        out = capsys.readouterr()
        if code == 0:
            assert "scipy_Radau" in (tmp_path / "scene" / "bench.md").read_text()
        else:
            assert "scene.yaml:" in out.err and "scipy_radau" in out.err, out.err
    shutil.rmtree(tmp_path / "scene", ignore_errors=True)
