"""The C back end's step loops (:mod:`phc.codegen.c_steps`, ``phc/codegen/c_runtime/steps.c``:
the implicit midpoint rule, the discrete gradient, midpoint4) against the Python loop.

The same model on the C backend is run twice, once with the step loop in C and once with
``PHC_COMPILED_LOOP=0`` (the Python loop calling the same compiled C functions through
ctypes). Each step solves the same equations to the Newton tolerance (1e-14 relative): the
loops differ only in the linear algebra (a dense LU against SuperLU, both of the same
equilibrated matrix), which changes the corrections by round-off, so the trajectories agree to
the tolerance accumulated over the steps. The discrete energy balance of the midpoint rule
holds to round-off on a lossless model with a quadratic Hamiltonian; two threads integrating
at once get what each gets alone, bit for bit (the library keeps no state); and every step the
C loop does not take itself — a model that cannot be evaluated, ``max_steps``, Ctrl-C, a
method or a model it does not serve — ends as the Python loop ends it.

Without a C compiler these tests are skipped (there is no C loop to test).
"""

from __future__ import annotations

import math
import re
import threading
import warnings
import weakref
from pathlib import Path

import numpy as np
import pytest

import phc
from compiled_loading import assert_same_trajectory as _assert_same_trajectory
from compiled_loading import both_loops as _both
from test_ida import STATE_MODEL  # a state that leaves asin's domain (one copy, in test_ida)
from phc.codegen.c_backend import available
from phc.errors import CompiledLoopWarning

OK, WHY = available()
pytestmark = pytest.mark.skipif(not OK, reason=f"the C step loop needs a C compiler: {WHY}")

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def compiled():
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = phc.compile_model(MODELS / name, certify=False, backend="c")
            assert cache[name].backend == "c"
        return cache[name]

    return get


@pytest.fixture
def loops(monkeypatch):
    """Which loop ran each piece of each run: "c", or None for the Python loop."""
    from phc.simulation import compiled_steps

    seen = []
    original = compiled_steps.integrate

    def spy(*args, **kwargs):
        out = original(*args, **kwargs)
        seen.append(None if out is None else out["step_loop"])
        return out

    monkeypatch.setattr(compiled_steps, "integrate", spy)
    return seen


@pytest.mark.parametrize("name, t_end, step", [
    ("pendulum.yaml", 2.0, 1e-2),
    ("rlc_circuit.yaml", 2.0, 1e-2),
    ("rigid_slider_crank.yaml", 0.1, 1e-3),
    ("flexible_slider_crank.yaml", 0.005, None),
])
def test_the_c_loop_follows_the_python_loop(compiled, monkeypatch, loops, name, t_end, step):
    model = compiled(name)
    fast, slow = _both(monkeypatch, model, solver="midpoint", t_end=t_end, step=step, n_out=51)
    half = len(loops) // 2  # one call per piece between input breakpoints
    assert loops == ["c"] * half + [None] * half and half >= 1
    _assert_same_trajectory(fast, slow, step or model.dae.options["step"])
    assert fast.constraint_drift <= max(10 * slow.constraint_drift, 1e-13)
    # the same Newton test and refresh rules: the same work, up to the iterations decided at the noise
    # level; a refresh decided there changes the later ones (the flexible slider–crank takes 26 to 30
    # factorizations in 500 steps in either loop as round-off in its start state changes)
    assert fast.n_residual_evals == pytest.approx(slow.n_residual_evals, rel=0.02, abs=5)
    assert fast.n_jacobian_evals == pytest.approx(slow.n_jacobian_evals, rel=0.2, abs=3)


@pytest.fixture(scope="module")
def reference():
    """The NumPy back end's module of a shipped model (the Python loop's reference)."""
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = phc.compile_model(MODELS / name, certify=False, backend="numpy")
            assert cache[name].backend == "numpy"
        return cache[name]

    return get


