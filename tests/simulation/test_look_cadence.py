"""The singularity monitor's cadence inside IDA is bounded by what a look costs (issue 38).

At the 1000-element beam (8007 unknowns) one sparse look cost what ~30 IDA steps cost, and the
step hook looked every 20 steps: the run took 2.3× its time without the monitor. The cadence
now keeps the looks at ``LOOK_SHARE`` of the integration's CPU time unless the conditioning
ratio falls toward the threshold. The run test replaces the CPU clock by a counter (one unit a
hook call, ``LOOK`` units a look), so the look count is deterministic: no timing assertions."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

import phc
from phc.simulation import ida, look_cadence, monitor
from phc.simulation.look_cadence import APPROACH_LOOKS, LOOK_SHARE, NEAR_DECADES, affordable_cadence

ROOT = Path(__file__).resolve().parents[2]
THRESHOLD = monitor.THRESHOLD


def test_an_expensive_look_far_from_the_threshold_waits_until_it_is_a_tenth_of_the_steps():
    # a look costs 30 steps, the ratio is flat at 4e-7 (the 1000-element beam): 30 / 0.1 = 300 steps
    k = affordable_cadence(20, 20, look_cpu=30e-3, step_cpu=1e-3, before=4e-7, ratio=4e-7, steps=20,
                           threshold=THRESHOLD)
    assert k == math.ceil(30 / LOOK_SHARE)


def test_a_cheap_look_keeps_the_cadence_the_ratio_asks_for():
    k = affordable_cadence(20, 20, look_cpu=1e-3, step_cpu=1e-3, before=4e-7, ratio=4e-7, steps=20,
                           threshold=THRESHOLD)
    assert k == 20


def test_a_falling_ratio_brings_expensive_looks_back_toward_the_base():
    # from 1e-5 to 1e-6 in 20 steps: 0.05 decades a step, 5 decades left to 1e-11, so at that
    # rate the threshold is 100 steps away: APPROACH_LOOKS looks before it, every 25 steps
    k = affordable_cadence(20, 20, look_cpu=30e-3, step_cpu=1e-3, before=1e-5, ratio=1e-6, steps=20,
                           threshold=THRESHOLD)
    assert k == int(5 / (APPROACH_LOOKS * 0.05))
    # falling faster than that: the base cadence, never less
    assert affordable_cadence(20, 20, look_cpu=30e-3, step_cpu=1e-3, before=1e-3, ratio=1e-6, steps=20,
                              threshold=THRESHOLD) == 20


def test_near_the_threshold_the_base_cadence_whatever_a_look_costs():
    ratio = THRESHOLD * 10 ** (NEAR_DECADES - 0.5)
    assert affordable_cadence(20, 20, look_cpu=1.0, step_cpu=1e-3, before=ratio, ratio=ratio, steps=20,
                              threshold=THRESHOLD) == 20


class _Counter:
    """A CPU clock that counts: a unit for each call of IDA's step hook, `look` units a look."""

    def __init__(self, look: float):
        self.now, self.look, self.looks = 0.0, look, 0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def counted(monkeypatch):
    def install(look: float) -> _Counter:
        clock = _Counter(look)
        hook_call, watch = ida._StepHook.__call__, monitor.SingularityMonitor.watch

        def counted_call(self, t, y, yp):
            clock.now += 1.0
            return hook_call(self, t, y, yp)

        def counted_watch(self, *args):
            clock.now += clock.look
            clock.looks += 1
            return watch(self, *args)

        monkeypatch.setattr(look_cadence, "_cpu", clock)
        monkeypatch.setattr(ida._StepHook, "__call__", counted_call)
        monkeypatch.setattr(monitor.SingularityMonitor, "watch", counted_watch)
        return clock
    return install


def test_the_looks_at_a_large_beam_stay_a_tenth_of_the_run(tmp_path, counted):
    """The Euler–Bernoulli cantilever with 30 elements (127 unknowns, above the monitor's dense
    size) over 2e-5 s, a look costing 1000 hook calls: the looks take at most LOOK_SHARE of the
    run's counted time, plus the first two looks (at the base cadence: how the ratio moves is not
    known before). Before, the hook looked every 20 steps
    (at most every 640, the stretch where the ratio is flat and far): 1.5 times the run or more."""
    text = (ROOT / "models" / "euler_bernoulli_beam.yaml").read_text()
    path = tmp_path / "beam30.yaml"
    path.write_text(text.replace("elements: 6\n", "elements: 30\n"))
    compiled = phc.compile_model(path, certify=False)
    assert compiled.module.N > monitor.DENSE_SIZE
    clock = counted(1000.0)
    r = phc.simulate(compiled, solver="ida", t_end=2e-5)
    assert r.success, r.message
    steps_units = clock.now - clock.looks * clock.look
    assert r.steps > 2000  # enough steps that the old cadence looked 100 times or more
    assert clock.looks >= 1
    assert clock.looks * clock.look <= LOOK_SHARE * steps_units + 2 * clock.look


def test_an_expensive_look_still_finds_the_four_bar_passage(tmp_path, counted):
    """The N = 8 four-bar (above the dense size) with IDA, a look costing 30 hook calls (what a
    look at the 1000-element beam costs): far from the passage the hook looks rarely, the falling
    ratio brings it back to every 20 steps, and the passage is reported at the first horizontal
    instant t* (IDA stops there or bridges it; 0.05 s places it, far below the ~0.7 s between two
    passes)."""
    import importlib.util

    import numpy as np
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    spec = importlib.util.spec_from_file_location("n_four_bar", ROOT / "models" / "n_four_bar.py")
    generator = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generator)
    path = tmp_path / "n_four_bar_8.yaml"
    generator.write(8, path)
    # the exact one-degree-of-freedom motion (tests/hard/test_n_four_bar.py): θ(t*) = 0
    inertia, moment = 9 / 3 + 8, 9 / 2 + 8
    sol = solve_ivp(lambda _, x: [x[1], -9.81 * moment / inertia * np.cos(x[0])], (0.0, 1.0), [np.pi / 2, -1.0],
                    rtol=1e-12, atol=1e-12, dense_output=True)
    t_star = brentq(lambda t: sol.sol(t)[0], 0.5, 1.0, xtol=1e-12)
    compiled = phc.compile_model(path, certify=False)
    assert compiled.module.N > monitor.DENSE_SIZE
    clock = counted(30.0)
    r = phc.simulate(compiled, solver="ida", t_end=1.0)
    times = [float(x) for x in re.findall(r"t [=≈] ([0-9.]+)", r.message)]
    assert times and min(abs(t - t_star) for t in times) < 0.05, r.message
    assert "singular" in r.message or "rank drop" in r.message, r.message
    assert clock.looks >= 2
