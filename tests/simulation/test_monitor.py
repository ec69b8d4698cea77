"""Tests of :mod:`phc.simulation.monitor` (the singularity monitor of a run) through
:func:`phc.simulate` on the rigid slider–crank.

With the rod as long as the crank (L = r = 0.15) the rod can fold onto the crank: at crank
angles θ = π/2 + kπ the rod stands perpendicular to the guide, the joint constraints become
dependent and the interconnection loses surjectivity (seed, Prop. "Interconnection through
a finite-dimensional coupling space"). The run must stop there with a message naming the
dependent equations and keep the results computed so far. The default geometry (L = 2r)
never reaches such a configuration and runs to the end.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import phc

REPO = Path(__file__).resolve().parents[2]
SLIDER_CRANK = REPO / "models" / "rigid_slider_crank.yaml"
R, OMEGA = 0.15, 150.0   # crank radius and imposed crank speed of the shipped model


@pytest.fixture(scope="module")
def compiled():
    return phc.compile_model(SLIDER_CRANK)


@pytest.fixture(scope="module")
def folded(compiled):
    return phc.simulate(compiled, params={"L": 0.15})


def test_singular_configuration_stops_the_run(compiled, folded):
    t_end = compiled.dae.options["t_end"]
    assert folded.success is False
    assert "singular configuration" in folded.message
    assert folded.t[-1] < t_end
    assert len(folded.t) > 1
    assert np.all(np.diff(folded.t) > 0)
    assert folded.summary()["success"] is False


def test_message_names_dependent_equations(compiled, folded):
    names = re.findall(r"`([^`]+)`", folded.message.split("become dependent")[0])
    assert names, folded.message
    equations = set(compiled.module.EQUATIONS)
    assert set(names) <= equations, (names, sorted(equations))


def test_run_stops_where_the_rod_is_perpendicular_to_the_guide(folded):
    """The stop time in the message is a singular crank angle θ = π/2 + kπ (θ = ω t)."""
    match = re.search(r"stopped at t = ([0-9.eE+-]+)", folded.message)
    assert match, folded.message
    t_stop = float(match.group(1))
    assert folded.t[-1] <= t_stop
    assert abs(math.cos(OMEGA * t_stop)) < 0.05
    theta = folded["crank.theta"]
    assert theta[-1] == pytest.approx(OMEGA * folded.t[-1], rel=1e-6)


def test_results_before_the_stop_are_kept_and_valid(folded):
    """With L = r the slider sits on one of the branches s = 2r cos θ or s = 0."""
    theta, s = folded["crank.theta"], folded["slider.s"]
    assert np.all(np.isfinite(folded.y))
    off_branch = np.minimum(np.abs(s - 2 * R * np.cos(theta)), np.abs(s))
    assert off_branch.max() < 1e-6
    assert folded.constraint_drift < 1e-6


def test_default_slider_crank_runs_to_the_end(compiled):
    result = phc.simulate(compiled)
    t_end = compiled.dae.options["t_end"]
    assert result.success is True, result.message
    assert "singular" not in result.message
    assert result.t[-1] == pytest.approx(t_end)
    # the closed form of the shipped model's outputs: x = r cos θ + sqrt(L² − r² sin² θ)
    assert np.abs(result["slider_x"] - result["slider_x_exact"]).max() < 1e-6


def test_the_cheap_look_leaves_the_svd_out_only_far_from_singular():
    """A look first estimates the 1-norm condition (LAPACK dgecon on an LU) and skips the
    singular values only when that estimate is RCOND_MARGIN·N times above the threshold.
    Matrices U·diag(s)·Vᵀ with σ_min/σ_max from 1e-2 down to 1e-13: wherever the look skips
    the SVD, the true ratio is above the threshold by a wide margin, and every matrix within
    RCOND_MARGIN of the threshold goes to the SVD."""
    from phc.simulation.monitor import RCOND_MARGIN, THRESHOLD, _far_from_singular

    rng = np.random.default_rng(3)
    skipped = 0
    for n in (6, 40, 120):
        for exponent in np.linspace(-2, -13, 23):
            u, _ = np.linalg.qr(rng.standard_normal((n, n)))
            v, _ = np.linalg.qr(rng.standard_normal((n, n)))
            s = np.logspace(0, exponent, n)
            J = (u * s) @ v.T
            ratio = s[-1] / s[0]
            rough = _far_from_singular(J, THRESHOLD)
            if rough is None:
                continue
            skipped += 1
            assert ratio >= 100 * THRESHOLD, (n, ratio, rough)
            assert rough <= ratio  # the estimate's bound is below the ratio it stands for
        # near the threshold the singular values decide
        u, _ = np.linalg.qr(rng.standard_normal((n, n)))
        J = (u * np.logspace(0, math.log10(RCOND_MARGIN * THRESHOLD), n)) @ u.T
        assert _far_from_singular(J, THRESHOLD) is None
    assert skipped > 20  # the cheap look does take over far from singular (the test can fail)


def test_the_history_keeps_its_reach_while_a_solver_crawls():
    """64 looks a millisecond apart, then 1000 a nanosecond apart (IDA cutting its step before
    a failure): the window still reaches back to the approach, ends at the newest look, and
    keeps its looks in time order — what the failure's diagnosis compares."""
    from collections import deque

    from phc.simulation.monitor import HISTORY, SingularityMonitor

    monitor = SingularityMonitor.__new__(SingularityMonitor)
    monitor.history = deque(maxlen=HISTORY)
    for k in range(HISTORY):
        monitor._remember((1e-3 * k, None, None))
    for k in range(1000):
        monitor._remember((1e-3 * (HISTORY - 1) + 1e-9 * (k + 1), None, None))
    times = [look[0] for look in monitor.history]
    assert len(times) == HISTORY and times == sorted(times)
    assert times[-1] == 1e-3 * (HISTORY - 1) + 1e-9 * 1000
    assert times[0] <= 0.5 * times[-1]  # the approach is still in the window


