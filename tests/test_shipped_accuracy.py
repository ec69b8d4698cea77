"""What `rtol = 1e-6` gives on every shipped model and the test models with outputs (slow):
the largest relative error of each output over the run, against IDA at 2e-9 (its local
tolerances 1e-11), below 1e-4.

The same comparison as ``benchmarks/bench_accuracy.py`` (whose table docs/tolerances.md
shows). Outputs that stay at round-off in the reference (|y_ref| < 1e-10 throughout) are
left out: a relative error of them means nothing. Where the reference stops early (the
flexible slider–crank's undamped bending modes), the part it reached is compared.

The two hardest cases are undamped oscillations over many periods, where the error
accumulates as a phase error: the pendulum's 8.5 periods and the Timoshenko beam's end
rotation rates, carried by its high modes. With IDA's local tolerances at a tenth of
`rtol` they missed the bound (2.7e-4, 3.4e-4); at 1/200
(``phc.simulation.ida.LOCAL_TOLERANCE``) they meet it.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

import phc
from phc.study.accuracy import estimate_errors, relative_output_errors

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
TEST_MODELS = [p for p in [ROOT / "tests" / "models" / "andrews_squeezer.yaml",
                           *sorted((ROOT / "tests" / "models" / "valid").glob("*.yaml"))]
               if "\n  outputs:" in p.read_text()]  # the test models that request outputs
BOUND = 1e-4
REFERENCE = 2e-9
"""rtol = atol of the references: IDA at local tolerances of 1e-11 (1/200 of it)."""
ESTIMATED = {
    "n_four_bar": "IDA passes the N four-bar's eight singular configurations in 10 s, each either itself or "
                  "by a bridge of midpoint steps, and which depends on the BLAS kernel's rounding; the step "
                  "sequences after the restarts differ, and so does BDF's phase error of the crank: 4e-5 with "
                  "the Haswell kernel, 1.5e-4 to 2.5e-4 with SkylakeX (an AVX-512 AMD EPYC)",
}
"""Shipped models whose error at rtol 1e-6 is above the bound on some CPUs (the promise is
measured, not guaranteed: docs/tolerances.md, "What `rtol` promises"), with the reason. For them
the test asks what every run does promise: the run's error estimate (a rerun at a tenth of the
tolerances, phc.study.accuracy) reports an error above the bound, to a factor 2, and the error
stays within ten times the bound."""
NOT_IDA: dict[str, str] = {}  # (the woodpecker's reference runs since issue 34 item 6: 1.2e-5 at 1e-6)
"""Shipped models this IDA-against-IDA test leaves out, with the reason (benchmarks/bench_accuracy.py likewise)."""
CASES = [pytest.param(p, id=p.stem) for p in sorted(MODELS.glob("*.yaml"))
         if p.stem != "crank_testset" and p.stem not in NOT_IDA]
CASES += [pytest.param(p, id=f"tests-{p.stem}") for p in TEST_MODELS]


@pytest.mark.slow
@pytest.mark.validation
@pytest.mark.parametrize("model", CASES)
def test_rtol_1e6_gives_outputs_within_1e4(model):
    compiled = phc.compile_model(model, certify=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = phc.simulate(compiled, solver="ida", rtol=1e-6, atol=1e-6, max_steps=2_000_000)
        ref = phc.simulate(compiled, solver="ida", rtol=REFERENCE, atol=REFERENCE, max_steps=2_000_000)
    assert run.success, run.message
    assert len(ref.t) > 0.3 * len(run.t), ref.message  # the reference covers a fair part of the run
    errors = relative_output_errors(run, ref)
    assert errors, "no output above round-off to compare"
    name, err = max(errors.items(), key=lambda kv: kv[1])
    if model.stem in ESTIMATED and err >= BOUND:
        (estimate,) = [e for e in estimate_errors(compiled, run, dict(solver="ida", rtol=1e-6, atol=1e-6,
                                                                      max_steps=2_000_000))
                       if e.kind == "temporal"]
        scale = float(abs(ref.outputs[name]).max())
        assert estimate.ok and estimate.per_output[name] >= err * scale / 2, (name, err, estimate.per_output)
        assert err < 10 * BOUND, f"{name}: relative error {err:.2e}"
        return
    assert err < BOUND, f"{name}: relative error {err:.2e}"
