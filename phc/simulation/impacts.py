"""Impacts: the momentum jumps of unilateral contacts with Newton's restitution law.

Input: a generated module whose outputs include a ``contact``'s gap, gap rate, normal and
restitution (:mod:`phc.library.contact`). Output: the contacts as :class:`Contacts`, which
the event driver (:mod:`phc.simulation.events`) watches beside the switching functions,
and :meth:`Contacts.impact`, the jump at a located impact.

At an impact of contact k at (t, y⁻) with closing rate ġ⁻ < 0 the momenta p_j paired with
the positions x_j in the gap jump along the normal n_j = ∂g/∂x_j, p_j⁺ = p_j⁻ + λ n_j,
positions continuous. ġ is affine in those momenta (ẋ_j = p_j/m_j), so its slope
c = dġ/dλ = Σ n_j²/m_j is found exactly from one consistent state at p⁻ + n (phc's own
consistent initialization computes ẋ, so no mass is read twice), and λ = −(1 + e) ġ⁻/c
gives ġ⁺ = −e ġ⁻. The kinetic energy lost, H(y⁻) − H(y⁺) = (1 − e²) ġ⁻²/(2c), is added to
the dissipated energy ``energy.supplied``, so H(t) − H(0) + E(t) stays exact. This is the jump
of a single frictionless contact with no other contact closed; with friction or several
contacts the impact law of :mod:`phc.simulation.impact_law` takes them jointly.

Persistent contact: the bounces of a ball accumulate at a finite time (Zeno). When the
rebound speed e|ġ⁻| falls below the contact's rest speed (default 1e-6 of the largest
closing speed it has seen), or the impacts accumulate (:data:`ACCUMULATE_COUNT` of them
within :data:`ACCUMULATE_SPAN` of the run), and the gap's acceleration after a plastic jump
(ġ⁺ = 0) pushes into the contact, the contact *closes*: the plastic jump's loss
ġ⁻²/(2c) is booked (what the accumulating bounces would have dissipated), the contact's
mode ``<c>.closed`` becomes 1, and its row holds ġ = 0 with the force λ = ``<c>.force`` as
the multiplier (:mod:`phc.library.contact`); λ ġ = 0, so the closed contact does no work.
While closed the driver watches λ; where it falls through zero the contact opens (mode 0,
λ = 0) and its gap is watched again. A module compiled without the mode (older phc) stops
the run where the contact would close, with a message.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from phc.errors import InconsistentInitialError
from phc.simulation.friction import Friction
from phc.simulation.midpoint import EVENT_TOL  # the relative time an event is located to

REST_FRACTION = 1e-6
"""Default rest speed of a contact: this fraction of the largest closing speed it has seen."""
ACCUMULATE_COUNT = 50
"""Impacts of one contact within :data:`ACCUMULATE_SPAN` of the run's span that close it."""
ACCUMULATE_SPAN = 1e-6
CLOSE = "close"
"""The outcome of :meth:`Contacts.impact` where the contact closes (persistent contact)."""