@pytest.mark.parametrize("solver", ["midpoint4", "discrete_gradient"])
@pytest.mark.parametrize("name, t_end, step", [
    ("pendulum.yaml", 2.0, 1e-2),
    ("rlc_circuit.yaml", 2.0, 1e-2),
    ("mass_spring_damper.yaml", 2.0, 1e-2),
    ("flexible_slider_crank.yaml", 0.01, 1e-4),
])
def test_the_c_loop_of_midpoint4_and_the_discrete_gradient_follows_the_numpy_python_loop(
        compiled, reference, loops, solver, name, t_end, step):
    """midpoint4 (three midpoint stages a step, two Newton matrices, its own predictor and
    passivity guard) and the discrete gradient (the secant iteration on the mean-value point
    around the stage solve) in C against the same methods in the Python loop on the NumPy back
    end (SuperLU, NumPy's model functions): every stage is solved to the Newton tolerance
    (1e-14 relative) and the secant iteration to the balance tolerance (2e-15 of the energy
    scale), so the loops differ only by the round-off of the linear algebra and of the model
    functions (C's libm against NumPy's), which each step's Newton test removes down to that
    tolerance; over at most 200 steps, with margin for the growth of a perturbation along the
    motion, the differential variables agree to 1e-9 of their size and the multipliers
    (differences of them over h) to 1e-9/h (tests/compiled_loading.py)."""
    fast = phc.simulate(compiled(name), solver=solver, t_end=t_end, step=step, n_out=51)
    slow = phc.simulate(reference(name), solver=solver, t_end=t_end, step=step, n_out=51)
    half = len(loops) // 2  # one call per piece between input breakpoints; None: the NumPy back end's loop
    assert loops == ["c"] * half + [None] * half and half >= 1
    _assert_same_trajectory(fast, slow, step)
    assert fast.steps == slow.steps and fast.steps >= 100
    assert fast.constraint_drift <= max(10 * slow.constraint_drift, 1e-13)
    # both loops keep the method's energy balance (exact for these quadratic Hamiltonians) to round-off
    assert fast.energy_balance_relative <= max(10 * slow.energy_balance_relative, 1e-13)


def test_discrete_gradient_energy_balance_is_exact_for_non_quadratic_h(compiled, loops):
    """Two masses and a cubic spring: H = k1 x²/2 + k s²/2 + k3 s⁴/4 + kinetic is not quadratic.
    At a coarse step the midpoint rule misses the discrete energy balance; the discrete
    gradient's C loop (the secant iteration on the mean-value point) keeps it to round-off."""
    model = compiled("two_mass_cubic_spring.yaml")
    options = dict(t_end=5.0, step=0.05, n_out=101, initial={"coupling.s": 0.8})
    dg = phc.simulate(model, solver="discrete_gradient", **options)
    mp = phc.simulate(model, solver="midpoint", **options)
    assert loops == ["c", "c"] and dg.success and mp.success
    assert dg.energy_balance_relative <= 1e-12
    assert mp.energy_balance_relative >= 1e-6  # the test can fail: H is not quadratic


def test_midpoint_energy_balance_is_exact_for_quadratic_h(compiled, loops):
    """The Cartesian pendulum (lossless; H = |p|²/2m + m g y is quadratic, the pin constraint
    quadratic in the positions): the discrete balance H(y₁) − H(y₀) = ∇H(midpoint)·(y₁ − y₀)
    holds exactly, so at a coarse step the balance is kept to the Newton tolerance, and the
    position constraint imposed at the step ends does not drift."""
    r = phc.simulate(compiled("pendulum.yaml"), solver="midpoint", t_end=5.0, step=0.05, n_out=101)
    assert loops == ["c"] and r.success
    assert r.energy_balance_relative <= 1e-12
    assert r.constraint_drift <= 1e-12


