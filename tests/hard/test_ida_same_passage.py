"""One `passage` event per rank drop IDA's bridges pass (phc.simulation.ida_bridge): a bridge that
starts where the last one ended, and whose conditioning dips on the passage's flank without
going below the last one's lowest, takes the same passage. At rtol = atol = 2e-9 (the accuracy
benchmark's reference) the N = 1 four-bar reported one of its 10 passes twice that way (11
events): a bridge from t = 6.4809 s, lowest 2.7e-8 at 6.4828, right after the one that located
the singular instant at 6.4790 (4.8e-9).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import phc
from phc.simulation.ida_bridge import SAME_PASSAGE, Bridges

ROOT = Path(__file__).resolve().parents[2]


def _after(t0, t1, lowest_at, lowest):
    """Bridges as they are after one bridge from t0 to t1, conditioned `lowest` at `lowest_at`."""
    b = Bridges.__new__(Bridges)
    b.records = [("event", "", t0, t1, 33, lowest_at, None)]
    b._last_lowest = lowest
    return b


def test_a_dip_on_the_flank_is_the_same_passage():
    b = _after(6.477057, 6.480884, 6.478971, 4.83e-9)
    assert b._same_passage(6.480884, 6.482768, 2.66e-8)  # the run's second bridge
    assert b._same_passage(6.480884, 6.480884, 4.56e-8)  # lowest at its start: no minimum inside
    assert not b._same_passage(6.480884, 6.482768, 1e-10)  # a deeper rank drop: a passage of its own
    far = 6.480884 + 1.01 * SAME_PASSAGE * (6.480884 - 6.477057)
    assert not b._same_passage(far, far + 1e-3, 2.66e-8)  # too far from the last bridge's end
    assert not b._same_passage(far, far, 2.66e-8)


def _exact_singular_times(t_end):
    """The instants the exact 1-dof motion of the N = 1 four-bar has its bars horizontal (θ a
    multiple of π): θ̈ = −g P cos θ / I (tests/hard/test_n_four_bar.py has the derivation)."""
    m, L, g = 1.0, 1.0, 9.81
    inertia, moment = 2 * m * L**2 / 3 + m * L**2, 2 * m * L / 2 + m * L
    sol = solve_ivp(lambda t, s: [s[1], -g * moment * np.cos(s[0]) / inertia], (0, t_end),
                    [np.pi / 2, -1.0 / L], rtol=1e-12, atol=1e-12, dense_output=True)
    t = np.linspace(0.0, t_end, 1_000_001)
    k = np.floor(sol.sol(t)[0] / np.pi)
    return t[1:][np.diff(k) != 0]


@pytest.mark.slow
def test_ida_at_the_reference_tolerances_reports_each_pass_once():
    compiled = phc.compile_model(ROOT / "models" / "n_four_bar.yaml", certify=False)
    r = phc.simulate(compiled, solver="ida", t_end=10.0, n_out=1001, rtol=2e-9, atol=2e-9)
    assert r.success, r.message
    singular = _exact_singular_times(10.0)
    passages = [e.t for e in r.events if e.kind == "passage"]
    assert len(passages) == len(singular), (passages, singular)
    # each at an exact singular instant, to a few bridge lengths (the bridge step with the lowest
    # conditioning is reported)
    assert np.abs(np.array(passages) - singular).max() < 0.01, (passages, singular)


def test_a_long_bridge_does_not_take_the_next_pass():
    """A bridge that located its instant counts, for the window in which a failure after it is the
    same passage, only twice the way to its minimum: the rest of it is the conditioning's slow
    recovery. IDA on the N = 10 four-bar (`phc.simulate(c, solver='ida', t_end=10, n_out=1001)`):
    its first bridge ran from 0.6967 to 0.9703 s (3 020 steps), lowest at 0.7201, and the bridge of
    the next pass, from 1.2385 s (lowest at 1.2410, 0.5 s later, 1.98e-12 against 1.43e-12), fell
    within four of its lengths: 9 events for 10 passes."""
    b = _after(0.696736, 0.970281, 0.720141, 1.428e-12)
    assert not b._same_passage(1.238522, 1.241034, 1.979e-12)  # the next pass: an event of its own
    assert b._same_passage(0.975, 0.975, 2e-9)  # IDA failing again on its way out: the same passage
    window = SAME_PASSAGE * 2.0 * (0.720141 - 0.696736)
    assert b._same_passage(0.970281 + 0.99 * window, 0.970281 + 0.99 * window, 2e-9)
    assert not b._same_passage(0.970281 + 1.01 * window, 0.970281 + 1.01 * window, 2e-9)
