"""Algebraic variables at the output times, recomputed from the differential states.

IDA controls the error of the differential variables only: the algebraic ones of phc's
index-2 formulation (constraint forces, the torque a flow source applies, the efforts at
junctions) are left out of its error test — with them in it, BDF cuts its step without end
(measured: the rigid slider–crank at ``rtol = 1e-6`` took 112 774 steps instead of 297 and
ended 67 % off; the pendulum and the double pendulum failed). What IDA returns for them at
an output time is the value of its interpolating polynomial, and their error is of the
order of the differential variables' error *divided by the step*: at ``rtol = 1e-6`` the
drive torque of ``models/rigid_slider_crank.yaml`` was 1.5 % off and the clamp force of
``models/euler_bernoulli_beam.yaml`` 71 %, while the positions were right to 1e-6.

Given the differential states at an output time (accurate to the tolerance), the algebraic
variables and the derivatives follow from the equations and their hidden constraints —
the system consistent initialization solves (:mod:`phc.simulation.initial`): ``F = 0`` and
the time derivative of the rows that carry information, with the states held. This module
solves it at every output time, starting from IDA's values: a chord iteration on the
weighted minimum-norm (least-squares) step, with the pseudo-inverse of the scaled Jacobian
computed once and refreshed when a step no longer reduces the residual
(:class:`phc.simulation.chord.ChordIteration`). Errors after it, same runs: 2.4e-6
and 5.9e-6. The states themselves are never moved; a point where the iteration does not
reduce the residual keeps IDA's values.
"""

from __future__ import annotations

import copy
from typing import Optional

import numpy as np

from phc.simulation.backend import BackendRun
from phc.simulation.chord import ChordIteration
from phc.simulation.guard import CATCH, ModelEvaluationError

DENSE_ENTRIES = 400_000
"""Largest (rows × unknowns) of the system solved densely; larger models keep IDA's values."""
PINV_RTOL = 1e-13
"""Singular values below this fraction of the largest are dropped from the pseudo-inverse
(a stiff beam's scaled Jacobian is ill-conditioned: what is smaller is round-off amplified)."""
CHORD_STEPS = 12
"""Most chord steps at one output time."""
ROUND_OFF = 1e-13
"""Residual (of the equilibrated rows, per row) at which the system counts as solved."""
STEP_ROUND_OFF = 1e-12
"""A chord correction below this fraction of the unknowns' scales (or sizes) is round-off:
the iteration stops there, without refreshing the pseudo-inverse for a step that cannot
reduce a residual already at round-off."""
SAME_MATRIX = 1e-14
"""A refresh whose scaled Jacobian differs from the last one by less than this fraction of
its largest entry keeps the pseudo-inverse (no SVD)."""
CONTRACTION = 0.5
"""A step that shrinks the residual by less than this factor refreshes the pseudo-inverse
(once per output time)."""


def depends_on_algebraic(mod, p, t, y, yp, scales) -> bool:
    """True when an output of `mod` changes with its algebraic variables or with ẏ (the
    quantities IDA does not control) at (t, y, ẏ)."""
    if not len(getattr(mod, "OUTPUTS", ())):
        return False
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    names = list(mod.VARIABLES)
    alg = [j for j in np.flatnonzero(~diff) if not str(names[j]).startswith("ggl.")]
    try:
        base = np.asarray(mod.outputs(t, y, yp, p), dtype=float)
        y1 = y.copy()
        if alg:
            y1[alg] += 1e-3 * (np.abs(y1[alg]) + scales[alg])
        yp1 = yp + 1e-3 * (np.abs(yp) + scales)
        moved = np.asarray(mod.outputs(t, y1, yp1, p), dtype=float)
    except (ModelEvaluationError, *CATCH):
        return False
    return bool(np.any(moved != base))


