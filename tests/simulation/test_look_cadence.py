"""The singularity monitor's cadence inside IDA is bounded by what a look costs (issue 38).

At the 1000-element beam (8007 unknowns) one sparse look cost what ~30 IDA steps cost, and the
step hook looked every 20 steps: the run took 2.3× its time without the monitor. The cadence
now keeps the looks at ``LOOK_SHARE`` of the integration's work unless the conditioning ratio
falls toward the threshold. The work is counted from IDA's counters and the looks' own
factorizations, never timed (issue 38/34): the runs below look at the same steps under any clock,
and no timing is asserted."""

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
    k = affordable_cadence(20, 20, look_work=30e-3, step_work=1e-3, before=4e-7, ratio=4e-7, steps=20,
                           threshold=THRESHOLD)
    assert k == math.ceil(30 / LOOK_SHARE)


def test_a_cheap_look_keeps_the_cadence_the_ratio_asks_for():
    k = affordable_cadence(20, 20, look_work=1e-3, step_work=1e-3, before=4e-7, ratio=4e-7, steps=20,
                           threshold=THRESHOLD)
    assert k == 20


def test_a_falling_ratio_brings_expensive_looks_back_toward_the_base():
    # from 1e-5 to 1e-6 in 20 steps: 0.05 decades a step, 5 decades left to 1e-11, so at that
    # rate the threshold is 100 steps away: APPROACH_LOOKS looks before it, every 25 steps
    k = affordable_cadence(20, 20, look_work=30e-3, step_work=1e-3, before=1e-5, ratio=1e-6, steps=20,
                           threshold=THRESHOLD)
    assert k == int(5 / (APPROACH_LOOKS * 0.05))
    # falling faster than that: the base cadence, never less
    assert affordable_cadence(20, 20, look_work=30e-3, step_work=1e-3, before=1e-3, ratio=1e-6, steps=20,
                              threshold=THRESHOLD) == 20


def test_near_the_threshold_the_base_cadence_whatever_a_look_costs():
    ratio = THRESHOLD * 10 ** (NEAR_DECADES - 0.5)
    assert affordable_cadence(20, 20, look_work=1.0, step_work=1e-3, before=ratio, ratio=ratio, steps=20,
                              threshold=THRESHOLD) == 20


@pytest.fixture
def looks(monkeypatch):
    """The times of the monitor's looks inside IDA's step loop, and the step hook (its budget)."""
    seen = {"times": [], "hooks": []}
    look, init = ida._StepHook._look, ida._StepHook.__init__

    def recorded_look(self, t, y, yp, h):
        seen["times"].append(float(t))
        return look(self, t, y, yp, h)

    def recorded_init(self, *args, **kwargs):
        init(self, *args, **kwargs)
        seen["hooks"].append(self)

    monkeypatch.setattr(ida._StepHook, "_look", recorded_look)
    monkeypatch.setattr(ida._StepHook, "__init__", recorded_init)
    return seen


def _beam(tmp_path, elements: int = 30):
    text = (ROOT / "models" / "euler_bernoulli_beam.yaml").read_text()
    path = tmp_path / f"beam{elements}.yaml"
    path.write_text(text.replace("elements: 6\n", f"elements: {elements}\n"))
    return phc.compile_model(path, certify=False)


def test_the_looks_at_a_large_beam_stay_a_tenth_of_the_run(tmp_path, looks):
    """The Euler–Bernoulli cantilever with 30 elements (above the monitor's dense size) over
    2e-5 s: the looks' counted work is at most LOOK_SHARE of the steps', plus the first two looks
    (at the base cadence: how the ratio moves is not known before) — a look there weighs some
    60–100 steps. Before issue 38 the hook looked every 20 steps (at most every 640, the stretch
    where the ratio is flat and far)."""
    compiled = _beam(tmp_path)
    assert compiled.module.N > monitor.DENSE_SIZE
    r = phc.simulate(compiled, solver="ida", t_end=2e-5)
    assert r.success, r.message
    budget = looks["hooks"][-1].budget
    assert r.steps > 2000  # enough steps that the old cadence looked 100 times or more
    assert budget.look_work > 20 * budget.step_work  # an expensive look, as on the 1000-element beam
    assert 1 <= len(looks["times"]) < r.steps / 20
    assert budget.looking <= LOOK_SHARE * budget.integrating + 2 * budget.look_work


