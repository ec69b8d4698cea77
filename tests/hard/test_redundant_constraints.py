"""Stress: redundant position constraints — a four-bar whose coupler–rocker pin is doubled.

phc detects this at compile time (it does not run with a least-squares multiplier): the
second connection repeats the first's position constraints, so its coupling map Γ has rank
2 where 4 is needed at every state. `phc compile` (and :func:`phc.compile_model`) stops at
the structural analysis, which names the repeated position rows of the second connection
as equations left without an unknown (PHC-E302); `phc check` also reports PHC-E421 naming
the connection that is not surjective.
The same linkage with a single pin compiles, and both solvers run it.
"""

from pathlib import Path

import pytest

import phc
from phc.cli import main
from phc.errors import ModelError
from time_limits import SUBPROCESS_TIMEOUT

HERE = Path(__file__).resolve().parent / "models"


def test_doubled_joint_is_rejected_at_compile_time():
    with pytest.raises(ModelError) as info:
        phc.compile_model(HERE / "four_bar_doubled_joint.yaml")
    codes = {d.code for d in info.value.diagnostics}
    assert "PHC-E302" in codes  # equations with no unknown left: the repeated position rows
    text = "\n".join(d.message for d in info.value.diagnostics if d.code == "PHC-E302")
    assert "`connections[2].position[" in text


def test_check_names_the_redundant_connection(capsys):
    assert main(["check", str(HERE / "four_bar_doubled_joint.yaml")]) == 1
    out = capsys.readouterr()
    report = out.out + out.err
    assert "coupler.b2 — rocker.pin2: rank 2/4 NOT surjective" in report
    assert "PHC-E421" in report


@pytest.mark.parametrize("solver", ["midpoint", "ida"])
def test_single_joint_four_bar_runs(solver):
    compiled = phc.compile_model(HERE / "four_bar.yaml")
    accuracy = dict(step=1e-3) if solver == "midpoint" else dict(rtol=1e-8, atol=1e-10)
    r = phc.simulate(compiled, solver=solver, **accuracy)
    assert r.success, r.message
    assert r.constraint_drift < 1e-8
    assert r.energy_balance_relative < (1e-12 if solver == "midpoint" else 1e-4)


def test_the_diagnosis_does_not_depend_on_the_hash_seed():
    """Which of the repeated rows is reported must be reproducible (it once varied with
    PYTHONHASHSEED through the matching's node hashes)."""
    import os
    import subprocess
    import sys

    outputs = set()
    for seed in ("1", "3", "5"):
        env = dict(os.environ, PYTHONHASHSEED=seed)
        run = subprocess.run([sys.executable, "-m", "phc", "compile", str(HERE / "four_bar_doubled_joint.yaml")],
                             capture_output=True, text=True, env=env, timeout=SUBPROCESS_TIMEOUT)
        assert run.returncode == 1
        outputs.add(run.stderr)
    assert len(outputs) == 1
