"""Discrete-gradient step for pH-DAEs with non-quadratic Hamiltonians (energy exact).

The implicit midpoint rule (:mod:`phc.simulation.midpoint`) conserves the discrete energy
balance only for quadratic H, because only then ``H(y_{n+1}) − H(y_n) = ∇H(y_mid)·Δy``. A
discrete gradient ``∇̄H(y_n, y_{n+1})`` is any vector with
``∇̄H·(y_{n+1} − y_n) = H(y_{n+1}) − H(y_n)`` and ``∇̄H(y, y) = ∇H(y)`` (Gonzalez 1996;
McLachlan, Quispel & Robidoux 1999); replacing the efforts ``e = ∇H(x)`` of the storage
relation (the paper's Section 2, storage port ``(x, e_L)``) by it, with the Dirac structure
evaluated at one common point, makes the balance of the paper's Remark 3 "Energy balance"
hold exactly for any step size.

Which discrete gradient
-----------------------
The generated residual fuses the constitutive relations ``e = ∇H(x)`` with the Dirac
structure (modulations ``J(x)``, constraint gradients, transforms): the efforts cannot be
replaced without also moving the point where the structure is evaluated. Two classical
choices fail here: the average vector field ``∫₀¹ ∇H(y(σ)) dσ`` applied as an average of
the *residual* averages ``J(y(σ)) ∇H(y(σ))``, which is not energy-exact once J depends on
the state (and is exact only up to the quadrature error); the Gonzalez correction
``∇H(y_mid) + c·Δy`` needs the efforts as separate outputs. We use the **mean-value
discrete gradient** ``∇̄H = ∇H(y(s*))`` with ``y(s) = y_n + s (y_{n+1} − y_n)``: by the
mean-value theorem there is an ``s* ∈ (0, 1)`` with ``∇H(y(s*))·Δy = H(y_{n+1}) − H(y_n)``.
Every row of F is evaluated at the one point ``(t_n + s* h, y(s*))`` with the flows
``Δy/h``, so power-isotropy of the Dirac structure there (the paper's Definition 1; modulated,
Proposition 5, or constrained, eq. (4)) gives exactly ``∇H(y(s*))·Δy = −h (P_ports + P_diss)(y(s*))`` — and the
energy accumulator ``energy.supplied`` of the DAE integrates the same power. Hence the
step solves the n equations of F together with one scalar equation for ``s``,

    r(s) = H(y_{n+1}) − H(y_n) + E_{n+1} − E_n = 0,

the discrete energy balance itself (E = ``energy.supplied``). We solve it by a safeguarded
secant iteration on ``s`` around the inner (simplified Newton) solve of F, starting at
``s = 1/2``: for quadratic H, ``r(1/2) = 0`` and the step *is* the implicit midpoint rule.
Otherwise, with the segment held at its ``s = 1/2`` value, ``u = s − 1/2`` and the
derivatives of φ(σ) = H(y(σ)) at ``σ = 1/2`` (φ'' = O(h²), φ''' = O(h³)), the cubic model
of φ gives ``r(s) ≈ φ'''/24 − φ''·u − φ'''·u²/2`` (the stage's own dependence on s gives the
same slope ``r' ≈ −φ''`` to leading order). The roots of this quadratic have the product
−1/12: one always lies within ``1/√12 ≈ 0.29`` of the middle, so for a short step a
balancing point is expected — ``s* = 1/2 + O(h)`` where the energy along the step is not
near an inflection (φ'' not small), up to ``1/2 ± 0.29`` where it is (that step is then
only first order). Choosing the root nearest ``1/2`` makes the method symmetric, so it is
of order 2 like the midpoint rule.

The energy at the step's ends
-----------------------------
H is the energy of the *states*. A rigid body with a configuration-dependent mass matrix
writes it as ``H = ½pᵀv + V(q)`` in its velocities v, unknowns of the rows ``M(q) v = p``
(:mod:`phc.library.rigid`), and the stage imposes those rows at ``y(s)``, where the effort
``v(s) = M(q(s))⁻¹p(s) = ∂H/∂p`` is wanted — not at the step's end, whose velocities are the
extrapolation ``v_n + (v(s) − v_n)/s`` and are not ``M(q₁)⁻¹p₁``. ``H(y₁)`` at those
velocities is not the energy of the states: balancing it kept a wrong function constant
(a cart–pole's energy drifted by 2.6e-3 at h = 0.01, seen in the outputs, whose velocities
are recomputed from the states) and, the extrapolation's error changing by ``−(1 − s)/s``
a step, made it unbalanceable (the run stopped at t ≈ 0.74 at every step size). So the
velocities of both ends are made consistent (:class:`EndVelocities`: one Newton correction
of the rows ``M(q) v = p`` at fixed states, exact for rows linear in v) before H is taken,
and the step ends with them. The states' step is unchanged (the stage determines ``v(s)``
whatever ``v_n`` is). The compiled loops (numba, C) do not do this: a model with such rows
runs the discrete gradient in the Python loop (:func:`phc.simulation.compiled_steps.integrate`).

Position constraints are imposed at the step ends as in the midpoint rule, by the
stabilizing multipliers η of the GGL formulation (``q̇ = … + G(q)ᵀη``). Without them the
mean-value theorem gives every *fixed* segment its balancing point; the segment moving
with s, the coupled problem has one for short steps (the cubic model above), not for
every step size; when φ is affine the balance holds at any s and ``r ≡ 0``. The
projection onto the constraints does work, though, ``h ∂H/∂q · G(q)ᵀη`` at the point y(s),
which is not a port power: zero on exact solutions, where η = 0, but not on the step. Where
it is as large as the variation of the mean-value mismatch along the segment, no s
balances the energy: r(s) stays on one side of 0. (Andrews' squeezing mechanism, whose
links turn at 10³ rad/s, was taken for such a case; its steps without a balancing point
came from the end velocities above, and it now balances every step.) Such a step is split like a step
whose Newton iteration fails (the work shrinks faster than the mismatch's variation on
shorter steps); where even the shortest split step has no balancing point, that step is
taken as the implicit-midpoint step (s = 1/2, second order and symmetric), counted, and
reported with the run (``unbalanced``); the run's energy-balance error shows what those
steps cost. A model without constraints has no such work: there a step without a
balancing point (after the splits) ends the run with a message, as before.
"""

