"""State events inside the compiled fixed-step loop (:mod:`phc.simulation.compiled_steps`,
the operation ``_watch`` of :mod:`phc.simulation.step_logic`): on the numba back end a run with
switching conditions steps in the compiled loop between events, which hands back the step at
whose end a switching function has fallen through zero; the Python loop's code locates the
event. Against the Python loop (``PHC_COMPILED_LOOP=0``) on the same compiled functions: the
same events, their times within the location tolerance, the same trajectory to the Newton
tolerance; against closed forms where the motion has one. The C back end's loop (steps.c's
``op_watch`` on the model library's ``phc_events``) against both: the same events, their times
within the location tolerance, the same trajectory to the Newton tolerance."""

from __future__ import annotations

import math

import numpy as np
import pytest
import test_events as event_models
from compiled_loading import assert_same_trajectory, both_loops

import phc
from phc.codegen.numba_backend import available
from phc.simulation.midpoint import EVENT_TOL

OK, WHY = available()
pytestmark = pytest.mark.skipif(not OK, reason=f"the compiled loop needs numba: {WHY}")

# The models of tests/simulation/test_events.py (their tolerances and outputs do not change fixed steps).
COULOMB = event_models.FRICTION.format(law="e_fr = Fc*sign(f_fr)")
PUSHED = event_models.PUSHED.format(force="c*t")


@pytest.fixture
def loops(monkeypatch):
    """Per call of compiled_steps.integrate (one per piece between events): whether the compiled loop ran it."""
    from phc.simulation import compiled_steps

    calls = []
    original = compiled_steps.integrate

    def spy(*args, **kwargs):
        out = original(*args, **kwargs)
        calls.append(out is not None and out.extra.get("step_loop") == "numba")
        return out

    monkeypatch.setattr(compiled_steps, "integrate", spy)
    return calls


def _model(tmp_path, text):
    path = tmp_path / "model.yaml"
    path.write_text(text)
    model = phc.compile_model(path, certify=False, backend="numba")
    assert model.backend == "numba"
    return model


def _location_tolerance(t, h):
    """Each loop locates a crossing to max(EVENT_TOL·max(1, |t|), 1e-9·h) (midpoint._locate) on
    trajectories that agree to the Newton tolerance: the two times within twice that."""
    return 2.0 * max(EVENT_TOL * max(1.0, abs(t)), 1e-9 * h)


def _same_events(fast, slow, h):
    assert [(e.kind, e.condition, e.direction) for e in fast.events] == \
        [(e.kind, e.condition, e.direction) for e in slow.events]
    for a, b in zip(fast.events, slow.events):
        assert abs(a.t - b.t) <= _location_tolerance(b.t, h), (a, b)


@pytest.mark.parametrize("solver, h", [("midpoint", 1e-3), ("discrete_gradient", 1e-3), ("midpoint4", 2e-3)])
def test_coulomb_block_steps_in_the_compiled_loop_between_its_events(tmp_path, monkeypatch, loops, solver, h):
    """The block slides left until π/2, right until π, then sticks (k·0.1 < F_c; the closed form
    of tests/simulation/test_events.py): three pieces, each in the compiled loop."""
    model = _model(tmp_path, COULOMB)
    fast, slow = both_loops(monkeypatch, model, solver=solver, step=h)
    half = len(loops) // 2
    assert half == 3 and loops == [True] * half + [False] * half
    assert [(e.kind, e.direction) for e in fast.events] == [("slip", 1), ("stick", 0)]
    _same_events(fast, slow, h)
    # the method's error at these steps (test_events.py: 2e-6 for midpoint, 1e-9 for midpoint4)
    assert abs(fast.events[0].t - math.pi / 2) < 2e-6 and abs(fast.events[1].t - math.pi) < 2e-6
    assert_same_trajectory(fast, slow, h)
    assert np.abs(fast["block.p"][fast.t > math.pi + 1e-3]).max() < 1e-12  # sticking is exact


def test_a_sticking_sign_is_watched_in_the_compiled_loop(tmp_path, monkeypatch, loops):
    """Pushed by c·t against F_c: stuck (the compiled loop watches 1 ∓ s) until t* = F_c/c."""
    model = _model(tmp_path, PUSHED)
    fast, slow = both_loops(monkeypatch, model, solver="midpoint", step=1e-3)
    half = len(loops) // 2
    assert loops[:half] == [True] * half and not any(loops[half:])
    assert [(e.kind, e.direction) for e in fast.events] == [("stick", 0), ("slip", 1)]
    _same_events(fast, slow, 1e-3)
    assert abs(fast.events[1].t - 0.75) < 1e-9  # s = c·t/F_c reaches 1 at t* = 3/4 (linear in t: exact)
    assert_same_trajectory(fast, slow, 1e-3)