def test_two_threads_integrate_at_once(compiled, loops):
    """The library keeps no state and ctypes releases the GIL during a chunk: two threads,
    each with its own parameters, integrate the same model at once and get bit for bit what
    each got alone."""
    model = compiled("rigid_slider_crank.yaml")
    options = [dict(solver="midpoint", t_end=0.2, step=2e-4, n_out=21, params=params)
               for params in ({}, {"omega": 100.0})]
    alone = [phc.simulate(model, **o) for o in options]
    together = [None, None]
    barrier = threading.Barrier(2)
    failures = []

    def run(k):
        try:
            barrier.wait()
            together[k] = phc.simulate(model, **options[k])
        except BaseException as err:  # noqa: BLE001 — reported by the main thread
            failures.append(err)

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not failures and not any(t.is_alive() for t in threads)
    assert loops == ["c"] * 4
    assert not np.array_equal(alone[0].y, alone[1].y)  # different runs (else the test tests little)
    for a, b in zip(alone, together):
        assert a.success and b.success
        assert np.array_equal(a.t, b.t) and np.array_equal(a.y, b.y) and a.steps == b.steps


# q' = 1: q(t) = t, and d/dq asin(q) = 1/sqrt(1 − q²) is not defined from t = 1 on


@pytest.mark.parametrize("solver", ["midpoint", "discrete_gradient", "midpoint4"])
def test_a_model_that_cannot_be_evaluated_is_handed_back(tmp_path, monkeypatch, loops, solver):
    """The C loop sees non-finite values (C returns NaN where Python raises) and hands the
    step back: the Python code retries, splits, and words the message naming the row."""
    path = tmp_path / "state_model.yaml"
    path.write_text(STATE_MODEL)
    model = phc.compile_model(path, certify=False, backend="c")
    fast, slow = _both(monkeypatch, model, solver=solver, step=0.01)
    assert loops == ["c", None]
    for r in (fast, slow):
        assert not r.success and "cannot be evaluated" in r.message, r.message
        assert 0.9 <= r.t[-1] <= 1.0 and np.all(np.isfinite(r.y))
    assert fast.message == slow.message and np.array_equal(fast.t, slow.t)


def test_max_steps_keeps_the_results_so_far(compiled, monkeypatch, loops):
    fast, slow = _both(monkeypatch, compiled("flexible_slider_crank.yaml"), solver="midpoint", t_end=0.01,
                       n_out=101, max_steps=333)
    assert loops == ["c", None]
    for r in (fast, slow):
        assert not r.success and "max_steps" in r.message and r.steps == 333
    assert fast.message == slow.message
    assert np.array_equal(fast.t, slow.t) and 1 < len(fast.t) < 101


def test_ctrl_c_between_chunks_keeps_the_results_so_far(compiled, monkeypatch, loops):
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
    assert loops == ["c"]
    assert r.interrupted and not r.success and r.message.startswith("interrupted at t = ")
    assert 0 < r.t[-1] < 0.01 and r.t[-1] == pytest.approx(seen[-1])
    assert math.isclose(float(r.message.split("t = ")[1]), r.t[-1], rel_tol=1e-5)
    assert np.all(np.isfinite(r.y)) and np.all(np.diff(r.t) > 0)


def _passages(message: str) -> list[float]:
    """Times of the rank drops a fixed-step run reports having passed (phc.simulation.midpoint.
    rank_drop_notice: "passed n rank drop(s) … (t ≈ t1, t2, …)")."""
    m = re.search(r"rank drop\(s\) of the position constraints' Jacobian \(t ≈ ([^)]*)\)", message)
    return [] if m is None else [float(x) for x in m.group(1).replace("…", "").split(",") if x.strip()]


def test_singular_configuration_is_handed_to_the_python_monitor(compiled, monkeypatch, loops):
    """The folded slider–crank (rod as long as the crank) passes crank angles θ = π/2 + kπ where
    the joint constraints become dependent. Near them the C loop's condition estimate is not
    conclusive or Newton struggles, and the step goes back to Python, whose monitor decides: a
    run stops near such an angle with the monitor's message, as the Python loop's does, or
    finishes (a fixed step passes the singular set at a distance ~h, or passes it with the
    least-norm step and reports the passage, at such an angle)."""
    model = compiled("rigid_slider_crank.yaml")
    stops = 0
    for step in (1e-4, 2e-5):
        fast, slow = _both(monkeypatch, model, solver="midpoint", params={"L": 0.15}, step=step)
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
    assert loops == ["c", None] * 2
    assert stops >= 1  # the singular set is met (stopped at or passed) by some run (else the test tests nothing)