from __future__ import annotations

import numpy as np

from phc.simulation import step_logic
from phc.simulation.backend import BackendRun
from phc.simulation.scaling import run_energy
from phc.simulation.midpoint import (NEWTON_HINT, SINGULAR_HINT, StageSolver, Stages, integrate_fixed_step,
                                     newton_weights_of)

BALANCE_TOL = 2e-15
"""The step's energy residual |r| is driven below this times the energy scale."""
MAX_SECANT = 12
S_MIN, S_MAX = 0.02, 0.98
"""The evaluation point s stays inside the segment."""


def secant_constants(c):
    """`c`, the constants vector of :mod:`phc.simulation.step_logic`, with the secant iteration's numbers."""
    c[step_logic._BAL_TOL], c[step_logic._MAX_SECANT] = BALANCE_TOL, MAX_SECANT
    c[step_logic._S_MIN], c[step_logic._S_MAX] = S_MIN, S_MAX
    return c


MOMENTUM_DEFINITION = ".momentum_definition["
"""The rows ``M(q) v = p`` of a rigid body with a configuration-dependent mass matrix
(:mod:`phc.library.rigid`), by their equation names."""


def velocity_rows(mod) -> tuple[np.ndarray, np.ndarray]:
    """The rows ``M(q) v = p`` (:data:`MOMENTUM_DEFINITION`) and the algebraic unknowns they
    determine (the velocities v, which the stored energy ``H = ½pᵀv + V`` is written in), or two
    empty arrays where there are none or they do not pair up (square)."""
    rows = np.array([i for i, name in enumerate(mod.EQUATIONS) if MOMENTUM_DEFINITION in str(name)], dtype=np.int64)
    if not len(rows):
        return rows, rows
    jr, jc = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    algebraic = ~np.asarray(mod.DIFFERENTIAL, dtype=bool)
    cols = np.unique(jc[np.isin(jr, rows) & algebraic[jc]]).astype(np.int64)
    if len(cols) != len(rows):
        return rows[:0], rows[:0]
    return rows, cols