def test_the_cadence_is_a_function_of_the_runs_counters_not_of_a_clock(tmp_path, looks, monkeypatch):
    """The same run looks at the same steps whatever the clocks say: the beam above run once as it
    is and once with every clock of the ``time`` module replaced by one that jumps by random
    amounts (a busy machine, a slow look). When the cadence was timed, a look that took longer
    made the next ones rarer."""
    import random
    import time

    compiled = _beam(tmp_path)
    first = phc.simulate(compiled, solver="ida", t_end=2e-5)
    times, looks["times"] = looks["times"], []
    rng, now = random.Random(1), [0.0]

    def jumping(*_):
        now[0] += rng.choice([1e-6, 1.0, 1e3])
        return now[0]

    for name in ("process_time", "perf_counter", "monotonic", "time", "thread_time"):
        monkeypatch.setattr(time, name, jumping)
    second = phc.simulate(compiled, solver="ida", t_end=2e-5)
    monkeypatch.undo()
    assert now[0] > 0  # the run did read a clock (its CPU time), just not for the cadence
    assert first.steps == second.steps
    assert len(times) > 1 and looks["times"] == times


def test_the_work_of_a_look_is_counted_from_its_lu():
    """A sparse look's work grows with the nonzeros of its LU and the solves it makes, and IDA's
    steps' work with its counters: a pure function of counts (no clock is read)."""
    import numpy as np
    import scipy.sparse as sps
    import scipy.sparse.linalg as spla

    # a tridiagonal matrix has no fill: n − 1 multipliers and n − 1 updates of one entry each
    n = 50
    J = sps.diags([np.full(n - 1, -1.0), np.full(n, 4.0), np.full(n - 1, -1.0)], [-1, 0, 1], format="csc")
    lu = spla.splu(J, permc_spec="NATURAL", diag_pivot_thresh=0.0)
    assert look_cadence.sparse_lu_flops(lu) == ((n - 1) + 2 * (n - 1), lu.L.nnz + lu.U.nnz)
    one, two = look_cadence.LookWork(), look_cadence.LookWork()
    one.sparse(J.nnz, lu=lu, solves=4)
    two.sparse(J.nnz, lu=lu, solves=8)
    assert one.lu_nnz == lu.L.nnz + lu.U.nnz
    assert two.work - one.work == pytest.approx(4 * (look_cadence.SOLVE_CALL_NS + look_cadence.SOLVE_NS * one.lu_nnz))
    kw = dict(n=n, nnz=J.nnz, sparse=True, lu_flops=one.lu_flops, lu_nnz=one.lu_nnz)
    base = look_cadence.integration_work(residuals=30, jacobians=2, steps=20, **kw)
    assert look_cadence.integration_work(residuals=60, jacobians=4, steps=40, **kw) == pytest.approx(2 * base)


def test_a_fixed_step_monitor_does_not_copy_the_factors_of_its_looks():
    """Only IDA's step hook reads a look's fill, and reading it copies both factors: the monitor of
    a fixed-step run charges its LU as one without fill and never touches ``L`` or ``U``."""

    class Factors:
        """An LU whose factors may not be read."""

        @property
        def L(self):
            raise AssertionError("L read")

        U = L

    from phc.simulation.monitor import SingularityMonitor

    nnz, solves = 148, 3
    work = look_cadence.LookWork(factors=False)
    work.sparse(nnz, lu=Factors(), solves=solves)
    assert work.lu_flops is None and work.lu_nnz is None
    assert work.work == pytest.approx(look_cadence.LOOK_NS + look_cadence.ASSEMBLE_NS * nnz
                                      + look_cadence.FACTOR_NS * nnz + look_cadence.FLOP_NS * 2 * nnz
                                      + solves * (look_cadence.SOLVE_CALL_NS + look_cadence.SOLVE_NS * nnz))

    class Module:
        N, JAC_ROWS, JAC_COLS = 2, [0, 1], [0, 1]

    assert not SingularityMonitor(Module, None).tally.factors
    assert SingularityMonitor(Module, None, count_factors=True).tally.factors


def test_an_expensive_look_still_finds_the_four_bar_passage(tmp_path, looks):
    """The N = 8 four-bar (above the dense size) with IDA, a look weighing several steps: far from
    the passage the hook looks rarely, the falling
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
    r = phc.simulate(compiled, solver="ida", t_end=1.0)
    times = [float(x) for x in re.findall(r"t [=≈] ([0-9.]+)", r.message)]
    assert times and min(abs(t - t_star) for t in times) < 0.05, r.message
    assert "singular" in r.message or "rank drop" in r.message, r.message
    assert len(looks["times"]) >= 2