def test_what_the_c_loop_does_not_run_is_said_once(compiled, monkeypatch, loops):
    """Every fixed-step method runs in C without a word; a model too large for the dense LU
    runs the Python loop, and a CompiledLoopWarning says so once per reason; switched off by
    PHC_COMPILED_LOOP=0, nothing is said."""
    from phc.codegen import c_steps
    from phc.simulation import compiled_steps

    monkeypatch.setattr(c_steps, "_SAID", set())
    model = compiled("pendulum.yaml")
    options = dict(t_end=0.2, step=1e-2, n_out=11)
    with warnings.catch_warnings():
        warnings.simplefilter("error", CompiledLoopWarning)
        for solver in ("midpoint", "discrete_gradient", "midpoint4"):
            assert phc.simulate(model, solver=solver, **options).success
        monkeypatch.setenv("PHC_COMPILED_LOOP", "0")
        phc.simulate(model, solver="midpoint", **options)
        monkeypatch.setenv("PHC_COMPILED_LOOP", "1")
    assert loops == ["c", "c", "c", None]
    monkeypatch.setattr(compiled_steps, "MAX_UNKNOWNS", model.module.N - 1)
    with pytest.warns(CompiledLoopWarning, match="more than the") as said:
        big = phc.simulate(model, solver="midpoint4", **options)
    assert [w.filename for w in said] == [__file__]  # the caller's line, not one inside phc
    with warnings.catch_warnings():
        warnings.simplefilter("error", CompiledLoopWarning)
        phc.simulate(model, solver="midpoint", **options)  # the same reason: said once
    monkeypatch.setattr(compiled_steps, "MAX_UNKNOWNS", 400)
    small = phc.simulate(model, solver="midpoint4", **options)
    assert loops == ["c", "c", "c", None, None, None, "c"]
    _assert_same_trajectory(small, big, 1e-2)


def test_the_library_is_built_once_from_the_shipped_source(compiled):
    """The C text ships in the package, the library is built (or loaded from the signed cache)
    once per process and checked against the driver's layout of the state arrays."""
    from phc.codegen import c_steps

    assert c_steps.SOURCE.is_file() and "void phc_steps_chunk(" in c_steps.source()
    lib = c_steps.library()
    assert lib is not None and c_steps.library() is lib and c_steps.why_not() == ""
    # re-entrant: every `static` is a function at file scope, none is data
    lines = c_steps.source().splitlines()
    statics = [line for line in lines if line.strip().startswith("static ") and (line[0].isspace() or "(" not in line)]
    assert statics == []
    assert sum(line.startswith("static ") for line in lines) >= 10
    # one Newton iteration in C, translated from step_logic, which every method's stages call;
    # the ABI the binding expects
    text = "\n".join(lines)
    assert text.count("static int64_t newton(") == 1 and "return newton(n, w, m, w->c, " in text  # op_stage
    assert text.count("op_stage(n, ws, ") >= 3  # the discrete gradient's stages and midpoint4's
    assert f"#define PHC_STEPS_ABI {c_steps.ABI}\n" in text


def test_the_translated_step_logic_is_not_written_in_steps_c_again():
    """step_logic's functions the C loop runs are translated, not ported: the hand-written steps.c
    defines none of them, the whole text defines each once, from the translation."""
    import re

    from phc.codegen import c_steps

    hand = c_steps.SOURCE.read_text(encoding="utf-8")
    whole = c_steps.source()
    assert hand.count(c_steps.MARKER) == 1 and c_steps.MARKER not in whole
    for name in c_steps.TRANSLATED:
        definition = re.compile(rf"^static [a-z0-9_]+ {name}\(", re.M)
        assert not definition.search(hand), name
        assert len(definition.findall(whole)) == 1, name
        assert f"step_logic.{name} (translated by phc.codegen.c_translate)" in whole
    # the chunk loop too: the library's entry is step_logic.chunk on the struct, written by c_steps
    # from chunk's parameters; steps.c has no loop over steps of its own
    assert "chunk" in c_steps.TRANSLATED
    entry = re.compile(r"^void phc_steps_chunk\(", re.M)
    assert not entry.search(hand) and len(entry.findall(whole)) == 1
    body = whole[whole.index("void phc_steps_chunk("):]
    body = body[:body.index("\n}\n")]
    assert body.count(";") == 1 and "    chunk(w->n, w, w->t_out, " in body
    assert "for (;;)" not in hand and "ist[I_STATUS]" not in hand  # no hand-written loop sets a chunk's status


