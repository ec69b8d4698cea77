"""The compiled fixed-step loop (:mod:`phc.simulation.compiled_steps`) against the Python loop.

The same model on the numba backend is run twice, once with the whole step loop compiled and
once with ``PHC_COMPILED_LOOP=0`` (the Python loop calling the same compiled functions):
the trajectories agree to the Newton tolerance (the LU differs: dense LAPACK against
SuperLU), the discrete energy balance holds to round-off, and failures, ``max_steps`` and
Ctrl-C keep the results so far with the Python loop's messages."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import phc
from compiled_loading import assert_same_trajectory as _assert_same_trajectory
from compiled_loading import both_loops as _both
from phc.codegen.numba_backend import available

OK, WHY = available()
pytestmark = pytest.mark.skipif(not OK, reason=f"the compiled loop needs numba: {WHY}")

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def compiled():
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = phc.compile_model(MODELS / name, certify=False, backend="numba")
            assert cache[name].backend == "numba"
        return cache[name]

    return get


@pytest.fixture
def used(monkeypatch):
    """Records whether each run went through the compiled loop."""
    from phc.simulation import compiled_steps

    calls = []
    original = compiled_steps.integrate

    def spy(*args, **kwargs):
        out = original(*args, **kwargs)
        calls.append(out is not None)
        return out

    monkeypatch.setattr(compiled_steps, "integrate", spy)
    return calls


@pytest.mark.parametrize("name, solver, t_end, step", [
    ("flexible_slider_crank.yaml", "midpoint", 0.01, None),
    ("flexible_slider_crank.yaml", "midpoint4", 0.01, 1e-4),
    ("rigid_slider_crank.yaml", "discrete_gradient", 0.1, 1e-3),
    ("rigid_slider_crank.yaml", "midpoint4", 0.1, 5e-3),
    ("pendulum.yaml", "midpoint", 2.0, 1e-2),
    ("pendulum.yaml", "discrete_gradient", 2.0, 1e-2),
    ("vibrating_string.yaml", "midpoint", 0.01, 1e-4),
])
def test_compiled_loop_follows_the_python_loop(compiled, monkeypatch, used, name, solver, t_end, step):
    model = compiled(name)
    fast, slow = _both(monkeypatch, model, solver=solver, t_end=t_end, step=step, n_out=51)
    half = len(used) // 2  # one call per piece between input breakpoints
    assert used == [True] * half + [False] * half
    _assert_same_trajectory(fast, slow, step or model.dae.options["step"])
    assert fast.constraint_drift <= max(10 * slow.constraint_drift, 1e-13)


def test_midpoint_energy_balance_is_exact_for_quadratic_h(compiled, monkeypatch, used):
    # the Cartesian pendulum: H = |p|²/2m + m g y is quadratic; a coarse step changes nothing
    r = phc.simulate(compiled("pendulum.yaml"), solver="midpoint", t_end=5.0, step=0.05, n_out=101)
    assert used == [True] and r.success
    assert r.energy_balance_relative <= 1e-12
    assert r.constraint_drift <= 1e-12


def test_discrete_gradient_energy_balance_is_exact_for_non_quadratic_h(compiled, monkeypatch, used):
    # H = k1 x²/2 + k s²/2 + k3 s⁴/4 + kinetic: the midpoint rule misses the balance at this step,
    # the discrete gradient keeps it to round-off
    model = compiled("two_mass_cubic_spring.yaml")
    options = dict(t_end=5.0, step=0.05, n_out=101, initial={"coupling.s": 0.8})
    dg = phc.simulate(model, solver="discrete_gradient", **options)
    mp = phc.simulate(model, solver="midpoint", **options)
    assert used == [True, True] and dg.success and mp.success
    assert dg.energy_balance_relative <= 1e-12
    assert mp.energy_balance_relative >= 1e-6  # the test can fail: H is not quadratic


def test_max_steps_keeps_the_results_so_far(compiled, monkeypatch, used):
    fast, slow = _both(monkeypatch, compiled("flexible_slider_crank.yaml"), solver="midpoint", t_end=0.01,
                       n_out=101, max_steps=333)
    assert used == [True, False]
    for r in (fast, slow):
        assert not r.success and "max_steps" in r.message and r.steps == 333
    assert fast.message == slow.message
    assert np.array_equal(fast.t, slow.t) and 1 < len(fast.t) < 101


STATE_MODEL = """\
format_version: 1
name: state_model
components:
  s:
    type: phs
    states: [q]
    hamiltonian: q**2/2 + asin(q)
    J: [[0]]
    R: [[0]]
    ports:
      u:
        domain: electrical
        causality: effort_in
        B: [[1]]
  src: {type: effort_source, domain: electrical, value: 1}