class Contacts:
    """The contacts of a generated module, read from its outputs (empty if it has none)."""

    def __init__(self, mod):
        names = tuple(getattr(mod, "OUTPUTS", ()))
        index = {n: i for i, n in enumerate(names)}
        variables = {n: i for i, n in enumerate(mod.VARIABLES)}
        self.mod = mod
        self.names: list[str] = []
        parameters = {n: i for i, n in enumerate(getattr(mod, "PARAMETERS", ()))}
        self.gap, self.rate, self.restitution, self.rest = [], [], [], []
        self.force: list[Optional[int]] = []
        """The column of each contact's force λ (None: compiled without persistent contact)."""
        self.mode: list[Optional[int]] = []
        """The parameter slot of each contact's mode ``<c>.closed`` (1 while closed)."""
        self.normals: list[list[tuple[int, int]]] = []  # (normal output, momentum)
        for n in names:
            if not n.endswith(".restitution"):
                continue
            c = n[:-len(".restitution")]
            if f"{c}.gap" not in index or f"{c}.gap_rate" not in index:
                continue
            normals = []
            for m in names:
                if m.startswith(f"{c}.normal."):
                    normals.append((index[m], variables[m[len(f"{c}.normal."):]]))
            self.names.append(c)
            self.gap.append(index[f"{c}.gap"])
            self.rate.append(index[f"{c}.gap_rate"])
            self.restitution.append(index[n])
            self.rest.append(index.get(f"{c}.rest_speed"))
            self.normals.append(normals)
            self.force.append(variables.get(f"{c}.force"))
            self.mode.append(parameters.get(f"{c}.closed"))
        self.n = len(self.names)
        self.hits: list[list[float]] = [[] for _ in range(self.n)]
        """The impact times of each contact (the accumulation test)."""
        self.gap_idx = np.asarray(self.gap, dtype=np.int64)
        self.closing = np.zeros(self.n)
        """The largest closing speed each contact has seen."""
        self.offset = np.zeros(self.n)
        """Added to each gap where it is watched: after an impact the gap starts at zero (to the
        event's location error), and a solver sees a crossing only from a positive value;
        with the offset a rebound whose whole flight lies within one step (the last bounces
        before a ball comes to rest) is still an impact at the step's end."""
        self.consistent: list = [None] * self.n
        """For a closed contact whose force fell to zero on IDA's values only: ``(t, y) -> (y, ẏ)``,
        the consistent state its force is watched on (:func:`phc.simulation.events._open`)."""
        self.friction = Friction(mod, self)
        """Coulomb friction at the closed contacts that have it (:mod:`phc.simulation.friction`)."""
        self.n_watch = self.n + 2 * self.friction.n
        """The functions watched: one per contact, two per frictional contact."""

    def outputs(self, t, y, yp, p) -> np.ndarray:
        return np.asarray(self.mod.outputs(t, y, yp, p), dtype=float)

    def gaps(self, t, y, yp, p) -> np.ndarray:
        return self.outputs(t, y, yp, p)[self.gap_idx] + self.offset if self.n else np.zeros(0)

    def closed(self, k: int, p) -> bool:
        return self.mode[k] is not None and p[self.mode[k]] > 0

    def watched(self, t, y, yp, p) -> np.ndarray:
        """What the driver watches of each contact: its gap (with the offset) while open, its
        force λ while closed (each positive while the mode holds); then two functions per
        frictional contact (:meth:`Friction.watched <phc.simulation.friction.Friction.watched>`)."""
        out = self.outputs(t, y, yp, p) if self.n else np.zeros(0)
        w = out[self.gap_idx] + self.offset if self.n else np.zeros(0)
        for k in range(self.n):
            if self.closed(k, p):
                w[k] = y[self.force[k]]
                if self.consistent[k] is not None:  # (phc.simulation.events._open)
                    try:
                        w[k] = self.consistent[k](t, y)[0][self.force[k]]
                    except InconsistentInitialError:
                        pass
        return np.concatenate([w, self.friction.watched(y, p, out, t)]) if self.friction.n else w

    def rate_of(self, t, y, yp, p, k: int) -> float:
        return float(self.outputs(t, y, yp, p)[self.rate[k]])

    def _normal(self, k: int, out, n: int) -> np.ndarray:
        normal = np.zeros(n)
        for o, pj in self.normals[k]:
            normal[pj] += out[o]
        return normal

    def _slope(self, k, t, y, p, normal, before, restart) -> float:
        """c = dġ/dλ = Σ n_j²/m_j, exactly: ġ is affine in the momenta."""
        trial = restart(y + normal)
        return float(self.outputs(t, trial[0], trial[1], p)[self.rate[k]]) - before

    def _accel(self, k, t, y, yp, p, restart) -> float:
        """The gap's acceleration at a consistent (y, ẏ), Σ n_j ṗ_j/m_j: ġ is affine in the
        momenta, so its change when they move by their rates ṗ_j is exact."""
        moved = y.copy()
        for _, pj in self.normals[k]:
            moved[pj] += yp[pj]
        ahead = restart(moved)
        return float(self.outputs(t, ahead[0], ahead[1], p)[self.rate[k]]) - self.rate_of(t, y, yp, p, k)

    def plastic(self, k: int, t, y, yp, p, restart) -> tuple[np.ndarray, np.ndarray, Optional[str]]:
        """The jump of contact k at a consistent (t, y, ẏ) to ġ⁺ = 0 (a plastic impact), its
        loss ġ⁻²/(2c) booked as dissipated: ``(y⁺, ẏ⁺, stop message or None)``."""
        out = self.outputs(t, y, yp, p)
        before = float(out[self.rate[k]])
        if abs(before) <= 1e-14 * (1.0 + float(np.abs(yp).max(initial=0.0))):
            return y, yp, None  # round-off of the consistent start: its loss is below H's round-off
        normal = self._normal(k, out, len(y))
        slope = self._slope(k, t, y, p, normal, before, restart)
        if not slope > 0:
            return y, yp, (f"contact `{self.names[k]}` cannot act at t = {t:.6g}: its gap does not respond to an "
                           "impulse on the masses it names (are they held by a constraint?)")
        return self._jump(k, t, y, p, normal, before, slope, 0.0, restart)

    def _jump(self, k, t, y, p, normal, before, slope, e, restart):
        """p⁺ = p⁻ + λ n with λ = −(1 + e) ġ⁻/c, the energy lost booked and checked."""
        energy = self.mod.VARIABLES.index("energy.supplied")
        new = y + (-(1.0 + e) * before / slope) * normal
        h_before = float(self.mod.hamiltonian(t, y, p))
        lost = h_before - float(self.mod.hamiltonian(t, new, p))
        new[energy] += lost
        # Newton's law loses (1 − e²) ġ⁻²/2c exactly when the impulse acts along the normal the
        # velocities see (ġ = Σ n_j ẋ_j with ẋ_j = ∂H/∂p_j); anything else is a fault of phc's pairing
        newton = (1.0 - e * e) * before * before / (2.0 * slope)
        # (to round-off of the kinetic energy, and of H where a potential makes it large)
        if abs(lost - newton) > 1e-8 * 0.5 * before * before / slope + 1e3 * np.finfo(float).eps * abs(h_before):
            return y, None, (f"contact `{self.names[k]}` at t = {t:.6g}: the impulse lost {lost:.6g} of energy where "
                             f"Newton's law loses {newton:.6g}: its normal does not match the bodies' velocities "
                             "(a fault in phc; please report it)")
        y_new, yp_new = restart(new)
        return y_new, yp_new, None

    def book(self, k: int, t, out, before: float, span: float, e: float) -> bool:
        """Record an impact of contact k at t with closing rate `before` < 0 (`out`: the
        outputs there): its gap is watched from just below the event's value (the event is
        located to EVENT_TOL in time), its largest closing speed and its impact times (the
        accumulation test) are updated. Returns whether it comes to rest: its rebound e|ġ⁻|
        below its rest speed, or its impacts accumulating."""
        self.offset[k] = max(0.0, -float(out[self.gap[k]])) + 2.0 * -before * EVENT_TOL * max(1.0, abs(t))
        self.closing[k] = max(self.closing[k], -before)
        hits = self.hits[k]
        hits.append(t)
        del hits[:-ACCUMULATE_COUNT]
        accumulating = len(hits) == ACCUMULATE_COUNT and hits[-1] - hits[0] <= ACCUMULATE_SPAN * span
        rest = (float(out[self.rest[k]]) if self.rest[k] is not None else REST_FRACTION * self.closing[k])
        return bool(e * -before <= rest or accumulating)

    def impact(self, k: int, t, y, yp, p, restart, span: float = 0.0
               ) -> tuple[np.ndarray, np.ndarray, Optional[str], float]:
        """The jump of contact k at (t, y, ẏ): ``(y⁺, ẏ⁺, outcome, rate before)`` with outcome
        None, :data:`CLOSE` (the plastic jump was taken and the contact is to close) or a
        message that stops the run; `restart(y)` returns the consistent ``(y, ẏ)`` with the
        differential states of y, `span` is the run's length (the accumulation test)."""
        # the rates at the event from the consistent state (a fixed-step solver hands over the
        # secant rate of its last partial step, which is off by O(h) from ẋ at the event)
        y, yp = restart(y)
        out = self.outputs(t, y, yp, p)
        before = float(out[self.rate[k]])
        if before >= 0:  # grazing or opening: no impact
            return y, yp, None, before
        e = float(out[self.restitution[k]])
        normal = self._normal(k, out, len(y))
        slope = self._slope(k, t, y, p, normal, before, restart)
        if not slope > 0:
            return y, yp, (f"contact `{self.names[k]}` cannot act at t = {t:.6g}: its gap does not respond to an "
                           "impulse on the masses it names (are they held by a constraint?)"), before
        if self.book(k, t, out, before, span, e):
            # coming to rest: after a plastic jump (ġ⁺ = 0), does the load press the masses on?
            y_rest, yp_rest, fault = self._jump(k, t, y, p, normal, before, slope, 0.0, restart)
            if fault is not None:
                return y, yp, fault, before
            if self._accel(k, t, y_rest, yp_rest, p, restart) <= 0:
                if self.mode[k] is None:
                    return y_rest, yp_rest, (
                        f"contact `{self.names[k]}` comes to rest at t = {t:.9g}, and the module was compiled "
                        "without persistent contact: recompile it (results up to there are kept)"), before
                self.hits[k].clear()
                return y_rest, yp_rest, CLOSE, before
        y_new, yp_new, fault = self._jump(k, t, y, p, normal, before, slope, e, restart)
        if fault is not None:
            return y, yp, fault, before
        return y_new, yp_new, None, before


def contact_forces(mod) -> list[int]:
    """The columns of the contacts' forces λ (``<c>.force``) in `mod`'s variables."""
    variables = {n: i for i, n in enumerate(getattr(mod, "VARIABLES", ()))}
    outputs = set(getattr(mod, "OUTPUTS", ()))
    return [variables[f"{n[:-12]}.force"] for n in outputs
            if n.endswith(".restitution") and f"{n[:-12]}.gap" in outputs and f"{n[:-12]}.force" in variables]


def has_contacts(mod) -> bool:
    """Whether `mod` has a contact (its outputs ``<c>.gap``, ``<c>.gap_rate``, ``<c>.restitution``)."""
    outputs = set(getattr(mod, "OUTPUTS", ()))
    return any(n.endswith(".restitution") and f"{n[:-12]}.gap" in outputs and f"{n[:-12]}.gap_rate" in outputs
               for n in outputs)


__all__ = ["ACCUMULATE_COUNT", "ACCUMULATE_SPAN", "CLOSE", "Contacts", "REST_FRACTION", "contact_forces", "has_contacts"]