class EndVelocities:
    """Makes the velocities of a step's end consistent with its states (module docstring,
    "The energy at the step's ends"): one Newton correction of the unknowns v of the rows
    ``M(q) v − p = 0`` at fixed ``(q, p)`` — exact up to round-off, the rows being linear in v."""

    def __init__(self, mod, p):
        self.mod, self.p = mod, p
        self.rows, self.cols = velocity_rows(mod)
        n = mod.N
        jr, jc = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
        row_at = {int(r): k for k, r in enumerate(self.rows)}
        col_at = {int(c): k for k, c in enumerate(self.cols)}
        self.entries = np.array([k for k, (r, c) in enumerate(zip(jr, jc)) if int(r) in row_at and int(c) in col_at],
                                dtype=np.int64)
        self.at = (np.array([row_at[int(jr[k])] for k in self.entries], dtype=np.int64),
                   np.array([col_at[int(jc[k])] for k in self.entries], dtype=np.int64))
        self.res, self.jac, self.zero = np.zeros(n), np.zeros(len(jr)), np.zeros(n)
        self.corrections = 0

    def __bool__(self):
        return bool(len(self.rows))

    def __call__(self, t, y):
        """``y``'s velocities in place: ``v ← v − (∂F_R/∂v)⁻¹ F_R(t, y)`` (the rows R do not
        depend on ẏ: they are evaluated with ẏ = 0, the Jacobian with c_j = 0)."""
        if not len(self.rows):
            return
        self.mod.residual(t, y, self.zero, self.p, self.res)
        self.mod.jacobian(t, y, self.zero, self.p, 0.0, self.jac)
        a = np.zeros((len(self.rows), len(self.cols)))
        np.add.at(a, self.at, self.jac[self.entries])
        try:
            dv = np.linalg.solve(a, self.res[self.rows])
        except np.linalg.LinAlgError:
            return  # a singular mass matrix: the stage solve reports it
        if np.all(np.isfinite(dv)):
            y[self.cols] -= dv
            self.corrections += 1


class _Workspace(Stages):
    """:class:`~phc.simulation.midpoint.Stages` with the operation ``consistent`` of
    :func:`phc.simulation.step_logic.discrete_gradient` (:class:`EndVelocities`)."""

    def __init__(self, stage, velocities):
        super().__init__(stage)
        self.velocities = velocities

    def consistent(self, t, y):
        self.velocities(t, y)


