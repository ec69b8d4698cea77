"""Fourth-order composition of the implicit midpoint rule (structure preserving).

One step of size h is three implicit-midpoint substeps of sizes ``γ₁h, γ₂h, γ₁h`` with
``γ₁ = 1/(2 − 2^{1/3})`` and ``γ₂ = −2^{1/3}/(2 − 2^{1/3})`` (the symmetric "triple jump"
of Yoshida 1990 and Suzuki 1990; ``2γ₁ + γ₂ = 1``, ``2γ₁³ + γ₂³ = 0``): the midpoint rule
is symmetric of order 2, so the composition is symmetric of order 4. The middle substep
runs backwards in time (``γ₂ < 0``).

Every substep is one step of :class:`~phc.simulation.midpoint.StageSolver` — every row of
the DAE at the substep's midpoint, the position constraints at its end — so what the
midpoint rule guarantees holds substep by substep and hence for the composite step: the
discrete energy balance is exact for quadratic H (the energy accumulator is integrated by
the same substeps), and position constraints do not drift.

Linear algebra: two :class:`StageSolver` s, one per distinct substep size (``γ₁h`` for the
first and the third substep, ``γ₂h`` for the middle one), each keeping its own cached LU
factorization — nothing is refactorized merely because the substep size alternates.

Stability and dissipation: the midpoint rule's stability function
``R(z) = (1 + z/2)/(1 − z/2)`` has ``|R| = 1`` on the imaginary axis for either sign of
the step, so undamped stiff modes (a flexible rod's, a fine beam's) stay bounded at any
step. The backward substep reverses dissipation, though: its balance reads
``H(y₂) − H(y₁) = γ₂h·P_diss ≥ 0``, so the composite step satisfies the energy *balance*
exactly but not the dissipation *inequality* ``H(y_{n+1}) ≤ H(y_n)`` (without supplied
power) — passivity is not guaranteed step by step. ``R(γ₁z)² R(γ₂z)`` has a pole at
``z = 2/γ₂ ≈ −1.17`` and ``|R| > 1`` only in a small disk around it (``−1.20 … −1.13`` on the
real axis, ``|Im z| ≲ 0.03``), elsewhere in the left half-plane ``|R| ≤ 1``: a nearly real
(overdamped) mode with ``h·|λ|`` in that band grows. Example: the mass–spring–damper with
c = 100 (λ ≈ −100) blows up at h = 0.0115 s and is fine at 0.01 and 0.0125 s.
"""

from __future__ import annotations

import numpy as np

from phc.simulation.midpoint import NEWTON_HINT, SINGULAR_HINT, StageSolver, integrate_fixed_step

GAMMA1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
GAMMA2 = -(2.0 ** (1.0 / 3.0)) / (2.0 - 2.0 ** (1.0 / 3.0))
FRACTIONS = (GAMMA1, GAMMA2, GAMMA1)
"""Substep sizes as fractions of the step."""
MID_TIMES = (0.5 * GAMMA1, GAMMA1 + 0.5 * GAMMA2, 1.0 - 0.5 * GAMMA1)
"""Midpoints of the substeps as fractions of the step (0.676, 0.5, 0.324: inside the step)."""


class Midpoint4Step:
    """One composite step ``advance(t, h, y, guess) -> (y1, ok, reason)``.

    Predictor: the midpoint value of each substep (where the algebraic variables of a
    midpoint rule are accurate; their end values oscillate) is extrapolated linearly in time
    from the same substep of the last two steps; the substep's end is guessed as
    ``2·m − y_start``. Without history, from the driver's guess of the step end."""

    def __init__(self, mod, p):
        self.stages = (StageSolver(mod, p), StageSolver(mod, p))  # γ₁h and γ₂h
        self.stage = self  # for the driver's look at `ill_conditioned`
        self.ill_conditioned = False
        self.singular = False
        self.history = []  # [(times of the substep midpoints, their values)], at most two

    @property
    def nfev(self):
        return sum(s.nfev for s in self.stages)

    @property
    def factorizations(self):
        return sum(s.matrix.factorizations for s in self.stages)

    def _predict(self, t, h, y, guess):
        times = [t + c * h for c in MID_TIMES]
        if len(self.history) == 2:
            (t0, m0), (t1, m1) = self.history
            return [m1[i] + (times[i] - t1[i]) * (m1[i] - m0[i]) / (t1[i] - t0[i]) for i in range(3)]
        slope = (guess - y) / h
        return [y + c * h * slope for c in MID_TIMES]

    def __call__(self, t, h, y, guess):
        mids = self._predict(t, h, y, guess)
        self.ill_conditioned = self.singular = False
        start, tau = y, t
        values = []
        for i, fraction in enumerate(FRACTIONS):
            stage = self.stages[0 if i != 1 else 1]
            hs = fraction * h
            y1, ok = stage.solve(tau, hs, start, 2.0 * mids[i] - start, 0.5)
            self.ill_conditioned |= stage.ill_conditioned
            if not ok:
                self.singular = stage.singular
                self.history.clear()
                return y1, False, (SINGULAR_HINT if stage.singular else NEWTON_HINT)
            values.append(0.5 * (start + y1))
            start, tau = y1, tau + hs
        self.history = (self.history + [([t + c * h for c in MID_TIMES], values)])[-2:]
        return start, True, ""


def integrate_midpoint4(mod, p, t_out, y0, yp0, *, rtol, atol, max_steps, progress=None, max_order=None,
                        step=None, names=None):
    """Fixed-step fourth-order composition of the implicit midpoint rule from ``t_out[0]``;
    output at every ``t_out`` (each output interval is split into equal steps no longer than
    `step`). Returns the same dict as the IDA backend."""
    del rtol, atol, max_order  # a fixed-step method: accuracy is set by `step`
    advance = Midpoint4Step(mod, p)
    out = integrate_fixed_step(mod, p, t_out, y0, yp0, max_steps=max_steps, progress=progress, step=step,
                               advance=advance, name="midpoint composition (order 4)", names=names)
    out.update(nfev=advance.nfev, njev=advance.factorizations)
    return out