class AlgebraicPolish:
    """Recomputes the algebraic variables and ẏ at held differential states (module docstring)."""

    def __init__(self, mod, p, t, y, scales):
        from phc.simulation.initial import _Problem

        dif = set(np.flatnonzero(np.asarray(mod.DIFFERENTIAL, dtype=bool)).tolist())
        self.base = _Problem(mod, p, t, np.asarray(y, dtype=float).copy(), dif, initial_relations=False,
                             scales=np.asarray(scales, dtype=float))
        self.base._prepare()
        rows, cols = self.base._shape
        self.usable = rows * cols <= DENSE_ENTRIES and cols > 0
        self.chord = ChordIteration(rtol=PINV_RTOL, same_matrix=SAME_MATRIX)
        self.active = None
        self.improved = 0

    @property
    def refreshes(self) -> int:
        """Pseudo-inverses computed so far."""
        return self.chord.refreshes

    def _jacobian(self, prob, u):
        """The scaled Jacobian of the active rows at u."""
        J = prob.jacobian(u).toarray() * prob.weights[None, :]
        if not np.all(np.isfinite(J)):
            return J  # refused by the chord iteration
        if self.active is None:
            # rows without unknowns (a position constraint of the held states) keep the
            # residual the states leave: left out, the system is consistent and its residual
            # goes to round-off
            self.active = np.flatnonzero(np.abs(J).max(axis=1) > 0)
        return J[self.active]

    def __call__(self, t, y, yp) -> tuple[np.ndarray, np.ndarray, bool]:
        """(y, ẏ) with the algebraic variables and ẏ recomputed at time t, and whether they
        changed (False: IDA's values kept)."""
        if not self.usable:
            return y, yp, False
        prob = copy.copy(self.base)
        prob.t0, prob.y, prob.yp = float(t), np.asarray(y, dtype=float).copy(), np.asarray(yp, dtype=float).copy()
        prob.z, prob.w = np.zeros(len(y)), np.zeros(len(y))

        def jacobian(u, g):
            return self._jacobian(prob, u)

        def negligible(u, step):  # in units of the unknowns' scales
            return float(np.abs(step).max()) <= STEP_ROUND_OFF * max(1.0, float(np.abs(u / prob.weights).max()))

        try:
            u = prob.pack()
            if self.chord.pinv is None and not self.chord.refresh(jacobian, u):
                return y, yp, False
            rows = len(self.active)
            out = self.chord.solve(u, lambda u: prob.G(u)[self.active], jacobian, steps=CHORD_STEPS,
                                   contraction=CONTRACTION, weights=prob.weights, negligible=negligible,
                                   # the rows are equilibrated: this is round-off
                                   converged=lambda u, size: size <= ROUND_OFF * np.sqrt(rows))
        except (ModelEvaluationError, *CATCH, np.linalg.LinAlgError):
            return y, yp, False
        if not out.size < out.start:
            return y, yp, False
        y1, yp1, _, _ = prob.unpack(out.x)
        self.improved += 1
        return y1, yp1, True


def polish_outputs(mod, p, out: BackendRun, scales, t_from: Optional[float] = None) -> BackendRun:
    """`out` (an integrator's arrays) with the algebraic variables and ẏ recomputed at every
    output time, when an output depends on them; unchanged otherwise or when the model is
    too large for the dense solve (:data:`DENSE_ENTRIES`)."""
    t, y, yp = out.t, out.y, out.yp
    if not len(t) or np.all(np.asarray(mod.DIFFERENTIAL, dtype=bool)):
        return out
    if len(mod.EQUATIONS) * mod.N > DENSE_ENTRIES:
        # the system has at least as many rows as equations and a column per unknown (the
        # algebraic variables and the rates): too large for the dense solve, known before
        # the problem's index arrays are built (at 8·10⁵ unknowns they took more memory
        # than the ten midpoint steps they followed, issue 35)
        return out
    if not depends_on_algebraic(mod, p, t[0], y[0], yp[0], np.asarray(scales, dtype=float)):
        return out
    # a switched run's modes at each output time (phc.simulation.events): the rows of a sticking
    # friction law or a closed contact are those of its mode
    modes = out.extra.get("modes")
    modes = None if modes is None or len(modes) != len(t) else np.asarray(modes, dtype=float)
    polishers: dict = {}

    def polisher(k):
        pk = p if modes is None else modes[k]
        key = np.asarray(pk, dtype=float).tobytes()
        if key not in polishers:
            try:
                polishers[key] = AlgebraicPolish(mod, pk, t[k], y[k], scales)
            except (ModelEvaluationError, *CATCH, np.linalg.LinAlgError):
                polishers[key] = None
        return polishers[key]

    first = polisher(0)
    if first is None or not first.usable:
        return out
    # the velocities of a configuration-dependent mass matrix are those of the states, v = M(q)⁻¹p:
    # a fixed-step solver's states meet the velocity constraints only at its step points, so at
    # the step ends the rows M(q) v = p and the velocity constraints' hidden rows disagree, and
    # the least-squares step above moved v off M(q)⁻¹p — H = ½pᵀv + V then was not the energy of
    # the states (a bead on a rod turned at a prescribed rate, discrete gradient: the energy
    # balance closed to 3e-15 without outputs, 1.2e-6 with `energy: H` among them)
    from phc.simulation.discrete_gradient import EndVelocities  # it imports the midpoint rule

    velocities = EndVelocities(mod, p)
    y, yp = np.array(y, dtype=float), np.array(yp, dtype=float)
    for k in range(len(t)):
        if t_from is not None and t[k] < t_from:
            continue
        polish = polisher(k)
        if polish is not None and np.all(np.isfinite(y[k])) and np.all(np.isfinite(yp[k])):
            y[k], yp[k], _ = polish(t[k], y[k], yp[k])
            velocities(t[k], y[k])
    improved = sum(q.improved for q in polishers.values() if q is not None)
    return out.replace(y=y, yp=yp, polished=improved)


__all__ = ["AlgebraicPolish", "polish_outputs", "depends_on_algebraic"]