def test_the_history_follows_a_solver_that_looks_often_for_long():
    """64 looks a millisecond apart, then 10 000 a microsecond apart over 10 ms (a solver on short
    steps all the way to a failure, the folding slider–crank's IDA run): the window advances
    with them. It used to keep the look at 63 ms and the newest one, 10 ms later, and nothing of
    the 10 ms between — where the conditioning fell, which the failure's diagnosis compares."""
    from collections import deque

    from phc.simulation.monitor import HISTORY, SingularityMonitor

    monitor = SingularityMonitor.__new__(SingularityMonitor)
    monitor.history = deque(maxlen=HISTORY)
    for k in range(HISTORY):
        monitor._remember((1e-3 * k, None, None))
    last = 1e-3 * (HISTORY - 1)
    for k in range(10_000):
        monitor._remember((last + 1e-6 * (k + 1), None, None))
    times = np.array([look[0] for look in monitor.history])
    assert len(times) == HISTORY and np.all(np.diff(times) > 0) and times[-1] == last + 1e-2
    assert times[0] >= last  # looks coming at one pace, the window is theirs
    # the look before the newest is near it (it was 10 ms back, 14 % of the window's reach)
    assert times[-1] - times[-2] <= 0.05 * (times[-1] - times[0])


def test_the_history_of_a_large_model_stays_within_its_memory():
    """Each kept look holds a copy of y and ẏ: a mesh of 8·10⁵ unknowns kept 64 of them, 820 MB.
    The window is as long as HISTORY_BYTES allows, never shorter than the four looks the
    failure's diagnosis compares, and a model up to 65 536 unknowns keeps all 64."""
    from types import SimpleNamespace

    from phc.simulation.monitor import HISTORY, HISTORY_BYTES, HISTORY_MIN, SingularityMonitor, history_length

    assert history_length(10) == history_length(65_536) == HISTORY
    for n in (65_537, 200_000, 800_007, 10**7):
        kept = history_length(n)
        assert HISTORY_MIN <= kept < HISTORY
        assert kept == HISTORY_MIN or kept * 16 * n <= HISTORY_BYTES
    assert history_length(800_007) * 16 * 800_007 <= HISTORY_BYTES
    mod = SimpleNamespace(N=800_007, JAC_ROWS=np.zeros(0, dtype=np.int64), JAC_COLS=np.zeros(0, dtype=np.int64))
    assert SingularityMonitor(mod, np.zeros(0)).history.maxlen == history_length(800_007)