def test_the_avx2_and_the_baseline_code_give_the_same_trajectory(compiled, monkeypatch, loops):
    """steps.c runs its solves, its LU and its stage point in an AVX2 copy where the CPU has
    AVX2, else in the baseline (SSE2) code: the same IEEE operations in the same order, no
    fused multiply-adds, so the two libraries give the same trajectory bit for bit (on a CPU
    without AVX2 both run the baseline code and the test only checks the build)."""
    from phc.codegen import c_steps

    model = compiled("flexible_slider_crank.yaml")
    options = dict(solver="midpoint", t_end=float(model.dae.options["t_start"]) + 2e-3, step=1e-5, n_out=11)
    default = phc.simulate(model, **options)
    monkeypatch.setattr(c_steps, "FLAGS", c_steps.FLAGS + ("-DPHC_NO_AVX2_DISPATCH",))
    monkeypatch.setattr(c_steps, "_LIBRARY", None)  # built again, without the AVX2 copies
    baseline = phc.simulate(model, **options)
    assert c_steps.library() is not None
    assert loops == ["c", "c"]
    assert default.success and baseline.success and default.steps == baseline.steps == 200
    assert np.array_equal(default.y, baseline.y) and np.array_equal(default.yp, baseline.yp)


@pytest.mark.parametrize("name", ["pendulum.yaml", "rigid_slider_crank.yaml", "dc_motor_pi.yaml"])
def test_the_nominal_scales_probe_takes_its_steps_in_c_as_the_python_stage_solver_does(compiled, monkeypatch, name):
    """The nominal-scales probe (phc.simulation.scaling._probe) takes its implicit-midpoint steps
    in the C loop (c_steps.midpoint_steps): the same stage solved by the same Newton iteration as
    the Python StageSolver's, each from another guess, so the largest |y| it sees, the energy
    scale and the power throughput agree with the Python probe's to the Newton tolerance
    (NEWTON_TOL = 1e-14 relative to 1 + max |y|; 1e-10 leaves room for the conditioning)."""
    from phc.codegen import c_steps
    from phc.simulation import scaling

    seen, taken = [], []
    probe, steps = scaling._probe, c_steps.midpoint_steps

    def spy(*args):
        seen.append(args)
        return probe(*args)

    def counting(*args):
        k, ys = steps(*args)
        taken.append(k)
        return k, ys

    monkeypatch.setattr(scaling, "_CACHE", weakref.WeakKeyDictionary())  # no scales kept from another test
    monkeypatch.setattr(scaling, "_probe", spy)
    monkeypatch.setattr(c_steps, "midpoint_steps", counting)
    phc.simulate(compiled(name), solver="ida", t_end=0.5)
    (args,) = seen
    in_c = probe(*args)
    assert taken[-1] == scaling.PROBE_STEPS + 1  # every step in C
    monkeypatch.setenv("PHC_COMPILED_LOOP", "0")  # the probe's steps in Python
    taken.clear()
    in_python = probe(*args)
    assert taken == [1]
    big_c, big_py = in_c[0], in_python[0]
    scale = 1.0 + np.abs(big_py).max()
    assert np.abs(big_c - big_py).max() <= 1e-10 * scale
    assert in_c[1] == pytest.approx(in_python[1], rel=1e-10, abs=1e-10 * scale)
    assert in_c[2] == pytest.approx(in_python[2], rel=1e-10, abs=1e-10 * scale)
    assert np.abs(big_py - np.abs(args[3])).max() > 1e-6 * scale  # the probe saw the states move