def test_the_watch_map_is_the_watch(tmp_path):
    """The compiled loop's a + b·v is the Watch's value bit for bit, in every mode of the block."""
    from phc.simulation.compiled_steps import watch_map
    from phc.simulation.events import Watch

    model = _model(tmp_path, PUSHED)
    raw = getattr(model.module, "module", model.module)
    watch = Watch(raw, raw.full_parameters())
    rng = np.random.default_rng(7)
    for stuck in (False, True):
        for mode in (1.0, -1.0, 0.0):
            watch.set_mode(0, mode)
            watch.set_stick(0, stuck)
            wmap = watch_map(watch)
            for _ in range(5):
                y, yp = rng.normal(size=raw.N), rng.normal(size=raw.N)
                v = watch.values(0.3, y, yp)
                mine = wmap[0] + wmap[1] * v[wmap[2].astype(int)]
                assert np.array_equal(mine, watch(0.3, y, yp))


def test_a_diode_switching_with_a_source_in_t_follows_the_python_loop(tmp_path, monkeypatch, loops):
    """The half-wave rectifier of test_events.py (a comparison ``e_D > 0`` watched while a sine
    source drives it): five switches, each within the location tolerance of the Python loop's and
    within the method's error (midpoint at h = 1e-5: 3e-7, test_events.py) of the independent
    solution written there."""
    from test_events import RECTIFIER, _rectifier_reference

    model = _model(tmp_path, RECTIFIER)
    fast, slow = both_loops(monkeypatch, model, solver="midpoint", step=1e-5)
    half = len(loops) // 2
    assert half >= 6 and loops == [True] * half + [False] * half  # a piece per event at least
    _same_events(fast, slow, 1e-5)
    reference, switches = _rectifier_reference(fast.t)
    assert len(fast.events) == len(switches) == 5
    assert max(abs(e.t - s) for e, s in zip(fast.events, switches)) < 3e-7
    assert_same_trajectory(fast, slow, 1e-5)


# ---------------------------------------------------------------------------------------------------
# the C back end's step loop (phc/codegen/c_runtime/steps.c: op_watch, the model library's phc_events)

def _c_model(tmp_path, text):
    from phc.codegen.c_backend import available as c_available

    ok, why = c_available()
    if not ok:
        pytest.skip(f"the C step loop needs a C compiler: {why}")
    path = tmp_path / "model_c.yaml"
    path.write_text(text)
    model = phc.compile_model(path, certify=False, backend="c")
    assert model.backend == "c"
    return model


@pytest.fixture
def step_loops(monkeypatch):
    """Per call of compiled_steps.integrate: the loop that ran the piece ("c", "numba"), None for Python's."""
    from phc.simulation import compiled_steps

    seen = []
    original = compiled_steps.integrate

    def spy(*args, **kwargs):
        out = original(*args, **kwargs)
        seen.append(None if out is None else out["step_loop"])
        return out

    monkeypatch.setattr(compiled_steps, "integrate", spy)
    return seen


@pytest.mark.parametrize("which", ["coulomb", "pushed", "rectifier"])
def test_the_c_librarys_switching_functions_are_the_numpy_modules(tmp_path, which):
    """``phc_events`` is printed from the same expressions as the NumPy module's ``events``
    (ResidualIR.events) with the NumPy module's operations in its order (phc.codegen.c_printer):
    the values agree bit for bit at random points, in every mode the parameters can set."""
    import ctypes

    from test_events import RECTIFIER

    model = _c_model(tmp_path, {"coulomb": COULOMB, "pushed": PUSHED, "rectifier": RECTIFIER}[which])
    raw = model.module
    raw = getattr(raw, "module", raw)
    nev = len(raw.SWITCHES) + len(raw.STICKS)
    assert nev >= 1
    events_c = raw.C_LIBRARY.phc_events
    rng = np.random.default_rng(3)
    for mode in (0.0, 1.0, -1.0):
        p = np.array(raw.full_parameters(), dtype=float)
        p[np.asarray(raw.SWITCH_SLOTS, dtype=int)] = mode
        for _ in range(20):
            t, y, yp = rng.uniform(0.0, 2.0), rng.normal(size=raw.N), rng.normal(size=raw.N)
            mine, theirs = np.full(nev, np.nan), np.full(nev, np.nan)
            raw.REFERENCE.events(t, y, yp, p, theirs)
            events_c(ctypes.c_double(t), *(ctypes.c_void_p(a.ctypes.data) for a in (y, yp, p, mine)))
            assert np.array_equal(mine, theirs), (mine, theirs)


