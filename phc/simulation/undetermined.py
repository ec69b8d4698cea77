"""What a midpoint step leaves undetermined at the step ends: the momenta along the constraint forces.

A midpoint-type step (``midpoint``, each substep of ``midpoint4``) evaluates every row of the DAE
inside the step; the velocity constraints hold there, for the mean of the momenta at the two
ends, and the constraint forces (the multipliers' impulses) act there. At the step ends the
momenta along the constraint forces are therefore free to alternate: ``p_n = p̃_n + (−1)ⁿ a`` with
``a`` along the constraint forces leaves every step's mean, and so the configuration, the velocity
constraints and the motion, as they are, carried by a multiplier alternating about its midpoint
value. A rank drop of the position constraints excites it (the redundant multiplier's impulse is not determined at the singular
configuration): at the N four-bar's first horizontal pass, ``midpoint4`` at h = 1e-4 left
``a`` = 2.1e-4 kg m²/s along (1, −1, −1/2) in (crank 0's, crank 1's, the coupler's angular
momentum) — the momentum of the other branch of the motion, (1, −1, −2) in (θ₀, θ₁, φ), a
constraint force at every configuration of the parallelogram branch but the horizontal ones —
and it stays for the rest of the run, the same size whatever the step. One step (three
substeps) flips its sign and two half steps (six) do not, so their comparison sees ``2a``: 0.16
to 0.45 of the step's change at h = 1e-4, and more at smaller steps, whose change is smaller
(docs/hard-cases.md).

:func:`force_directions` gives, in the differential variables, the directions the multipliers'
impulses move: ``E⁻¹ F_z`` for the multipliers z (the algebraic variables the algebraic rows do
not determine, :func:`phc.simulation.tested.determined_algebraic`: the connections' efforts and
the GGL multipliers, which only the constraints' derivatives determine), ``E = ∂F/∂ẏ`` on the
differential rows and columns, at the step's midpoint. The configuration variables (those the
position constraints depend on) are left out of them: the configuration is compared in full. The
directions are the constraint forces at the step, the weak one next to a rank drop included (no
singular value is dropped from the fit).

Reference for redundant and singular constraints: J. García de Jalón, E. Bayo, "Kinematic and
Dynamic Simulation of Multibody Systems", Springer 1994.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from phc.simulation.tested import determined_algebraic

DENSE_LIMIT = 2000
"""Largest number of differential variables for which the directions are computed (a dense
least-squares solve); above it there are none (the comparison is made on every variable)."""


def force_directions(mod, p, t, h, y, y_new, end_rows) -> Optional[np.ndarray]:
    """The directions (columns, n rows, zero outside the differential variables that are not
    configuration variables) along which the multipliers' impulses move the momenta in the step
    ``(t, y) → (t + h, y_new)`` (`end_rows`: the rows of F that are position constraints); None
    where the model has no multipliers, or too many differential variables (:data:`DENSE_LIMIT`)."""
    n = mod.N
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    if int(diff.sum()) > DENSE_LIMIT:
        return None
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    # at the step's midpoint, the algebraic variables at zero: the multipliers enter the rows
    # linearly, and their values at the step ends carry the alternation (±9e8 N at the four-bar's
    # first passage)
    mid = np.where(diff, 0.5 * (y + y_new), 0.0)
    yp = (y_new - y) / h
    f_y, both = np.zeros(len(rows)), np.zeros(len(rows))
    try:
        mod.jacobian(t + 0.5 * h, mid, yp, p, 0.0, f_y)
        mod.jacobian(t + 0.5 * h, mid, yp, p, 1.0, both)
    except (ArithmeticError, ValueError):
        return None
    f_yp = both - f_y
    if not (np.all(np.isfinite(f_y)) and np.all(np.isfinite(f_yp))):
        return None
    differential_rows = np.zeros(n, dtype=bool)
    differential_rows[rows[f_yp != 0]] = True
    multipliers = np.flatnonzero(~diff & ~determined_algebraic(mod, p, t + 0.5 * h, mid, yp))
    if not len(multipliers):
        return None
    d_rows, d_cols = np.flatnonzero(differential_rows), np.flatnonzero(diff)
    E = np.zeros((n, n))
    np.add.at(E, (rows, cols), f_yp)
    Fy = np.zeros((n, n))
    np.add.at(Fy, (rows, cols), f_y)
    try:
        moved, *_ = np.linalg.lstsq(E[np.ix_(d_rows, d_cols)], Fy[np.ix_(d_rows, multipliers)], rcond=None)
    except np.linalg.LinAlgError:
        return None
    directions = np.zeros((n, len(multipliers)))
    directions[d_cols] = moved
    configuration = np.zeros(n, dtype=bool)
    configuration[cols[np.isin(rows, np.asarray(end_rows, dtype=int))]] = True
    directions[configuration] = 0.0
    keep = np.abs(directions).max(axis=0) > 0
    return directions[:, keep] if keep.any() and np.all(np.isfinite(directions)) else None


def without(v, directions) -> np.ndarray:
    """`v` less its least-squares fit by the columns of `directions` (:func:`force_directions`)."""
    coef, *_ = np.linalg.lstsq(directions, v, rcond=None)
    return v - directions @ coef