def test_the_probes_midpoint_steps_do_not_read_the_other_methods_constants(compiled, monkeypatch):
    """The probe's midpoint steps are handed step_constants("midpoint"), without the secant iteration's and
    the composition's numbers (so a first run need not import discrete_gradient and midpoint4): its steps
    are those of the whole vector to the bit, and so with those entries garbage."""
    from phc.codegen import c_steps
    from phc.simulation import compiled_steps
    from phc.simulation import step_logic as sl

    raw = compiled("rigid_slider_crank.yaml").module
    raw = getattr(raw, "module", raw)
    p = phc.simulation.parameter_vector(raw)
    r = phc.simulate(compiled("rigid_slider_crank.yaml"), solver="ida", t_end=1e-3, n_out=2)
    y0, yp0 = r.y[0], r.yp[0]
    t = np.linspace(0.0, 1e-3, 9)
    full, part = compiled_steps.step_constants(), compiled_steps.step_constants("midpoint")
    others = [sl._BAL_TOL, sl._MAX_SECANT, sl._S_MIN, sl._S_MAX, sl._G1, sl._G2, sl._M0, sl._M1, sl._M2]
    kept = np.setdiff1d(np.arange(len(full)), others)
    assert np.array_equal(part[kept], full[kept]) and not part[others].any()
    with pytest.raises(ValueError):
        compiled_steps.step_constants("midpoint4")
    runs = []
    for constants in (full, part, np.where(np.isin(np.arange(len(full)), others), 1e300, full)):
        monkeypatch.setattr(compiled_steps, "step_constants", lambda method=None, c=constants: c.copy())
        runs.append(c_steps.midpoint_steps(raw, p, t, y0, yp0))
    assert runs[0][0] == len(t)  # every step taken
    for k, ys in runs[1:]:
        assert k == runs[0][0] and np.array_equal(ys, runs[0][1])

@pytest.mark.parametrize("name", ["rigid_slider_crank.yaml", "dc_motor_pi.yaml"])
def test_the_functions_along_a_run_are_one_c_call_with_the_values_of_one_call_per_point(compiled, monkeypatch, name):
    """A run's H, energy scale, powers, invariants and outputs at its output points are one call
    of the step library (c_steps.along): the model's own C functions, so the values equal those of
    one call per point and function to the bit."""
    import phc.simulation as simulation
    from phc.codegen import c_steps

    seen, batched = [], []
    evaluate, along = simulation._evaluate_along, c_steps.along
    monkeypatch.setattr(simulation, "_evaluate_along", lambda *a: seen.append(a) or evaluate(*a))
    monkeypatch.setattr(c_steps, "along", lambda *a: batched.append(1) or along(*a))
    result = phc.simulate(compiled(name), solver="ida", t_end=0.5, n_out=21)
    assert batched and result.success
    mod, p, out = seen[0]
    rows = c_steps.along(getattr(mod, "module", mod), p, out.t, out.y, out.yp)
    raw = getattr(mod, "module", mod)
    single = {"H": [raw.hamiltonian(*a, p) for a in zip(out.t, out.y)],
              "scale": [raw.energy_scale(*a, p) for a in zip(out.t, out.y)],
              "powers": [raw.powers(*a, p) for a in zip(out.t, out.y, out.yp)],
              "inv": [raw.invariants(*a, p) for a in zip(out.t, out.y)],
              "vinv": [raw.velocity_invariants(*a, p) for a in zip(out.t, out.y)],
              "outs": [raw.outputs(*a, p) for a in zip(out.t, out.y, out.yp)]}
    for key, values in single.items():
        assert np.array_equal(rows[key], np.array(values, dtype=float).reshape(rows[key].shape)), key
    assert rows["outs"].shape == (21, len(raw.OUTPUTS))
    np.testing.assert_array_equal(result.H, rows["H"])