@pytest.mark.parametrize("which, solver, h", [
    ("coulomb", "midpoint", 1e-3), ("coulomb", "discrete_gradient", 1e-3), ("coulomb", "midpoint4", 2e-3),
    ("pushed", "midpoint", 1e-3), ("rectifier", "midpoint", 1e-5)])
def test_the_c_loop_watches_the_switches_as_numbas_loop_and_the_python_loop(tmp_path, monkeypatch, step_loops,
                                                                           which, solver, h):
    """The same event models on the C loop, on numba's loop and on the Python loop (on the C
    module): every piece between events runs in the C loop, and the events are the same, each
    time within the event locator's tolerance of the other two loops' (each loop locates to
    EVENT_TOL on trajectories that agree to the Newton tolerance: _location_tolerance); the
    trajectory is the Python loop's to the Newton tolerance accumulated over the steps
    (assert_same_trajectory), and numba's as well (both compiled loops take the same steps)."""
    from test_events import RECTIFIER

    text = {"coulomb": COULOMB, "pushed": PUSHED, "rectifier": RECTIFIER}[which]
    fast, slow = both_loops(monkeypatch, _c_model(tmp_path, text), solver=solver, step=h)
    half = len(step_loops) // 2
    assert half >= 2 and step_loops == ["c"] * half + [None] * half  # a piece per event at least, all in C
    assert fast.events
    _same_events(fast, slow, h)
    assert_same_trajectory(fast, slow, h)
    del step_loops[:]
    numba_run = phc.simulate(_model(tmp_path, text), solver=solver, step=h)
    assert set(step_loops) == {"numba"}
    _same_events(fast, numba_run, h)
    assert_same_trajectory(fast, numba_run, h)


def test_a_c_library_without_switching_functions_keeps_the_python_loop(tmp_path, monkeypatch, step_loops):
    """A model library printed before ``phc_events`` existed (c_steps.watches is False): the
    run is the Python loop's on the same C functions, bit for bit, and a CompiledLoopWarning
    says once how to get the C loop."""
    from phc.codegen import c_steps
    from phc.errors import CompiledLoopWarning

    model = _c_model(tmp_path, COULOMB)
    monkeypatch.setattr(c_steps, "_SAID", set())
    monkeypatch.setattr(c_steps, "watches", lambda raw: False)
    with pytest.warns(CompiledLoopWarning, match="no switching functions"):
        fast = phc.simulate(model, solver="midpoint", step=1e-3)
    monkeypatch.setenv("PHC_COMPILED_LOOP", "0")
    slow = phc.simulate(model, solver="midpoint", step=1e-3)
    assert fast.success and fast.events and "c" not in step_loops
    assert np.array_equal(fast.y, slow.y)


def test_auto_without_c_runs_a_long_event_run_on_numbas_loop(tmp_path, monkeypatch, step_loops):
    """``auto`` where C is not used (the compiler blocked while the model compiles): the small
    model is the NumPy module, and a fixed-step run of at least AUTO_LOOP_STEPS steps with
    switching conditions switches to numba's compiled loop, which watches them
    (phc.simulation.fixed_step_plan excludes contacts alone); the events are the NumPy module's
    Python loop's, each time within the locator's tolerance."""
    from phc.codegen import backends, cc

    path = tmp_path / "auto.yaml"
    path.write_text(COULOMB)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(cc, "available", lambda: (False, "no C compiler found (test)"))
        model = phc.compile_model(path, certify=False, backend="auto")
    assert model.backend == "numpy"
    h = 1e-3
    assert 5.0 / h >= backends.AUTO_LOOP_STEPS  # the model's t_end: a long run
    fast = phc.simulate(model, solver="midpoint", step=h)
    assert fast.backend == "numba" and "compiled step loop" in fast.backend_note, fast.backend_note
    assert step_loops and set(step_loops) == {"numba"}
    slow = phc.simulate(model, solver="midpoint", step=h, backend="numpy")
    assert slow.backend == "numpy"
    _same_events(fast, slow, h)
    assert_same_trajectory(fast, slow, h)
