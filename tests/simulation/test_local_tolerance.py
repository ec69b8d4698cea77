"""IDA's local tolerances against the `rtol` a user asks for (docs/tolerances.md).

IDA runs at ``local_fraction(rtol)`` of the tolerances asked for: 1/200, never below
a local rtol of 1e-13. The round-off floor of the nominal scales (step 9 of
:mod:`phc.simulation.scaling`) is measured against the absolute tolerance IDA applies.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.simulation.ida import LOCAL_TOLERANCE, TIGHTEST_LOCAL, local_fraction
from phc.simulation import scaling

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.mark.parametrize("rtol", [1e-3, 1e-6, 1e-8, 1e-11, 1e-12, 1e-14])
def test_local_fraction_is_1_200_but_not_below_the_tightest_local_tolerance(rtol):
    f = local_fraction(rtol)
    assert 0 < f <= 1
    assert rtol * f >= min(rtol, TIGHTEST_LOCAL) * (1 - 1e-12)
    if rtol * LOCAL_TOLERANCE >= TIGHTEST_LOCAL:
        assert f == LOCAL_TOLERANCE
    else:  # the floor decides (rtol 1e-12 runs at 1e-13)
        assert math.isclose(rtol * f, min(rtol, TIGHTEST_LOCAL))


def test_the_round_off_floor_follows_the_solver():
    assert scaling.tested_fraction("ida", 1e-6) == local_fraction(1e-6)
    assert scaling.tested_fraction("ida", 1e-12) == local_fraction(1e-12)
    for solver in ("midpoint", "discrete_gradient", "midpoint4"):
        assert scaling.tested_fraction(solver, 1e-6) == scaling.FIXED_STEP_FRACTION


def test_the_local_fraction_keeps_the_shipped_pendulum_within_100_rtol():
    """The shipped pendulum, released from 90°, over its 20 s (8.5 periods) at rtol 1e-6,
    against the solution of the same motion in the angle written here (θ'' = −(g/L) sin θ,
    scipy DOP853 at 1e-13): within 100 · rtol. With IDA at a tenth of rtol it was 2.7e-4
    (the phase error BDF accumulates over the periods)."""
    from scipy.integrate import solve_ivp

    compiled = phc.compile_model(MODELS / "pendulum.yaml", certify=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = phc.simulate(compiled, solver="ida", rtol=1e-6, atol=1e-6, n_out=801)
    assert run.success, run.message
    assert run.t[-1] == pytest.approx(20.0)
    ref = solve_ivp(lambda t, z: [z[1], -9.81 * math.sin(z[0])], (0, run.t[-1]), [math.pi / 2, 0.0],
                    method="DOP853", rtol=1e-13, atol=1e-13, t_eval=run.t)
    angle = np.asarray(run.outputs["angle"])
    err = np.abs(angle - ref.y[0]).max() / np.abs(ref.y[0]).max()
    assert err < 100 * 1e-6, err