def test_the_energy_sizes_of_a_c_module_are_one_c_call_with_the_values_of_single_calls(compiled, monkeypatch):
    """The nominal scales' energy sizes (phc.simulation.energy_sizes) evaluate the C module's H at
    the perturbed states in two calls of the step library (the first round, then every later round;
    its NumPy reference's H does not take a matrix of states on the slider–crank: sin); the sizes
    equal those of single calls to the bit."""
    from phc.codegen import c_steps
    from phc.simulation import scaling

    seen, batched = [], []
    sizes, along = scaling.energy_sizes, c_steps.along
    monkeypatch.setattr(scaling, "_CACHE", weakref.WeakKeyDictionary())  # no scales kept from another test
    monkeypatch.setattr(scaling, "energy_sizes", lambda *a: seen.append(a) or sizes(*a))
    monkeypatch.setattr(c_steps, "along", lambda *a, **k: batched.append(k) or along(*a, **k))
    phc.simulate(compiled("rigid_slider_crank.yaml"), solver="ida", t_end=0.5)
    assert seen and {"only_h": True} in batched
    batched.clear()
    in_c = sizes(*seen[0])
    # the first round's ±steps, then the later rounds of the variables H is not yet curved in (one
    # H is linear in, the crank's angle or the slider's position, takes every round): two calls
    assert batched == [{"only_h": True}] * 2
    monkeypatch.setattr(c_steps, "along", lambda *a, **k: None)  # single calls of the C H
    single = sizes(*seen[0])
    assert np.array_equal(in_c, single) and (single > 0).sum() >= 4  # the momenta and the height are curved


def test_a_c_mesh_takes_its_energy_sizes_from_the_lazy_numpy_columns_above_the_c_limit(compiled, monkeypatch):
    """Each state the energy sizes perturb costs a whole evaluation of the C H, quadratic in a
    mesh's size (a 10⁵-element beam: minutes before the first step). Above
    ``energy_sizes.C_COLUMNS_ENTRIES`` states × unknowns the C module's sizes come from its NumPy
    reference's lazy columns, without a call of the C H at a matrix of states, and agree with the
    C columns' to rounding (the lazy sums run in another order)."""
    from phc.codegen import c_steps
    from phc.simulation import energy_sizes as es
    from phc.simulation import scaling

    seen = []
    sizes = scaling.energy_sizes
    monkeypatch.setattr(scaling, "_CACHE", weakref.WeakKeyDictionary())
    monkeypatch.setattr(scaling, "energy_sizes", lambda *a: seen.append(a) or sizes(*a))
    string = compiled("vibrating_string.yaml")
    phc.simulate(string, solver="midpoint", t_end=1e-3)
    assert seen
    in_c = sizes(*seen[0])
    along, calls = c_steps.along, []
    monkeypatch.setattr(c_steps, "along", lambda *a, **k: calls.append(k) or along(*a, **k))
    monkeypatch.setattr(es, "C_COLUMNS_ENTRIES", 0)
    lazy = sizes(*seen[0])
    assert not calls
    assert (in_c > 0).sum() >= 16
    # the sizes are sqrt(2E/k) from second differences of H: the string's 16 elements' states each
    # hold a share of H of order 1e-2, so sums of H in another order, a few ε of H apart, move a
    # second difference by ~1e-13 of itself; 1e-9 leaves that four decades
    np.testing.assert_allclose(lazy, in_c, rtol=1e-9, atol=0)


