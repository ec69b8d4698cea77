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
c = 100 (λ ≈ −100) blows up at h = 0.0115 s and is fine at 0.01 and 0.0125 s. Guard:
a composite step whose net dissipated energy ``Σ γᵢh·P_diss(midpointᵢ)`` is negative
violates passivity and is rejected (the driver retries it in smaller pieces, which leaves
the band, and says so); it is never reported as a success silently.
"""

from __future__ import annotations

import numpy as np

from phc.simulation import step_logic
from phc.simulation.backend import BackendRun
from phc.simulation.scaling import run_energy
from phc.simulation.midpoint import (NEWTON_HINT, SINGULAR_HINT, StageSolver, Stages, integrate_fixed_step,
                                     newton_weights_of)

PASSIVITY_HINT = ("the step added energy through dissipation (the backward substep of the composition "
                  "outweighed the forward ones: a damped mode with h·|λ| near 1.17); change `step` by about "
                  "10 %, or use `midpoint`")
ACTIVE_HINT = ("the resistive ports supply power, which no passive law does and the composition's passivity guard "
               "rejects at every step size; a resistive law of the wrong sign, or a source written as a resistor, "
               "makes a model active (`phc check` reports PHC-E451) and can make its solution blow up: check the "
               "law's sign, or, for a model meant to be active, use `midpoint`, `discrete_gradient` or `ida`, which "
               "follow it and name a blow-up; the dissipated power is {power:.3g} (in the model's unit of power)")
"""What a step rejected by the passivity guard says where the dissipation itself supplies power at
the step's state (a blow-up model, docs/hard-cases.md), rather than a damped mode in the unstable
band (:data:`PASSIVITY_HINT`)."""
GAMMA1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
GAMMA2 = -(2.0 ** (1.0 / 3.0)) / (2.0 - 2.0 ** (1.0 / 3.0))
FRACTIONS = (GAMMA1, GAMMA2, GAMMA1)
"""Substep sizes as fractions of the step."""
MID_TIMES = (0.5 * GAMMA1, GAMMA1 + 0.5 * GAMMA2, 1.0 - 0.5 * GAMMA1)
"""Midpoints of the substeps as fractions of the step (0.676, 0.5, 0.324: inside the step)."""


def composition_constants(c):
    """`c`, the constants vector of :mod:`phc.simulation.step_logic`, with the composition's numbers."""
    c[step_logic._G1], c[step_logic._G2] = GAMMA1, GAMMA2
    c[step_logic._M0], c[step_logic._M1], c[step_logic._M2] = MID_TIMES
    return c


class Midpoint4Step:
    """One composite step ``advance(t, h, y, guess) -> (y1, ok, reason)``:
    :func:`phc.simulation.step_logic.midpoint4`, the code the compiled loop runs as well.

    Predictor: the midpoint value of each substep (where the algebraic variables of a
    midpoint rule are accurate; their end values oscillate) is extrapolated linearly in time
    from the same substep of the last two steps; the substep's end is guessed as
    ``2·m − y_start``. Without history, from the driver's guess of the step end."""

    def __init__(self, mod, p, scales=None):
        self.mod, self.p = mod, p
        w = newton_weights_of(scales, mod)
        self.stages = (StageSolver(mod, p, weights=w), StageSolver(mod, p, weights=w))  # γ₁h and γ₂h
        for stage in self.stages:
            # the least-norm retry of a substep starts from its failed iterate where that is at round-off
            # (StageSolver._closer_start), as in the `midpoint` and `discrete_gradient` runs; from the
            # constant predictor of a retried step the N = 10 four-bar at h = 1e-3 ended a passage step
            # 3.8e-7 rad off in crank 0, 0.46 of the step's change from its two half steps, and the
            # monitor stopped the run at t = 1.24 (docs/hard-cases.md)
            stage.restart_near = True
        self.workspace = Stages(*self.stages)
        self.stage = self  # for the driver's look at `ill_conditioned`
        self.ill_conditioned = False
        self.singular = False
        self.constants = composition_constants(self.stages[0].constants.copy())
        self.constants[step_logic._RUN_ENERGY] = run_energy(mod, scales)
        self.hist_t, self.hist_v = np.zeros((2, 3)), np.zeros((2, 3, mod.N))
        self.algmask = (~np.asarray(mod.DIFFERENTIAL, dtype=bool)).astype(np.int8)
        """The algebraic variables (1), as the driver's predictor takes them
        (:func:`phc.simulation.step_logic.midpoint4` starts them at the step's midpoint)."""
        self.nhist = 0
        """The substep midpoints (times ``hist_t[k]``, values ``hist_v[k]``) of the last ``nhist``
        steps (at most two)."""

    @property
    def evaluation_error(self):
        """The model evaluation that stopped the last substep, if any."""
        return next((s.evaluation_error for s in self.stages if s.evaluation_error is not None), None)

    @property
    def nfev(self):
        return sum(s.nfev for s in self.stages)

    @property
    def factorizations(self):
        return sum(s.matrix.factorizations for s in self.stages)

    def __call__(self, t, h, y, guess):
        out = np.array(guess, dtype=float)
        code, self.ill_conditioned, self.nhist = step_logic.midpoint4(
            self.mod.powers, self.mod.energy_scale, self.workspace, self.constants, t, h, y, guess, self.p, out,
            self.hist_t, self.hist_v, self.nhist, self.algmask)
        self.singular = code == step_logic._SINGULAR
        if code == step_logic._OK:
            return out, True, ""
        if code == step_logic._PASSIVITY:
            # passivity violated over the composite step: a damped mode in the band where the
            # backward substep's anti-dissipation wins (see the module docstring) — unless the
            # dissipation supplies power at the step's state itself: then the model is active
            supplied = self.supplied_power(t, h, y, out)
            if supplied is not None:
                return out, False, ACTIVE_HINT.format(power=supplied)
            return out, False, PASSIVITY_HINT
        return out, False, (SINGULAR_HINT if self.singular else NEWTON_HINT)

    def supplied_power(self, t, h, y, end):
        """The dissipation power at the step's mean state and slope (from `y` to the rejected step's
        `end`) where it is negative beyond round-off — power the resistive ports supply, which no
        passive law does at any state — else None."""
        if not np.all(np.isfinite(end)):
            end = y
        try:
            power = float(self.mod.powers(t + 0.5 * h, 0.5 * (y + end), (end - y) / h, self.p)[1])
            floor = step_logic.passivity_floor(abs(float(self.mod.energy_scale(t, y, self.p))),
                                               self.constants[step_logic._RUN_ENERGY])
        except (ArithmeticError, ValueError):
            return None
        return power if h * power < -floor else None