class DiscreteGradientStep:
    """One step: the stage equations F at ``y(s)`` plus the energy balance ``r(s) = 0``."""

    def __init__(self, mod, p, scales=None):
        self.mod, self.p = mod, p
        self.stage = StageSolver(mod, p, weights=newton_weights_of(scales, mod))
        self.stage.restart_near = True  # the least-norm retry's start (StageSolver._closer_start)
        self.e = list(mod.VARIABLES).index("energy.supplied")
        self.secant_iterations = 0
        self.unbalanced = 0
        """Steps where no s balanced the energy: taken as implicit-midpoint steps (module docstring)."""
        self._midpoint = None
        self.projects = any(str(v).startswith("ggl.") for v in mod.VARIABLES)
        """The model has GGL multipliers, whose projection may do work (module docstring)."""
        self.constants = secant_constants(self.stage.constants.copy())
        self.constants[step_logic._RUN_ENERGY] = run_energy(mod, scales)
        self.velocities = EndVelocities(mod, p)
        self.workspace = _Workspace(self.stage, self.velocities)

    def __call__(self, t, h, y, guess):
        """One step (:func:`phc.simulation.step_logic.discrete_gradient`, the code the compiled loop
        runs as well): ``(y1, ok, reason)``."""
        self._midpoint = None
        out = np.array(guess, dtype=float)
        code, _, y1, best, scale, y_half, secants = step_logic.discrete_gradient(
            self.mod.hamiltonian, self.mod.energy_scale, self.workspace, self.constants, self.e, t, h, y, guess, self.p,
            out)
        self.secant_iterations += secants
        if code == step_logic._OK:
            return y1, True, ""
        if not secants:  # the implicit-midpoint stage itself failed
            if code == step_logic._EVAL and self.stage.evaluation_error is None:
                return y1, False, "the energy could not be evaluated at the step's end"
            return y1, False, SINGULAR_HINT if self.stage.singular else NEWTON_HINT
        # no point balances the energy (the constraint projection's work, module docstring): the
        # driver splits the step; where the shortest split step fails too, `fallback` takes its
        # implicit-midpoint step
        self._midpoint = y_half
        return y1, False, (f"no point along the step balances the energy (|r| = {best:.1e}, "
                           f"energy scale {scale:.1e}): the mean-value discrete gradient has no solution "
                           "on this step; for a short `step` one is expected within 0.29 of the step's "
                           "middle where H is smooth along it, or use `midpoint4`/`midpoint` (energy exact "
                           "for quadratic H) or `ida`")

    def fallback(self):
        """The implicit-midpoint step of the last call if it failed only to balance the energy
        (counted in ``unbalanced``), else None."""
        y_half, self._midpoint = self._midpoint, None
        if y_half is None or not self.projects:  # without constraints, no work explains it: a failure
            return None
        self.unbalanced += 1
        return y_half


def integrate_discrete_gradient(mod, p, t_out, y0, yp0, options, *, progress=None, names=None, events=None,
                                nominal=None) -> BackendRun:
    """Fixed-step discrete-gradient integration from ``t_out[0]``; output at every ``t_out``
    (each output interval is split into equal steps no longer than ``options.step``; a
    fixed-step method's accuracy is set by `step` alone)."""
    step, max_steps = options.step, options.max_steps
    # the whole step loop compiled, when the model runs on the numba or the C backend (with events: numba)
    from phc.simulation import compiled_steps

    out = compiled_steps.integrate("discrete_gradient", mod, p, t_out, y0, yp0, max_steps=max_steps,
                                   progress=progress, step=step, name="discrete gradient", names=names,
                                   python_advance=lambda: DiscreteGradientStep(mod, p, nominal),
                                   weights=newton_weights_of(nominal, mod), scales=nominal, events=events)
    if out is not None:
        return _report_unbalanced(out)
    advance = DiscreteGradientStep(mod, p, nominal)
    out = integrate_fixed_step(mod, p, t_out, y0, yp0, max_steps=max_steps, progress=progress, step=step,
                               advance=advance, name="discrete gradient", names=names, events=events,
                               scales=nominal)
    out = out.replace(nfev=advance.stage.nfev, njev=advance.stage.matrix.factorizations,
                      unbalanced=advance.unbalanced)
    return _report_unbalanced(out)


def _report_unbalanced(out: BackendRun) -> BackendRun:
    """The run's message says how many steps found no balancing point (module docstring)."""
    k = int(out.extra.get("unbalanced", 0))
    if not k:
        return out
    return out.replace(message=(f"{out.message}; {k} of the split steps' sub-steps found no point that balances "
                                "the energy exactly (the constraint projection of the GGL formulation did work "
                                "there: fast motion along curved constraints) and were taken as implicit-midpoint "
                                "steps: the energy balance holds to the error reported, not to round-off"))
