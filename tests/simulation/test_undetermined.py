"""The momenta a midpoint step leaves undetermined at its ends (phc.simulation.undetermined), on the
N = 1 four-bar, against its constraint Jacobian written out here.

The four-bar's configuration q = (θ₀, θ₁, x, y, φ) (two cranks of length 1 hinged at x = 0 and 1,
a coupler of length 1 with its centre at (x, y)) has the position constraints

    cos θ₀ − (x − ½ cos φ) = 0,   sin θ₀ − (y − ½ sin φ) = 0,
    x + ½ cos φ − (1 + cos θ₁) = 0,   y + ½ sin φ − sin θ₁ = 0,

whose gradients are the rows of G. The momenta conjugate to q take the constraint forces Gᵀλ, so
the directions the multipliers' impulses move the momenta span range(Gᵀ), and what a
least-squares fit by them leaves of a momentum vector is its part in ker G: the velocity of the
parallelogram motion (θ₀ = θ₁ = θ, the coupler translating), t = (1, 1, −sin θ, cos θ, 0). The
other branch's momentum a = (1, −1, 0, 0, −½) (the cranks turning opposite ways, the coupler
rotating) is in range(Gᵀ) at every parallelogram configuration but the horizontal ones:
a = Gᵀ(α, −½, α, −½) with α = −(1 + ½ cos θ)/sin θ, which grows without bound as θ → 0 — the
redundant multiplier of the rank drop. It is the alternating component the passage leaves.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc
from phc.simulation import parameter_vector
from phc.simulation.midpoint import constraint_rows
from phc.simulation.undetermined import force_directions, without

ROOT = Path(__file__).resolve().parents[2]
MOMENTA = ("crank0.p_w", "crank1.p_w", "coupler1.p_vx", "coupler1.p_vy", "coupler1.p_w")
CONFIGURATION = ("crank0.theta", "crank1.theta", "coupler1.x", "coupler1.y", "coupler1.phi")


@pytest.fixture(scope="module")
def four_bar():
    mod = phc.compile_model(ROOT / "models" / "n_four_bar.yaml", certify=False).module
    return mod, parameter_vector(mod)


def _state(mod, theta):
    """The parallelogram configuration at crank angle θ, some momenta, multipliers zero."""
    y = np.zeros(mod.N)
    names = list(mod.VARIABLES)
    for name, value in zip(CONFIGURATION, (theta, theta, 0.5 + np.cos(theta), np.sin(theta), 0.0)):
        y[names.index(name)] = value
    for name, value in zip(MOMENTA, (-1.6, -1.6, 0.3, -4.9, 0.0)):
        y[names.index(name)] = value
    return y


def _vector(mod, values):
    v = np.zeros(mod.N)
    names = list(mod.VARIABLES)
    for name, value in zip(MOMENTA, values):
        v[names.index(name)] = value
    return v


@pytest.mark.parametrize("theta", [0.7, 1e-3])
def test_the_constraint_forces_span_the_other_branch_momentum_and_leave_the_motion(four_bar, theta):
    """At a regular configuration (θ = 0.7) and next to the horizontal one (θ = 1e-3, where the
    redundant multiplier is 1.5e3 times the others and G's smallest singular value 1e-3 of its
    largest): the other branch's momentum a is fitted to round-off (relative 1e-9: the fit is a
    least-squares solve with G's conditioning, 1e3), the parallelogram velocity t is left whole
    (to 1e-9), and the configuration variables are in no direction (they are compared in full)."""
    mod, p = four_bar
    y = _state(mod, theta)
    found = force_directions(mod, p, 0.0, 1e-4, y, y, constraint_rows(mod))
    assert found is not None
    names = list(mod.VARIABLES)
    assert np.all(found[[names.index(n) for n in CONFIGURATION]] == 0.0)
    a = _vector(mod, (1.0, -1.0, 0.0, 0.0, -0.5))
    assert np.abs(without(a, found)).max() < 1e-9
    t = _vector(mod, (1.0, 1.0, -np.sin(theta), np.cos(theta), 0.0))
    assert np.abs(without(t, found) - t).max() < 1e-9


def test_at_the_horizontal_configuration_the_other_branch_is_free(four_bar):
    """At θ = 0 the rank drops: range(Gᵀ) loses a direction, and ker G(0) holds both branches'
    velocities, t = (1, 1, 0, 1, 0) and s = (1, −1, 0, 0, −2). The fit then leaves of a its part
    along s, (a·s/s·s) s = s/2, and t whole: the directions are the constraint forces at the state,
    not a fixed set (to 1e-12: G(0) is exact and well scaled on its range)."""
    mod, p = four_bar
    y = _state(mod, 0.0)
    found = force_directions(mod, p, 0.0, 1e-4, y, y, constraint_rows(mod))
    a = _vector(mod, (1.0, -1.0, 0.0, 0.0, -0.5))
    s = _vector(mod, (1.0, -1.0, 0.0, 0.0, -2.0))
    assert np.abs(without(a, found) - 0.5 * s).max() < 1e-12
    t = _vector(mod, (1.0, 1.0, 0.0, 1.0, 0.0))
    assert np.abs(without(t, found) - t).max() < 1e-12
