"""``auto`` on a long fixed-step run (:func:`phc.codegen.backends.for_run`).

``auto`` runs a model on C where a C compiler is found and the C back end prints the model:
every fixed-step method's loop then runs in C, whatever the run's length. Where C is not used
(here: the compiler blocked while the model compiles), a model below
:data:`~phc.codegen.backends.AUTO_MIN_UNKNOWNS` unknowns compiles to the NumPy module; a
fixed-step run of at least :data:`~phc.codegen.backends.AUTO_LOOP_STEPS` steps then runs on
numba's compiled step loop where numba can be imported, else on NumPy with the reason in the
run's note. An explicit ``numpy``, IDA, a shorter run and a model loaded from its description
stay on NumPy. The switched run takes the NumPy run's steps: both solve the same implicit
midpoint equations to the Newton tolerance, so the states agree to that tolerance accumulated
over the steps.

The suite runs with ``PHC_BACKEND=numpy`` (tests/conftest.py): these tests ask for ``auto``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc
from phc.cli import main
from phc.codegen import backends, c_backend, cc, numba_backend, numba_cache
from phc.codegen.compiled import CompiledModel
from phc.errors import SimulationSetupError
from phc.simulation.midpoint import NEWTON_TOL

PENDULUM = Path(__file__).resolve().parents[2] / "models" / "pendulum.yaml"
H = 1e-3
"""The step of every run here (the pendulum's period is about 2 s: a fine step)."""
SHORT = 200
"""The threshold the rule's own tests set (``AUTO_LOOP_STEPS`` monkeypatched): short runs."""


def _numba():
    return numba_backend.available()[0]


def _c():
    return c_backend.available()[0]


def _without_c():
    """The pendulum compiled under ``auto`` while no C compiler is found: the NumPy module
    (the size rule)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(cc, "available", lambda: (False, "no C compiler found (test)"))
        model = phc.compile_model(PENDULUM, certify=False, backend="auto")
    assert model.backend == "numpy" and model.module.N < backends.AUTO_MIN_UNKNOWNS
    assert model.backend_request == "auto"
    return model


@pytest.fixture(scope="module")
def compiled():
    return _without_c()


def _run(model, steps, solver="midpoint", **kwargs):
    """`steps` steps of `H` over one output interval."""
    return phc.simulate(model, t_end=steps * H, step=H, n_out=2, solver=solver, **kwargs)


@pytest.fixture
def short(monkeypatch):
    monkeypatch.setattr(backends, "AUTO_LOOP_STEPS", SHORT)


@pytest.fixture
def no_numba(monkeypatch):
    monkeypatch.setattr(numba_cache, "_AVAILABLE", (False, "numba is not installed (test)"))


@pytest.mark.skipif(not _numba(), reason="numba is not installed: no compiled step loop without C")
def test_a_long_midpoint_run_runs_compiled_and_takes_the_numpy_runs_steps(compiled):
    steps = backends.AUTO_LOOP_STEPS
    fast = _run(compiled, steps)
    slow = _run(compiled, steps, backend="numpy")
    assert fast.backend == "numba"
    assert f"auto: {steps} midpoint steps, at least {steps}" in fast.backend_note
    assert "\n" not in fast.backend_note
    assert slow.backend == "numpy" and slow.backend_note == ""
    assert fast.success and slow.success, (fast.message, slow.message)
    assert fast.steps == slow.steps == steps
    assert np.array_equal(fast.t, slow.t)
    # every step solves the same equations to NEWTON_TOL (relative to 1 + |y|); a dense LU
    # against SuperLU changes the iterates by round-off. Accumulated over the steps, with a
    # factor 100 for the growth of a perturbation along the swing:
    diff = fast.differential & (np.array(fast.variables) != "energy.supplied")
    err = np.abs(fast.y[-1] - slow.y[-1]) / (1.0 + np.abs(slow.y).max(axis=0))
    bound = 100 * steps * NEWTON_TOL
    assert err[diff].max() <= bound, err[diff].max()
    # the algebraic ones (multipliers at the step ends) are differences of those over h
    assert err[~diff].max(initial=0.0) <= bound / H, err[~diff].max(initial=0.0)


@pytest.mark.skipif(not _c(), reason="no C compiler")
@pytest.mark.parametrize("solver", ["midpoint", "discrete_gradient", "midpoint4"])
def test_with_c_every_fixed_step_run_runs_on_c(short, no_numba, solver):
    """A small model runs on C under `auto` (the size rule is numba's only), and so does its
    step loop, long run or short, with nothing to switch."""
    on_c = phc.compile_model(PENDULUM, certify=False, backend="auto")
    assert on_c.backend == "c"
    for steps in (SHORT, SHORT // 4):
        result = _run(on_c, steps, solver=solver)
        assert result.success, result.message
        assert (result.backend, result.backend_note) == ("c", ""), result.backend_note
        assert result.steps == steps


@pytest.mark.skipif(not (_numba() and _c()), reason="needs numba and a C compiler")
def test_a_model_the_c_back_end_refuses_runs_on_numba(short, monkeypatch):
    """Where the C back end refuses the model (an input table), `auto` compiles it to the
    NumPy module and a long run switches to numba's loop, never to C's."""
    from phc.codegen import c_printer

    monkeypatch.setattr(c_printer, "unsupported", lambda expr, known: "a construct refused by this test")
    monkeypatch.setattr(c_backend, "_LOADED", {})
    refused = phc.compile_model(PENDULUM, certify=False, backend="auto")
    assert refused.backend == "numpy"
    assert "refused by this test" in backends.describe(refused.module, "auto")
    assert backends.run_targets(refused, None, "midpoint", SHORT) == ["numba"]
    module, note = backends.for_run(refused, "auto", "midpoint", SHORT)
    assert backends.name_of(module) == "numba"
    assert f"auto: {SHORT} midpoint steps" in note


def test_without_numba_and_c_the_run_stays_numpy_and_says_why(compiled, short, no_numba, monkeypatch):
    monkeypatch.setattr(cc, "available", lambda: (False, "no C compiler found (test)"))
    result = _run(compiled, SHORT)
    assert result.success, result.message
    assert result.backend == "numpy"
    assert "numba is not installed (test)" in result.backend_note
    assert "without C" in result.backend_note


def test_explicit_numpy_never_switches(compiled, short):
    assert _run(compiled, SHORT, backend="numpy").backend == "numpy"
    requested = phc.compile_model(PENDULUM, certify=False, backend="numpy")
    assert requested.backend_request == "numpy"
    result = _run(requested, SHORT)
    assert (result.backend, result.backend_note) == ("numpy", "")


def test_ida_keeps_the_size_rule(compiled, short):
    result = phc.simulate(compiled, t_end=1.0, n_out=2 * SHORT, solver="ida")
    assert (result.backend, result.backend_note) == ("numpy", "")


def test_a_run_below_the_threshold_stays_numpy(short):
    fresh = _without_c()  # no compiled loop built yet
    result = _run(fresh, SHORT - 1)
    assert result.steps == SHORT - 1
    assert (result.backend, result.backend_note) == ("numpy", "")


@pytest.mark.skipif(not _numba(), reason="numba is not installed: no compiled step loop without C")
def test_once_built_the_loop_serves_shorter_runs(short):
    """The threshold weighs the loop's one-off cost; once the model has built it, a shorter
    run takes it too — before, a finer step over the threshold ran 10–40 times faster than a
    coarser one below it (the work check of `phc bench`, docs/benchmarks.md). Same steps,
    same states to the Newton tolerance accumulated over the steps."""
    fresh = _without_c()
    assert _run(fresh, SHORT).backend == "numba"
    result = _run(fresh, SHORT // 2)
    reference = _run(fresh, SHORT // 2, backend="numpy")
    assert result.backend != "numpy" and "built already" in result.backend_note
    assert result.steps == reference.steps == SHORT // 2
    # the bound of the long run above: NEWTON_TOL per step, ×100 for growth along the swing
    diff = result.differential & (np.array(result.variables) != "energy.supplied")
    err = np.abs(result.y[-1] - reference.y[-1]) / (1.0 + np.abs(reference.y).max(axis=0))
    assert err[diff].max() <= 100 * result.steps * NEWTON_TOL, err[diff].max()


def test_a_model_loaded_from_its_description_stays_numpy_and_says_so(compiled, short):
    loaded = CompiledModel.from_description(compiled.description, compiled.source, backend_request="auto")
    assert loaded.dae is None
    result = _run(loaded, SHORT)
    assert result.backend == "numpy"
    assert "loaded from its description" in result.backend_note


@pytest.mark.skipif(not _numba(), reason="numba is not installed: no compiled step loop without C")
def test_the_cli_backend_line_says_why(short, capsys, monkeypatch):
    monkeypatch.setenv("PHC_FRONT_END_CACHE", "0")
    monkeypatch.setattr(cc, "available", lambda: (False, "no C compiler found (test)"))
    args = ["simulate", str(PENDULUM), "--no-certify", "--solver", "midpoint", "--t-end", str(SHORT * H),
            "--step", str(H), "--n-out", "2", "--backend", "auto"]
    assert main(args) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("  backend")]
    assert len(lines) == 1
    assert f"auto: {SHORT} midpoint steps" in lines[0]
    assert lines[0].split()[1].rstrip(":") == "numba"


def test_substeps_split_an_interval_into_the_fewest_steps_not_longer_than_step():
    """One rule for every loop (phc.simulation.step_logic.substeps): a whole number of steps
    stays that number despite the rounding of interval/step, a remainder takes one more step,
    no step set (0) is one step per output interval."""
    from phc.simulation.step_logic import substeps

    assert substeps(0.3, 0.1) == 3  # 0.3 / 0.1 = 2.9999999999999996
    assert substeps(1.0, 0.1) == 10 and substeps(0.7, 0.1) == 7
    assert substeps(1.05, 0.1) == 11 and substeps(0.05, 0.1) == 1
    assert substeps(1.0, 0.0) == 1
    for n in range(1, 2000):  # every whole number of steps of a common size
        assert substeps(n * 1e-3, 1e-3) == n
