"""One options object (issue 31 item 3): the model file's `simulation` section, a scene,
the command line and `phc.simulate` accept and refuse the same run options, with one
wording: the names and defaults are :class:`phc.options.RunOptions`'s, the ranges
:data:`phc.names.RUN_LIMITS` (the spec's pydantic types are built from them)."""

from __future__ import annotations

import math
from pathlib import Path

import pydantic
import pytest

import phc
from phc.errors import SimulationSetupError
from phc.names import RUN_LIMITS, option_problem
import dataclasses

from phc.options import DEFAULTS, RunOptions
from phc.spec.model import SimulationSpec
from phc.spec.run import TYPES
from phc.spec.scene import AccuracySpec, SceneSpec
from time_limits import SUBPROCESS_TIMEOUT

MODELS = Path(__file__).resolve().parents[1] / "models"

# for every numeric option: values on both sides of each end of its range
CASES = {
    "t_end": ([1e-9, 1e300], [0.0, -1.0, math.inf, math.nan]),
    "n_out": ([2, 10_000_000], [1, 10_000_001, 0]),
    "rtol": ([1e-12, 0.5], [0.0, 1.0, -1e-3, math.nan]),
    "atol": ([1e-300, 1e3], [0.0, -1.0, math.inf]),
    "step": ([1e-9, 10.0], [0.0, -1e-3, math.inf, math.nan]),
    "max_steps": ([1, 2 ** 31 - 1], [0, 2 ** 31]),
    "max_order": ([1, 5], [0, 6]),
}


def test_every_numeric_option_has_cases():
    assert set(CASES) == set(RUN_LIMITS) == set(TYPES)


def _spec_accepts(model, name, value) -> bool:
    try:
        model.model_validate({name: value})
    except pydantic.ValidationError:
        return False
    return True


def _scene_accepts(name, value) -> bool:
    if name in AccuracySpec.model_fields:
        return _spec_accepts(AccuracySpec, name, value)
    if name in SceneSpec.model_fields:
        try:
            SceneSpec.model_validate({"model": "m.yaml", name: value})
        except pydantic.ValidationError:
            return False
        return True
    return None  # not a scene option (max_steps)


@pytest.mark.parametrize("name", sorted(CASES))
def test_every_layer_draws_the_same_line(name):
    good, bad = CASES[name]
    base = RunOptions(t_end=1e300) if name != "t_end" else RunOptions()
    for value in good:
        assert _spec_accepts(SimulationSpec, name, value), (name, value)
        assert _scene_accepts(name, value) in (True, None), (name, value)
        assert option_problem(*RUN_LIMITS[name], value) is None, (name, value)
        assert getattr(base.with_overrides(**{name: value}), name) == value
    for value in bad:
        assert not _spec_accepts(SimulationSpec, name, value), (name, value)
        assert _scene_accepts(name, value) in (False, None), (name, value)
        problem = option_problem(*RUN_LIMITS[name], value)
        assert problem is not None and problem.startswith("must be ")
        with pytest.raises(SimulationSetupError) as err:
            base.with_overrides(**{name: value})
        assert str(err.value) == f"`{name}` {problem}"  # the command line's words, named as in Python


def test_the_model_section_gives_the_options_object():
    fields = set(RunOptions.names())
    assert fields <= set(SimulationSpec.model_fields)
    section = SimulationSpec()
    assert section.run_options() == DEFAULTS  # the defaults are RunOptions'
    assert {name: SimulationSpec.model_fields[name].default for name in fields} == dataclasses.asdict(DEFAULTS)
    written = SimulationSpec.model_validate({"t_end": 3.0, "rtol": 1e-6, "solver": "midpoint", "step": 0.01})
    assert written.run_options() == RunOptions(t_end=3.0, rtol=1e-6, solver="midpoint", step=0.01)
    with pytest.raises(pydantic.ValidationError, match="must be before `t_end`"):
        SimulationSpec(t_start=2.0, t_end=1.0)
    with pytest.raises(SimulationSetupError, match="must be a finite time greater than the start time"):
        RunOptions(t_start=0.5).with_overrides(t_end=0.25)
    with pytest.raises(SimulationSetupError, match="unknown solver `rk4`"):
        RunOptions().with_overrides(solver="rk4")
    with pytest.raises(TypeError, match="unknown run option"):
        RunOptions().with_overrides(tolerance=1e-3)
    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULTS.rtol = 0.5  # frozen
    assert isinstance(RunOptions().with_overrides(n_out=5.0).n_out, int)


def test_the_options_object_loads_without_pydantic():
    """What a cached `phc simulate` imports: the options, not the model language."""
    import subprocess
    import sys

    code = "import sys, phc.options; print('pydantic' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.strip() == "False", out.stdout + out.stderr


def test_simulate_refuses_what_the_file_refuses():
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml", certify=False)
    for name, (_, bad) in CASES.items():
        with pytest.raises(SimulationSetupError, match=f"^`{name}` must be"):
            phc.simulate(compiled, **{name: bad[0]})
    run = phc.simulate(compiled, t_end=0.1, n_out=3, rtol=1e-6, max_order=2)
    assert run.success and run.rtol == 1e-6 and run.atol == compiled.options["atol"]
    with pytest.warns(phc.simulation.IgnoredOptionWarning, match="ignores `max_order`"):
        phc.simulate(compiled, t_end=0.1, n_out=3, solver="midpoint", max_order=2)


def test_max_order_reaches_ida():
    """BDF of order 1 needs far more steps than orders up to 5 for the same tolerance
    (error per step O(h²) against O(h⁶)): the option is not dropped on its way."""
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml", certify=False)
    low = phc.simulate(compiled, t_end=1.0, rtol=1e-7, atol=1e-9, max_order=1)
    high = phc.simulate(compiled, t_end=1.0, rtol=1e-7, atol=1e-9, max_order=5)
    assert low.success and high.success
    assert low.steps > 5 * high.steps
