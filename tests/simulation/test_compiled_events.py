"""State events inside the compiled fixed-step loop (:mod:`phc.simulation.compiled_steps`,
the operation ``_watch`` of :mod:`phc.simulation.step_logic`): on the numba back end a run with
switching conditions steps in the compiled loop between events, which hands back the step at
whose end a switching function has fallen through zero; the Python loop's code locates the
event. Against the Python loop (``PHC_COMPILED_LOOP=0``) on the same compiled functions: the
same events, their times within the location tolerance, the same trajectory to the Newton
tolerance; against closed forms where the motion has one."""

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