def test_the_probe_takes_the_values_at_the_c_steps_from_one_call_and_finds_what_single_calls_find(
        compiled, monkeypatch):
    """The nominal scales' probe (phc.simulation.scaling._probe) reads the power throughput at the
    midpoints and the energy scale at the ends of the steps the C loop took from one call of the step
    library (c_steps.probe_values): the values to the bit of the guarded single calls, which it makes
    only at the start. Without the library at hand (single calls at every step) the probe finds the
    same largest states, energy and power."""
    from phc.codegen import c_steps
    from phc.simulation import scaling
    from phc.simulation.guard import GuardedModule

    starts, probe = [], scaling._probe
    monkeypatch.setattr(scaling, "_CACHE", weakref.WeakKeyDictionary())  # no scales kept from another test
    monkeypatch.setattr(scaling, "_probe", lambda *a: starts.append(a) or probe(*a))
    phc.simulate(compiled("rigid_slider_crank.yaml"), solver="ida", t_end=0.5)
    guarded, p, _, y0, yp0 = starts[0][:5]  # the run's consistent start
    raw = guarded.module
    mod = GuardedModule(raw)
    tau = 0.05  # the crank turns in the probe's steps: the energy and the states move

    h = tau / scaling.PROBE_STEPS
    k, ys = c_steps.midpoint_steps(raw, p, h * np.arange(scaling.PROBE_STEPS + 1), y0, yp0)
    assert k == scaling.PROBE_STEPS + 1  # every step in C
    power, scale = c_steps.probe_values(raw, p, 0.0, h, y0, ys[1:k])
    t, y = 0.0, y0
    for i, y1 in enumerate(ys[1:k]):  # the probe's own single calls, as it makes them
        assert power[i] == float(np.abs(raw.powers(t + 0.5 * h, 0.5 * (y + y1), (y1 - y) / h, p)).sum())
        y, t = y1, t + h
        assert scale[i] == raw.energy_scale(t, y, p)

    calls = []
    for name in ("energy_scale", "powers"):
        wrapped = getattr(mod, name)
        setattr(mod, name, lambda *a, _w=wrapped, _n=name: calls.append(_n) or _w(*a))
    found = probe(mod, p, 0.0, y0, yp0, tau, None)
    assert sorted(calls) == ["energy_scale", "powers"]  # at the start only
    monkeypatch.setattr(c_steps, "along", lambda *a, **k: None)
    alone = probe(mod, p, 0.0, y0, yp0, tau, None)
    assert len(calls) == 2 + (2 + 2 * scaling.PROBE_STEPS)  # the second probe: the start and every step
    assert np.array_equal(found[0], alone[0]) and found[1:] == alone[1:] and found[1] > 0


def test_the_output_sensitivities_of_a_c_module_are_one_c_call_with_the_values_of_single_calls(
        compiled, monkeypatch):
    """The derivatives of the requested outputs by the states (phc.simulation.scaling.
    output_sensitivities, what IDA's promise scales are made of) evaluate the outputs of a C module
    at every perturbed state in one call of the step library: the same matrix to the bit as one
    guarded call per state (the library not at hand), and the central difference of the outputs
    written out here for each state."""
    from phc.codegen import c_steps
    from phc.simulation import scaling
    from phc.simulation.guard import GuardedModule

    raw = compiled("two_mass_cubic_spring.yaml").module
    mod = GuardedModule(raw)
    p = phc.simulation.parameter_vector(raw)
    rng = np.random.default_rng(5)
    y0, yp0 = rng.normal(size=raw.N), rng.normal(size=raw.N)
    s = 0.5 + rng.random(raw.N)
    calls, along = [], c_steps.along
    monkeypatch.setattr(c_steps, "along", lambda *a, **k: calls.append(k) or along(*a, **k))
    in_c = scaling.output_sensitivities(mod, p, 0.0, y0, yp0, s)
    assert calls == [{}]  # one call, every function at every perturbed state
    states = np.flatnonzero(raw.DIFFERENTIAL)
    for j in states:  # the central difference, state by state
        up, down = y0.copy(), y0.copy()
        up[j] += 1e-6 * s[j]
        down[j] -= 1e-6 * s[j]
        expected = (raw.outputs(0.0, up, yp0, p) - raw.outputs(0.0, down, yp0, p)) / (2.0 * 1e-6 * s[j])
        assert np.array_equal(in_c[:, j], expected)
    monkeypatch.setattr(c_steps, "along", lambda *a, **k: None)
    single = scaling.output_sensitivities(mod, p, 0.0, y0, yp0, s)
    assert np.array_equal(in_c, single) and np.count_nonzero(in_c[:, states]) >= len(states)
