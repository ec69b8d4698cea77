"""Stress: lossless oscillator and string over many periods (`phc.simulation.midpoint`).

The implicit midpoint rule keeps the discrete energy balance of a quadratic Hamiltonian
exactly at every step, so its drift after N periods is round-off accumulated over the
steps (≤ 1e-10 relative); IDA (BDF, error-controlled) drifts at its tolerance level,
which is reported. Fast: 10² periods; slow: 10⁴ periods (`pytest -m slow tests/hard -s`
prints the figures).
"""

import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

import phc

MODELS = Path(__file__).resolve().parents[2] / "models"


@lru_cache(maxsize=None)
def compiled(name):
    return phc.compile_model(MODELS / name)


PERIOD_OSC = 2 * math.pi / math.sqrt(4.0 / 1.0)  # mass_spring_damper: k = 4, m = 1
PERIOD_STRING = 2 * 0.64 / 80.0  # vibrating_string: 2L/c, the fundamental


def _step(period, steps_per_period):
    """The midpoint rule's step; None for IDA, whose steps follow its tolerances."""
    return period / steps_per_period if steps_per_period is not None else None


def _oscillator(periods, solver, steps_per_period=None, **kw):
    return phc.simulate(compiled("mass_spring_damper.yaml"), params={"c": 0.0}, solver=solver,
                        t_end=periods * PERIOD_OSC, n_out=periods + 1, step=_step(PERIOD_OSC, steps_per_period),
                        **kw)


# The free string released from a smooth strain profile (the shipped model's force pulse
# switched off: a BDF code's first step could jump over a 4 ms pulse).
STRING_INITIAL = {f"string.eps[{i}]": 1e-3 * math.sin(math.pi * (i + 0.5) / 16) for i in range(16)}


def _string(periods, solver, steps_per_period=None, **kw):
    return phc.simulate(compiled("vibrating_string.yaml"), solver=solver, t_end=periods * PERIOD_STRING,
                        n_out=periods + 1, step=_step(PERIOD_STRING, steps_per_period), params={"F0": 0.0},
                        initial=STRING_INITIAL, **kw)


def _drift(result):
    """Relative energy drift: max |H − H(0)| / max H."""
    return float(np.abs(result.H - result.H[0]).max() / np.abs(result.H).max())


def _check(run, periods, steps_per_period, ida_rtol=1e-6):
    mp = run(periods, "midpoint", steps_per_period)
    assert mp.success, mp.message
    assert mp.energy_balance_relative <= 1e-10
    ida = run(periods, "ida", rtol=ida_rtol, atol=1e-3 * ida_rtol, max_steps=10**9)
    assert ida.success, ida.message
    print(f"\n{periods} periods: energy balance midpoint {mp.energy_balance_relative:.1e}, "
          f"IDA {ida.energy_balance_relative:.1e} (rtol {ida.rtol:g})")
    assert np.isfinite(ida.energy_balance_relative)
    assert ida.H.max() > 0 and mp.H.max() > 0
    assert ida.energy_balance_relative > mp.energy_balance_relative
    return mp, ida


def test_oscillator_100_periods():
    mp, _ = _check(_oscillator, 100, 40)
    # the amplitude does not decay or grow: the closed form's energy ½ k x0² = 0.5
    assert mp.H == pytest.approx(0.5, rel=1e-10)


def test_string_100_periods():
    mp, _ = _check(_string, 100, 80, ida_rtol=1e-4)
    assert _drift(mp) <= 1e-10
    assert mp.H[0] > 0


@pytest.mark.slow
def test_oscillator_10000_periods():
    mp, _ = _check(_oscillator, 10_000, 40, ida_rtol=1e-10)
    assert mp.H == pytest.approx(0.5, rel=1e-10)


@pytest.mark.slow
def test_string_10000_periods():
    mp, _ = _check(_string, 10_000, 40, ida_rtol=1e-8)
    assert _drift(mp) <= 1e-10
