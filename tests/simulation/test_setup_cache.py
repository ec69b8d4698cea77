"""The per-run set-up kept for repeated inputs (:func:`phc.simulation.scaling.remember`): the nominal
scales' probe (:func:`~phc.simulation.scaling.cached_nominal_scales`) and IDA's tolerances
(:func:`phc.simulation.ida.run_settings`) are computed once for a set of inputs and anew for any
other; a run that repeats another is the same run."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.simulation import ida as ida_module
from phc.simulation import scaling

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def pendulum():
    return phc.compile_model(MODELS / "pendulum.yaml", certify=False, backend="numpy")


def _counted(monkeypatch):
    """Counters of the probe's runs and of the tolerances' computations."""
    counts = {"probe": 0, "tolerances": 0}
    probe, tolerances = scaling._probe, ida_module._tolerances

    def spy_probe(*args, **kwargs):
        counts["probe"] += 1
        return probe(*args, **kwargs)

    def spy_tolerances(*args, **kwargs):
        counts["tolerances"] += 1
        return tolerances(*args, **kwargs)

    monkeypatch.setattr(scaling, "_probe", spy_probe)
    monkeypatch.setattr(ida_module, "_tolerances", spy_tolerances)
    monkeypatch.setattr(scaling, "_CACHE", type(scaling._CACHE)())  # nothing kept from other tests
    return counts


def _run(compiled, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return phc.simulate(compiled, solver="ida", t_end=0.5, n_out=21, **options)


def test_a_repeated_run_reuses_its_set_up_and_is_the_same_run(pendulum, monkeypatch):
    counts = _counted(monkeypatch)
    first = _run(pendulum, rtol=1e-6, atol=1e-8)
    assert counts == {"probe": 1, "tolerances": 1}
    second = _run(pendulum, rtol=1e-6, atol=1e-8)
    assert counts == {"probe": 1, "tolerances": 1}  # nothing computed again
    np.testing.assert_array_equal(first.y, second.y)
    assert first.steps == second.steps


@pytest.mark.parametrize("change", [dict(atol=1e-9), dict(rtol=1e-7), dict(params={"L": 0.5}), dict(t_end=0.4)])
def test_a_changed_input_computes_the_set_up_anew(pendulum, monkeypatch, change):
    """atol (the scales' round-off floor and IDA's tolerances), rtol (IDA's tolerances; the scales read
    atol times the tested fraction, which depends on it), a parameter (both) and the time span (both):
    each computes what reads it again, and the run equals one with nothing kept."""
    counts = _counted(monkeypatch)
    options = dict(rtol=1e-6, atol=1e-8)
    _run(pendulum, **options)
    changed = {**options, **change}
    t_end = changed.pop("t_end", 0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = phc.simulate(pendulum, solver="ida", t_end=t_end, n_out=21, **changed)
    assert counts["tolerances"] == 2
    if "rtol" not in change:
        assert counts["probe"] == 2
    monkeypatch.setattr(scaling, "_CACHE", type(scaling._CACHE)())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fresh = phc.simulate(pendulum, solver="ida", t_end=t_end, n_out=21, **changed)
    np.testing.assert_array_equal(run.y, fresh.y)


def test_the_kept_scales_are_returned_as_copies(pendulum, monkeypatch):
    """Changing the scales a call returned does not change what the next call gets (nor their
    attributes: :class:`phc.simulation.scaling.Scales`)."""
    _counted(monkeypatch)
    from phc.simulation import parameter_vector

    mod = pendulum.module
    p = parameter_vector(mod)
    y0, yp0 = np.linspace(0.1, 1.0, mod.N), np.zeros(mod.N)
    a = scaling.cached_nominal_scales(mod, p, y0, yp0, span=1.0, atol=1e-8)
    expected = np.array(a)
    a[:] = -1.0
    b = scaling.cached_nominal_scales(mod, p, y0, yp0, span=1.0, atol=1e-8)
    np.testing.assert_array_equal(b, expected)
    fresh = scaling.nominal_scales(mod, p, y0, yp0, span=1.0, atol=1e-8)
    np.testing.assert_array_equal(b, fresh)
    assert type(b) is type(fresh)
    for name in ("floored", "sizes"):
        x, y = getattr(b, name, None), getattr(fresh, name, None)
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_array_equal(x, y)
