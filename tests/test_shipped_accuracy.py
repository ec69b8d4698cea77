"""What `rtol = 1e-6` gives on every shipped model (slow): the largest relative error of
each output over the run, against IDA at 1e-10, below 1e-4.

The same comparison as ``benchmarks/bench_accuracy.py`` (whose table docs/tolerances.md
shows). Outputs that stay at round-off in the reference (|y_ref| < 1e-10 throughout) are
left out: a relative error of them means nothing. Where the reference stops early (the
flexible slider–crank's undamped bending modes at 1e-10), the part it reached is compared.

Two models do not meet the bound, for the reason docs/tolerances.md gives: BDF's energy
drift on an undamped oscillation over many periods turns into a phase error that grows
faster than linearly in time (the pendulum's 8.5 periods; the Timoshenko beam's end
rotation rates, carried by its high modes). They are marked as expected failures
(strict: a change that makes them pass shows up here).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

import phc
from phc.accuracy import relative_output_errors

MODELS = Path(__file__).resolve().parents[1] / "models"
BOUND = 1e-4
PHASE_ERROR = pytest.mark.xfail(strict=True, reason="BDF phase error over many periods of an undamped "
                                                   "oscillation (docs/tolerances.md)")
CASES = [pytest.param(p.stem, marks=[PHASE_ERROR] if p.stem in ("pendulum", "timoshenko_beam") else [])
         for p in sorted(MODELS.glob("*.yaml")) if p.stem != "crank_testset"]


@pytest.mark.slow
@pytest.mark.parametrize("model", CASES)
def test_rtol_1e6_gives_outputs_within_1e4(model):
    compiled = phc.compile_model(MODELS / f"{model}.yaml", certify=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = phc.simulate(compiled, solver="ida", rtol=1e-6, atol=1e-6, max_steps=2_000_000)
        ref = phc.simulate(compiled, solver="ida", rtol=1e-10, atol=1e-10, max_steps=2_000_000)
    assert run.success, run.message
    assert len(ref.t) > 0.3 * len(run.t), ref.message  # the reference covers a fair part of the run
    errors = relative_output_errors(run, ref)
    name, err = max(errors.items(), key=lambda kv: kv[1])
    assert err < BOUND, f"{name}: relative error {err:.2e}"