UNSTABLE_BAND = (1.10, 1.23)
"""h·|λ| range (with |Im λ| ≤ 0.1|λ|, Re λ < 0) treated as inside the composition's unstable disk."""
SPECTRUM_LIMIT = 400
"""Largest system whose linearized spectrum is checked at the start (dense eigenproblem)."""


def unstable_modes(mod, p, t0, y0, yp0, steps) -> list[tuple[float, complex]]:
    """(h, λ) pairs of damped modes of the linearization at the start for which a step h
    falls in the composition's unstable band: eigenvalues of ``F_y v = −λ F_ẏ v``."""
    import scipy.linalg as sla

    n = mod.N
    if n > SPECTRUM_LIMIT:
        return []
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    buf = np.zeros(len(rows))
    mod.jacobian(t0, y0, yp0, p, 0.0, buf)
    fy = np.zeros((n, n))
    np.add.at(fy, (rows, cols), buf)
    mod.jacobian(t0, y0, yp0, p, 1.0, buf)
    fyp = -fy
    np.add.at(fyp, (rows, cols), buf)
    with np.errstate(all="ignore"):
        lam = sla.eigvals(fy, -fyp)
    lam = lam[np.isfinite(lam)]
    hits = []
    for h in steps:
        for mu in lam:
            size = abs(mu)
            if mu.real < 0 and abs(mu.imag) <= 0.1 * size and UNSTABLE_BAND[0] <= h * size <= UNSTABLE_BAND[1]:
                hits.append((h, complex(mu)))
    return hits


def integrate_midpoint4(mod, p, t_out, y0, yp0, options, *, progress=None, names=None, events=None,
                        nominal=None) -> BackendRun:
    """Fixed-step fourth-order composition of the implicit midpoint rule from ``t_out[0]``;
    output at every ``t_out`` (each output interval is split into equal steps no longer than
    ``options.step``; a fixed-step method's accuracy is set by `step` alone). A step that puts
    a damped mode of the linearization at the start into the method's unstable band is
    refused before the run."""
    step, max_steps = options.step, options.max_steps
    intervals = np.diff(np.asarray(t_out, dtype=float))
    steps = sorted({float(d / step_logic.substeps(d, step or 0.0)) for d in intervals})
    hits = unstable_modes(mod, p, float(t_out[0]), y0, yp0, steps)
    if hits:
        h, mu = hits[0]
        return BackendRun.from_mapping(dict(
                    t=np.asarray(t_out[:1], dtype=float), y=np.atleast_2d(y0), yp=np.atleast_2d(yp0), steps=0,
                    nfev=0, njev=0, success=False, cpu=0.0,
                    message=(f"midpoint4: step h = {h:.4g} puts a damped mode (λ = {mu.real:.4g}"
                             f"{mu.imag:+.2g}j) at h·|λ| = {h * abs(mu):.3f}, inside the composition's unstable band "
                             f"{UNSTABLE_BAND[0]}–{UNSTABLE_BAND[1]}: its backward substep would amplify it; change "
                             "`step` (e.g. by 20 %) or use `midpoint`")))
    # the whole step loop compiled, when the model runs on the numba or the C backend (with events: numba)
    from phc.simulation import compiled_steps

    out = compiled_steps.integrate("midpoint4", mod, p, t_out, y0, yp0, max_steps=max_steps, progress=progress,
                                   step=step, name="midpoint composition (order 4)", names=names,
                                   python_advance=lambda: Midpoint4Step(mod, p, nominal),
                                   weights=newton_weights_of(nominal, mod), scales=nominal, events=events)
    if out is not None:
        return out
    advance = Midpoint4Step(mod, p, nominal)
    out = integrate_fixed_step(mod, p, t_out, y0, yp0, max_steps=max_steps, progress=progress, step=step,
                               advance=advance, name="midpoint composition (order 4)", names=names, events=events,
                               scales=nominal)
    return out.replace(nfev=advance.nfev, njev=advance.factorizations)