connections:
  - [s.u, src.port]
simulation:
  t_end: 2.0
  n_out: 201
  initial:
    s.q: 0.0
"""
# q' = 1: q(t) = t, and d/dq asin(q) = 1/sqrt(1 − q²) is not defined from t = 1 on


@pytest.mark.parametrize("solver", ["midpoint", "discrete_gradient", "midpoint4"])
def test_model_evaluation_failure_keeps_the_results_so_far(tmp_path, monkeypatch, used, solver):
    path = tmp_path / "state_model.yaml"
    path.write_text(STATE_MODEL)
    model = phc.compile_model(path, certify=False, backend="numba")
    fast, slow = _both(monkeypatch, model, solver=solver, step=0.01)
    assert used == [True, False]
    for r in (fast, slow):
        assert not r.success and "cannot be evaluated" in r.message, r.message
        assert 0.9 <= r.t[-1] <= 1.0 and np.all(np.isfinite(r.y))
    assert fast.message == slow.message and np.array_equal(fast.t, slow.t)


def test_ctrl_c_between_chunks_keeps_the_results_so_far(compiled, monkeypatch, used):
    from phc.simulation import compiled_steps
    from phc.simulation.result import SimulationInterrupted

    monkeypatch.setattr(compiled_steps, "CHUNK_SECONDS", 1e-4)  # many chunks, many progress reports
    seen = []

    def progress(t):
        seen.append(t)
        if len(seen) == 3:
            raise KeyboardInterrupt

    with pytest.raises(SimulationInterrupted) as info:
        phc.simulate(compiled("flexible_slider_crank.yaml"), solver="midpoint", t_end=0.01, n_out=101,
                     progress=progress)
    r = info.value.result
    assert used == [True]
    assert r.interrupted and not r.success and r.message.startswith("interrupted at t = ")
    assert 0 < r.t[-1] < 0.01 and r.t[-1] == pytest.approx(seen[-1])
    assert math.isclose(float(r.message.split("t = ")[1]), r.t[-1], rel_tol=1e-5)
    assert np.all(np.isfinite(r.y)) and np.all(np.diff(r.t) > 0)


def test_large_systems_and_the_numpy_backend_keep_the_python_loop(compiled, monkeypatch):
    from phc.simulation import compiled_steps

    model = compiled("pendulum.yaml")
    assert compiled_steps.enabled(model.module)
    monkeypatch.setattr(compiled_steps, "MAX_UNKNOWNS", model.module.N - 1)
    assert not compiled_steps.enabled(model.module)
    numpy_model = phc.compile_model(MODELS / "pendulum.yaml", certify=False, backend="numpy")
    monkeypatch.setattr(compiled_steps, "MAX_UNKNOWNS", 400)
    assert not compiled_steps.enabled(numpy_model.module)


def test_newton_weights_give_the_same_steps(compiled):
    """A weight vector 1/(1 + max|y|) in every entry reproduces the default stopping rule's scale
    (|y| changes little over the run): the same trajectory to the tolerance."""
    from phc.simulation import compiled_steps, parameter_vector, start_state, initial_values

    model = compiled("rigid_slider_crank.yaml")
    mod = model.module
    p = parameter_vector(mod)
    values, fixed = initial_values(model, p)
    init = start_state(model, p, 0.0, values, fixed)
    t_out = np.linspace(0.0, 0.1, 11)
    common = dict(max_steps=10_000, progress=None, step=1e-3, name="implicit midpoint",
                  python_advance=None)
    plain = compiled_steps.integrate("midpoint", mod, p, t_out, init.y0, init.yp0, **common)
    w = np.full(mod.N, 1.0 / (1.0 + np.abs(plain["y"]).max()))
    weighted = compiled_steps.integrate("midpoint", mod, p, t_out, init.y0, init.yp0, weights=w, **common)
    assert plain["success"] and weighted["success"]
    assert np.abs(plain["y"] - weighted["y"]).max() <= 1e-9 * (1.0 + np.abs(plain["y"]).max())
    with pytest.raises(ValueError, match="weights"):
        compiled_steps.integrate("midpoint", mod, p, t_out, init.y0, init.yp0, weights=np.ones(3), **common)


def _passages(message: str) -> list[float]:
    """Times of the rank drops a fixed-step run reports having passed (phc.simulation.midpoint.
    rank_drop_notice: "passed n rank drop(s) … (t ≈ t1, t2, …)")."""
    m = re.search(r"rank drop\(s\) of the position constraints' Jacobian \(t ≈ ([^)]*)\)", message)
    return [] if m is None else [float(x) for x in m.group(1).replace("…", "").split(",") if x.strip()]


@pytest.mark.parametrize("solver", ["midpoint", "discrete_gradient"])
def test_singular_configuration_stops_near_a_singular_angle_only(compiled, monkeypatch, used, solver):
    """The folded slider–crank (rod as long as the crank) passes crank angles θ = π/2 + kπ where
    the joint constraints become dependent. A fixed step only passes the singular set at a
    distance ~h, and whether a hard step or a look falls close enough is a matter of the
    iteration's path (dense LU or SuperLU): either loop may step over one. Where a loop stops,
    it is near such an angle with the monitor's message, and the results before are kept; where
    it passes one with the least-norm step (one step and two half steps agreeing), the passages
    it reports are at such angles."""
    model = compiled("rigid_slider_crank.yaml")
    stops = 0
    for step in (1e-4, 2e-5):
        fast, slow = _both(monkeypatch, model, solver=solver, params={"L": 0.15}, step=step)
        for r in (fast, slow):
            if r.success:
                # passed: each rank drop it reports (the Python monitor's notice) is at such an angle
                for t_pass in _passages(r.message):
                    angle = 150.0 * t_pass - math.pi / 2
                    assert abs(angle - math.pi * round(angle / math.pi)) < 0.1, (step, t_pass)
                    stops += 1
                continue
            stops += 1
            assert "singular configuration" in r.message and "become dependent" in r.message, r.message
            t_stop = float(r.message.split("stopped at t = ")[1].split()[0])
            angle = 150.0 * t_stop - math.pi / 2
            assert abs(angle - math.pi * round(angle / math.pi)) < 0.1, (step, t_stop)
            assert r.t[-1] <= t_stop and len(r.t) > 1 and np.all(np.isfinite(r.y))
            assert r.constraint_drift < 1e-9
    assert used == [True, False] * 2
    assert stops >= 1  # the singular set is met (stopped at or passed) by some run (else the test tests nothing)


def test_the_predictor_changes_the_start_not_the_solution(compiled, monkeypatch, used):
    """The quadratic extrapolation of the midpoints (PREDICTOR_ORDER 2) against the linear one:
    Newton starts elsewhere, the steps converge to the same solution (to the Newton tolerance,
    accumulated over the steps as between the two loops), with the discrete energy balance
    and the position constraints at round-off."""
    from phc.simulation import midpoint as mp

    model = compiled("flexible_slider_crank.yaml")
    options = dict(solver="midpoint", t_end=0.01, n_out=51)
    quadratic = phc.simulate(model, **options)
    monkeypatch.setattr(mp, "PREDICTOR_ORDER", 1)
    linear = phc.simulate(model, **options)
    assert used == [True, True]
    _assert_same_trajectory(quadratic, linear, model.dae.options["step"])
    for r in (quadratic, linear):
        assert r.energy_balance_relative <= 1e-12 and r.constraint_drift <= 1e-12
    assert quadratic.n_residual_evals != linear.n_residual_evals  # the predictor did change the iterations


@pytest.mark.parametrize("loop", ["1", "0"])
def test_a_quadratic_predictor_needs_fewer_iterations_on_a_smooth_solution(compiled, monkeypatch, loop):
    """The mass–spring–damper (linear: one Newton matrix for the whole run, so the same
    factorizations) at h = 0.01: extrapolating the midpoints by a parabola instead of a line
    starts Newton closer, in both loops — a count, not a time."""
    from phc.simulation import midpoint as mp

    monkeypatch.setenv("PHC_COMPILED_LOOP", loop)
    model = compiled("mass_spring_damper.yaml")
    runs = {}
    for order in (1, 2):
        monkeypatch.setattr(mp, "PREDICTOR_ORDER", order)
        runs[order] = r = phc.simulate(model, solver="midpoint", t_end=5.0, step=0.01, n_out=11)
        assert r.success and r.energy_balance_relative <= 1e-13
    assert runs[2].n_jacobian_evals == runs[1].n_jacobian_evals
    assert runs[2].n_residual_evals <= 0.95 * runs[1].n_residual_evals  # 2.68 against 2.98 a step measured
    assert np.abs(runs[2].y - runs[1].y).max() <= 1e-12 * (1.0 + np.abs(runs[1].y).max())


def test_both_loops_run_the_same_newton_test(compiled, monkeypatch, used):
    """Weighted test with the algebraic variables relative to |y| + 1 (GGL multipliers left
    out), the same stagnation and refresh rules: the compiled loop needs the Python loop's
    number of residual evaluations and factorizations (up to the round-off that decides an
    iteration at the noise level). The compiled loop that left the algebraic variables out
    needed 6 % fewer evaluations here and lost the energy balance of the rigid slider–crank."""
    fast, slow = _both(monkeypatch, compiled("flexible_slider_crank.yaml"), solver="midpoint", t_end=0.01, n_out=51)
    assert used == [True, False]
    assert fast.n_residual_evals == pytest.approx(slow.n_residual_evals, rel=0.02)
    assert fast.n_jacobian_evals == pytest.approx(slow.n_jacobian_evals, rel=0.1, abs=3)


# ---------------------------------------------------------------------------------------------------
# mixed precision: the Newton corrections with a single-precision copy of the inverse


@pytest.fixture
def loop_runs(monkeypatch):
    """What the compiled loop returned for each run (its dict), None for a run it did not take."""
    from phc.simulation import compiled_steps

    outs = []
    original = compiled_steps.integrate

    def spy(*args, **kwargs):
        out = original(*args, **kwargs)
        outs.append(out)
        return out

    monkeypatch.setattr(compiled_steps, "integrate", spy)
    return outs


def test_single_precision_copy_keeps_an_si_scaled_inverse_in_range():
    """M = D₁ Q D₂ with D₁, D₂ spanning 10^±60 (units that differ by far more than single
    precision's range, 10^±38) and Q orthogonal; x spanning 10^±40. The product through the
    equilibrated single-precision copy matches the double one to single precision's round-off,
    entry by entry, where a plain cast to float32 loses entries to overflow and underflow."""
    from phc.simulation import compiled_steps as cs

    assert cs._build()
    rng = np.random.default_rng(7)
    n = 40
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    d1, d2 = np.logspace(-60, 60, n), rng.permutation(np.logspace(60, -60, n))
    M = d1[:, None] * q * d2[None, :]
    x = rng.permutation(np.logspace(-40, 40, n)) * rng.choice([-1.0, 1.0], n)
    with np.errstate(over="ignore"):
        plain = M.astype(np.float32)
    assert np.isinf(plain).any() and ((plain == 0) & (M != 0)).any()  # the test can fail without scaling
    lp = (np.zeros((2, n, n), np.float32), np.ones((2, 3, n)), np.array([0.0] * (2 * n) + [1.0, 0.0], np.float32))
    Am = np.ascontiguousarray(M.T)  # the kernel keeps matrices column-major
    cs._lowprec(Am, lp, 1)
    R, C = lp[1][1, 0], lp[1][1, 1]
    assert np.all(np.log2(R) == np.round(np.log2(R))) and np.all(np.log2(C) == np.round(np.log2(C)))
    assert np.abs(lp[0][1]).max() < 2.0 and np.all(np.abs(lp[0][1]).max(axis=1) >= 1.0)
    ints = np.array([n, 1, 0, 0], np.int32)
    chars = np.frombuffer(b"LNU", np.uint8).copy()
    y = x.copy()
    cs._solve32(lp, 1, ints, chars, y)
    exact = M @ x
    bound = np.abs(M) @ np.abs(x)
    assert np.all(np.isfinite(y))
    assert np.all(np.abs(y - exact) <= 4 * n * np.finfo(np.float32).eps * bound)


def test_mixed_precision_reaches_the_double_precision_solution(compiled, monkeypatch, loop_runs):
    """The flexible slider–crank (83 unknowns: mixed precision by default) with the single-
    precision copy and without: the trajectories agree to the Newton tolerance, the discrete
    energy balance and the constraints hold to round-off, and the iteration needs no more
    residual evaluations (the copy's round-off is below what the old matrix costs anyway)."""
    from phc.simulation import compiled_steps as cs

    model = compiled("flexible_slider_crank.yaml")
    assert model.module.N >= cs.MIXED_PRECISION_MIN
    options = dict(solver="midpoint", t_end=0.01, n_out=51)
    monkeypatch.setenv("PHC_MIXED_PRECISION", "1")
    mixed = phc.simulate(model, **options)
    monkeypatch.setenv("PHC_MIXED_PRECISION", "0")
    double = phc.simulate(model, **options)
    assert [out["mixed_precision"] for out in loop_runs] == [True, False]
    assert loop_runs[0]["low_precision_strikes"] < cs.LOW_PRECISION_STRIKES  # it stayed on
    _assert_same_trajectory(mixed, double, model.dae.options["step"])
    assert mixed.energy_balance_relative <= 1e-12 and mixed.constraint_drift <= 1e-12
    assert mixed.n_residual_evals <= 1.02 * double.n_residual_evals


def test_near_a_singular_configuration_the_corrections_go_back_to_double(compiled, monkeypatch, loop_runs):
    """The folded slider–crank (see the singular-configuration test) with the single-precision
    copy at every size: near the singular angles the Newton matrix's conditioning spoils the
    copy's contraction, the corrections are redone in double precision (strikes), and the run
    ends as a double-precision run may: finished, or stopped near a singular angle with the
    monitor's message."""
    monkeypatch.setenv("PHC_MIXED_PRECISION", "always")
    r = phc.simulate(compiled("rigid_slider_crank.yaml"), solver="midpoint", params={"L": 0.15}, step=1e-4)
    (out,) = loop_runs
    assert out["mixed_precision"] and out["low_precision_strikes"] >= 1
    if not r.success:
        assert "singular configuration" in r.message, r.message
        t_stop = float(r.message.split("stopped at t = ")[1].split()[0])
        angle = 150.0 * t_stop - math.pi / 2
        assert abs(angle - math.pi * round(angle / math.pi)) < 0.1, t_stop
    assert r.constraint_drift < 1e-9 and np.all(np.isfinite(r.y))


def test_the_model_functions_are_looked_up_once_per_module(compiled):
    """The compiled functions reach the kernel as numba wrapper-address objects made once per
    module: the same objects on every run, with the addresses numba itself would look up."""
    import numba
    from numba.core import types
    from numba.experimental.function_type import _get_wrapper_address

    from phc.simulation import compiled_steps as cs

    raw = compiled("pendulum.yaml").module
    first = cs._functions(raw)
    assert first is not None and cs._functions(raw) is first
    sigs = cs._build()[2]
    for obj, name in zip(first, cs._FUNCTION_NAMES):
        assert obj.signature() == sigs[name]
        assert obj.__wrapper_address__() == _get_wrapper_address(obj.func, sigs[name])
        # numba's type of the argument, made once per object, is the one its own rule makes
        assert numba.typeof(obj) is obj.numba_type and obj.numba_type == types.FunctionType(sigs[name])


def test_the_cache_stamp_covers_every_file_the_loop_is_compiled_from():
    """The compiled loop is kept in phc's cache under a stamp of its source text: the stamp covers
    the file of every function the loop is compiled from (the kernel module) and the module that
    compiles it (signatures, LAPACK/BLAS symbols), so that a change to either recompiles it."""
    from phc.simulation import compiled_steps as cs
    from phc.codegen import numba_steps_kernel as kernel

    ready = cs._build()
    assert ready
    chunk, dummy, _ = ready
    files = {Path(cs.__file__), Path(chunk.py_func.__code__.co_filename), Path(dummy.py_func.__code__.co_filename)}
    files |= {Path(f.py_func.__code__.co_filename) for f in vars(kernel).values() if hasattr(f, "py_func")}
    assert Path(kernel.__file__) in files
    source = cs._kernel_source()
    for path in files:
        assert path.read_text(encoding="utf-8") in source, path
    assert cs._lowprec is kernel._lowprec and hasattr(cs._lowprec, "py_func")  # the jitted one, by either name


@pytest.mark.parametrize("solver, entry", [("midpoint", "newton"), ("discrete_gradient", "discrete_gradient"),
                                           ("midpoint4", "midpoint4")])
def test_both_loops_run_the_step_logic_written_once(compiled, monkeypatch, used, solver, entry):
    """Each method's step logic and the driver's routine bookkeeping exist once
    (phc.simulation.step_logic): the compiled loop jits the code of those very functions, and the
    Python loop calls them — a run with the compiled loop off goes through the entry point of its
    method, the Newton iteration, the output grid, the predictor, the monitor's cadence and the
    acceptance of every step, and agrees with the compiled run to the Newton tolerance."""
    from phc.simulation import compiled_steps as cs
    from phc.codegen import numba_steps_kernel as kernel
    from phc.simulation import step_logic

    assert cs._build()
    driver = ("next_step", "predict", "looks", "accept")
    for name, func in (("_newton", step_logic.newton), ("_discrete_gradient", step_logic.discrete_gradient),
                       ("_midpoint4_step", step_logic.midpoint4), ("lagrange_weights", step_logic.lagrange_weights),
                       ("predictor_nodes", step_logic.predictor_nodes), ("substeps", step_logic.substeps),
                       ("extrapolate", step_logic.extrapolate), ("polynomial", step_logic.polynomial),
                       *((name, getattr(step_logic, name)) for name in driver)):
        jitted = getattr(kernel, name)
        assert jitted.py_func.__code__ is func.__code__ and hasattr(jitted, "py_func"), name
    for gone in ("_predict", "_accept", "_substeps", "_predictor_nodes", "_lagrange_weights"):
        assert not hasattr(kernel, gone), gone  # no second copy of the driver in the kernel
    # the chunk loop itself is step_logic's (the C loop's phc_steps_chunk is its translation): the
    # kernel's _chunk only builds the workspace and calls it, with no loop of its own
    assert kernel.chunk.py_func.__code__ is step_logic.chunk.__code__
    import inspect

    own = inspect.getsource(getattr(kernel._chunk, "py_func", kernel._chunk))
    assert "while" not in own and own.rstrip().splitlines()[-1].strip().startswith("chunk(ws, ")
    calls = {}
    for name in {entry, "newton", *driver}:
        original = getattr(step_logic, name)

        def counted(*args, _name=name, _original=original):
            calls[_name] = calls.get(_name, 0) + 1
            return _original(*args)

        monkeypatch.setattr(step_logic, name, counted)
    model = compiled("pendulum.yaml")
    fast, slow = _both(monkeypatch, model, solver=solver, t_end=0.5, step=1e-2, n_out=11)
    assert used == [True, False]
    assert calls[entry] >= 50 and calls["newton"] >= calls[entry]  # 50 steps, each at least one stage
    for name in driver:  # the Python loop's bookkeeping of each of the 50 steps
        assert calls[name] >= 50, name
    _assert_same_trajectory(fast, slow, 1e-2)


def test_a_loop_that_does_not_compile_is_said_once(monkeypatch):
    """The compiled step loop failing to build (numba present) is a warning naming why, once
    per process; the Python loop then runs (enabled() is False), never silently."""
    import types
    import warnings

    from phc.errors import CompiledLoopWarning
    from phc.simulation import compiled_steps

    def broken():
        raise RuntimeError("a typing error in the step logic (test)")

    monkeypatch.setattr(compiled_steps, "_READY", None)
    monkeypatch.setattr(compiled_steps, "_WHY", "")
    monkeypatch.setattr(compiled_steps, "_SAID", [])
    monkeypatch.setattr(compiled_steps, "_compile", broken)
    monkeypatch.setattr("phc.codegen.numba_cache.available", lambda: (True, ""))
    raw = types.SimpleNamespace(BACKEND="numba", N=3)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert not compiled_steps.enabled(raw)
        assert not compiled_steps.enabled(raw)
    said = [w for w in caught if issubclass(w.category, CompiledLoopWarning)]
    assert len(said) == 1 and "a typing error in the step logic (test)" in str(said[0].message)
