"""Coulomb friction at a closed contact: sticking and sliding as modes with located events.

Input: a generated module whose ``contact`` has `friction` and `tangent`
(:func:`phc.library.contact._friction`: the variables ``<c>.slip_rate`` v_t and
``<c>.friction_force`` λ_t, the output ``<c>.friction`` μ, the mode parameter
``<c>.sliding`` σ). Output: :class:`Friction`, the functions the event driver
(:mod:`phc.simulation.events`) watches beside each contact's gap or force, and the mode
changes at their events (:func:`on_close`, :func:`on_event`, :func:`settle`).

While the contact is open λ_t = 0. While it is closed (normal force λ ≥ 0 the multiplier
of ġ = 0) the row ``<c>.friction`` holds, by σ:

* **sliding** (σ = ±1, the sign of v_t): λ_t = −μ σ λ. The driver watches σ v_t; where it
  falls through zero the contact tries to **stick**: σ = 0, the row holds v_t = 0 and λ_t is
  its multiplier, the consistent state is solved, and the stick is kept if |λ_t| ≤ μ λ (the
  force needed to hold the bodies is admissible; the same switch model of Karnopp as the
  set-valued ``sign`` of :mod:`phc.simulation.events`). Otherwise it slides the way the
  force cannot hold, σ = −sign(λ_t) of the trial. On the bound (within the slack) one rule,
  :func:`slides_on`, decides for both: the way it was sliding it slides on, else it sticks.
  Before the trial the slip rate that the event's location error leaves is removed by a
  tangential impulse (its tiny kinetic energy booked as dissipated),
  so a stick holds v_t = 0 to round-off from its first step. A slide that begins at rest
  (from sticking, or a trial that failed) has its σ v_t watched from just below zero
  (:meth:`Friction.slide`): v_t grows from 0 with zero slope there, and its round-off is no
  return through zero.
* **sticking** (σ = 0): the driver watches μ λ − λ_t and μ λ + λ_t; where one falls through
  zero (|λ_t| reaches μ λ) it **slips**, σ = −sign(λ_t) — λ_t is continuous there. λ and λ_t
  are multipliers (outside IDA's error test), and a solver's values of them are off by its
  constraints' round-off over a step; so near the bound (within :data:`NEAR` of μ λ) the
  bound is evaluated at the consistent state, and a slip found on values that were off by
  more is confirmed there: where the force is still inside the cone the contact sticks on
  (:func:`on_event`).

A contact closes (:func:`on_close`) sliding with σ = sign(v_t) when it slides, and tries to
stick when v_t = 0 (a block put down on a slope). The friction power is λ_t v_t: −μ λ |v_t| ≤ 0
sliding, 0 sticking or open; the contact's dissipation term −λ_t v_t books it, so the energy
balance H(t) − H(0) + E(t) stays exact. The impacts of frictional contacts, and the part a
closed contact takes in another's impact, are :mod:`phc.simulation.impact_law`'s.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from phc.errors import InconsistentInitialError

STICK_SLACK = 1e-9
"""A stick is kept while |λ_t| ≤ (1 + slack) μ λ (as :data:`phc.simulation.events.STICK_SLACK`)."""
NEAR = 1e-3
"""Within this fraction of μ λ of its bound on a solver's values, a sticking contact's bound is
evaluated at the consistent state (:meth:`Friction.watched`): above the multipliers' error on
the solvers (IDA's up to 7e-4 just after a restart, on the woodpecker)."""


def slides_on(need: float, bound: float, way: float, orient: float = -1.0, floor: float = 0.0) -> float:
    """The decision of a stick trial, the one rule of the contacts' friction and of the
    set-valued sign (:func:`phc.simulation.events._try_stick`): 0.0 where the contact (or
    body) sticks, else the way ±1 it slides. `need`: the force the trial needs to hold it
    (λ_t; the sign's value s), `bound` ≥ 0 the most the law can give (μ λ; 1), `way` the
    way it was sliding before the trial (±1; 0 at rest), `orient` the way a force beyond
    the bound makes it slide per sign of `need` (σ = −sign λ_t: −1; the sign's orientation),
    `floor` an absolute round-off of |need| beside the bound's relative one.

    Clearly inside the bound (|need| below it by more than :data:`STICK_SLACK` of it and
    `floor`) it sticks; clearly outside it slides the way the force points. On the bound —
    within that slack — round-off of the trial would choose between the two: there a
    contact that was sliding the way the force points slides on (its slip began just now,
    v_t grows from 0 with zero slope, and the root finding took its round-off for a
    return through zero), and one at rest, or sliding the other way, sticks (as Karnopp's
    switch model: the force is admissible). The slack covers the bound's change over an
    event's location error, which round-off of the state decides (1e-13 s after the
    woodpecker's slip the need was 6.4e-12 of μ λ beyond it), and round-off of λ, λ_t."""
    excess = abs(need) - bound
    slack = STICK_SLACK * bound + floor
    if excess < -slack:
        return 0.0
    new = float(orient * np.sign(need)) if need != 0 else float(way)
    if excess > slack:
        return new
    return new if way != 0 and new == way else 0.0


class Friction:
    """The frictional contacts of a module (`contacts`: a :class:`~phc.simulation.impacts.Contacts`)."""

    def __init__(self, mod, contacts):
        variables = {n: i for i, n in enumerate(mod.VARIABLES)}
        parameters = {n: i for i, n in enumerate(getattr(mod, "PARAMETERS", ()))}
        outputs = {n: i for i, n in enumerate(getattr(mod, "OUTPUTS", ()))}
        self.of: list[Optional[int]] = []
        """For each contact, its index here (None: no friction)."""
        self.contact, self.slip, self.force, self.mode, self.mu = [], [], [], [], []
        self.tangents: list[list[tuple[int, int]]] = []
        """(output ∂s/∂x_j, momentum column) of each frictional contact."""
        for k, c in enumerate(contacts.names):
            slots = (variables.get(f"{c}.slip_rate"), variables.get(f"{c}.friction_force"),
                     parameters.get(f"{c}.sliding"), outputs.get(f"{c}.friction"))
            if None in slots or contacts.mode[k] is None:
                self.of.append(None)
                continue
            self.of.append(len(self.contact))
            self.contact.append(k)
            for where, slot in zip((self.slip, self.force, self.mode, self.mu), slots):
                where.append(slot)
            head = f"{c}.tangent."
            self.tangents.append([(o, variables[n[len(head):]]) for n, o in outputs.items() if n.startswith(head)])
        self.n = len(self.contact)
        self.contacts = contacts
        self.offset = np.zeros(self.n)
        """What σ v_t of each sliding contact is watched from below zero (:meth:`slide`)."""
        self.mod = mod
        self.fixed = set(np.flatnonzero(np.asarray(mod.DIFFERENTIAL)).tolist()) | {
            j for j, r in enumerate(getattr(mod, "ROLES", ())) if r == "energy"}
        """The columns a consistent state keeps (the differential states and the energy)."""

    def watched(self, y, p, out, t=None) -> np.ndarray:
        """Two entries per frictional contact, positive while its mode holds: σ v_t and +1
        sliding; μ λ − λ_t and μ λ + λ_t sticking; +1 open. `out`: the module's outputs at
        (t, y). λ and λ_t are multipliers, and a solver's values of them are off by its
        constraints' round-off over a step (IDA's by up to 7e-4 of μ λ on the woodpecker just
        after a restart, midpoint4's by 7e-6 at h = 1.25e-5): within :data:`NEAR` of the bound
        on those values, the bound is evaluated at the consistent state of the differential
        states in `y` (a solve), so the slip is found where the consistent force reaches the
        cone rather than early or late by their error."""
        w = np.ones(2 * self.n)
        for i, k in enumerate(self.contact):
            if not self.contacts.closed(k, p):
                continue
            sigma = p[self.mode[i]]
            if sigma != 0:
                w[2 * i] = sigma * y[self.slip[i]] + self.offset[i]
                continue
            bound = out[self.mu[i]] * y[self.contacts.force[k]]
            w[2 * i], w[2 * i + 1] = bound - y[self.force[i]], bound + y[self.force[i]]
            if t is not None and min(w[2 * i], w[2 * i + 1]) < NEAR * abs(bound):
                try:
                    z, zp = self.consistent(t, y, p)
                except InconsistentInitialError:
                    continue
                bound = self.contacts.outputs(t, z, zp, p)[self.mu[i]] * z[self.contacts.force[k]]
                w[2 * i], w[2 * i + 1] = bound - z[self.force[i]], bound + z[self.force[i]]
        return w

    def consistent(self, t, y, p):
        """The consistent ``(y, ẏ)`` at t with the differential states (and the energy) of `y`."""
        from phc.simulation.initial import consistent_initial_conditions

        r = consistent_initial_conditions(self.mod, p, t, dict(enumerate(y)), self.fixed, initial_relations=False)
        return r.y0, r.yp0

    def slide(self, i: int, sigma: float, y, p) -> None:
        """Contact i slides the way σ from (its slip rate in) `y`. Its σ v_t is watched from
        just below its value there: a slide that begins at rest (from sticking, or a stick
        trial that failed) has v_t = 0 growing with zero slope, and without the offset the
        root finding takes its round-off for a return through zero (the sleeve of
        models/woodpecker.yaml under IDA at rtol 2e-9: 50 stick trials within 7.6e-10 s).
        The offset, 1e-12 of the state's size as a reopened contact's gap has
        (:func:`phc.simulation.events._open`), delays a real return through zero by
        offset/|v̇_t|; a slide that begins with a slip rate above it has none."""
        p[self.mode[i]] = sigma
        v = sigma * float(y[self.slip[i]])
        noise = 1e-12 * (1.0 + float(np.abs(y).max(initial=0.0)))
        self.offset[i] = max(0.0, -v) + noise if v <= noise else 0.0

    def margin(self, i: int, y, p, out) -> float:
        """(μ λ − |λ_t|)/(μ λ) of a sticking contact i: how far its force is inside the cone."""
        bound = out[self.mu[i]] * y[self.contacts.force[self.contact[i]]]
        return float((bound - abs(y[self.force[i]])) / bound) if bound > 0 else -np.inf

    def decide(self, i: int, y, p, out, way: float) -> float:
        """The stick trial of contact i at the consistent sticking state `y` (:func:`slides_on`):
        0.0 it sticks, else the way σ it slides; `way` the way it was sliding (0: at rest)."""
        lam = y[self.contacts.force[self.contact[i]]]
        bound = out[self.mu[i]] * max(lam, 0.0)
        return slides_on(float(y[self.force[i]]), float(bound), float(way), -1.0, 1e-14 * abs(float(lam)))


def _event(t, name, direction, kind):
    from phc.simulation.events import Event  # events imports this module

    return Event(t, name, int(direction), kind, f"{name}.friction")


def _stop(watch, i: int, t, y, restart):
    """y with the slip rate v_t that the event's location error leaves (v_t is affine in the
    momenta) removed by a tangential impulse p_j += Λ ∂s/∂x_j, its kinetic energy booked as
    dissipated; the slope dv_t/dΛ is measured from one consistent state, the contact held
    open for it (as :meth:`~phc.simulation.impacts.Contacts.plastic` measures the normal's)."""
    f, contacts = watch.contacts.friction, watch.contacts
    k = f.contact[i]
    out = contacts.outputs(t, y, y * 0.0, watch.p)
    direction = np.zeros(len(y))
    for o, pj in f.tangents[i]:
        direction[pj] += out[o]
    closed, watch.p[contacts.mode[k]] = watch.p[contacts.mode[k]], 0.0
    try:
        before, after = restart(y, True)[0][f.slip[i]], restart(y + direction, True)[0][f.slip[i]]
    except InconsistentInitialError:
        return y
    finally:
        watch.p[contacts.mode[k]] = closed
    if before == 0.0 or not after - before > 0:
        return y
    new = y - (before / (after - before)) * direction
    energy = list(contacts.mod.VARIABLES).index("energy.supplied")
    new[energy] += float(contacts.mod.hamiltonian(t, y, watch.p)) - float(contacts.mod.hamiltonian(t, new, watch.p))
    return new


def _stick(watch, i: int, t, y, restart, events, sliding: bool = False):
    """Try to stick frictional contact i at (t, y): keep it where the force needed is
    admissible, else slide the way that force cannot hold (:func:`slides_on`: on the bound a
    contact sliding the way the force points slides on). Returns the consistent (y, ẏ).
    `sliding`: the contact slides now (its σ v_t fell through zero); sliding on the same way
    is then no switch and no event — where it began to slip from sticking its slip rate grows
    from 0 with zero slope (λ_t is continuous there), and IDA's root finding sees round-off
    of v_t cross zero until it has grown (the sleeve of models/woodpecker.yaml under IDA:
    8 such trials within 5e-10 s)."""
    f = watch.contacts.friction
    name = watch.contacts.names[f.contact[i]]
    sigma = watch.p[f.mode[i]]
    y = _stop(watch, i, t, y, restart)
    watch.p[f.mode[i]] = 0.0
    try:
        y1, yp1 = restart(y, True)
    except InconsistentInitialError:  # the slip rate held at 0: the momenta move by the event's location error
        y1, yp1 = restart(y, False)
    out = watch.contacts.outputs(t, y1, yp1, watch.p)
    way = f.decide(i, y1, watch.p, out, sigma if sliding else 0.0)
    if way == 0:
        events.append(_event(t, name, 0, "stick"))
        return y1, yp1
    f.slide(i, way, y, watch.p)
    if not sliding or watch.p[f.mode[i]] != sigma:
        events.append(_event(t, name, watch.p[f.mode[i]], "slip"))
    return restart(y, True)


def _restarts(watch, t, dif, energy):
    """``restart(y, states)``: the consistent state at t, the differential states fixed if `states`."""
    from phc.simulation.events import _restart  # events imports this module

    return lambda z, states=True: _restart(watch, t, z, (dif if states else set()) | set(energy))


def on_close(watch, k: int, t, y, yp, dif, energy):
    """Contact k closes at (t, y) (its mode already 1): the friction mode it closes in —
    sliding with the sign of v_t, or a stick trial where v_t = 0. Returns the consistent
    state and the mode's event, ``(y, ẏ, events)`` (`dif`, `energy`: the columns of the
    differential states and of the energy)."""
    restart = _restarts(watch, t, dif, energy)
    f = watch.contacts.friction
    i = f.of[k]
    events: list = []
    if i is None:
        return (*restart(y, True), events)
    v = float(y[f.slip[i]])
    if abs(v) > 1e-12 * (1.0 + float(np.abs(yp).max(initial=0.0))):
        f.slide(i, np.sign(v), y, watch.p)
        events.append(_event(t, watch.contacts.names[k], np.sign(v), "slip"))
        return (*restart(y, True), events)
    return (*_stick(watch, i, t, y, restart, events), events)


def on_event(watch, j: int, t, y, yp, events, dif, energy):
    """Entry j of the friction watch fell through zero at (t, y): σ v_t of a sliding contact
    (it tries to stick) or a bound of a sticking one (it slips)."""
    restart = _restarts(watch, t, dif, energy)
    f = watch.contacts.friction
    i = j // 2
    k = f.contact[i]
    if not watch.contacts.closed(k, watch.p):
        return y, yp
    watch.handled.append((t, watch.contacts.names[k], "friction"))  # (the chatter test's message)
    if watch.p[f.mode[i]] != 0:
        return _stick(watch, i, t, y, restart, events, sliding=True)
    # λ_t reached ±μλ on the solver's values of λ and λ_t (multipliers: IDA's are outside its
    # error test); at the consistent state still sticking the force may be inside the cone yet
    # (a root on values that were off by more than NEAR): then the slip is not due, and the
    # contact sticks on from that state, its bound watched on consistent states (Friction.watched)
    y1, yp1 = restart(y, True)
    if f.margin(i, y1, watch.p, watch.contacts.outputs(t, y1, yp1, watch.p)) > STICK_SLACK:
        return y1, yp1
    sigma = -1.0 if j % 2 == 0 else 1.0  # λ_t reached +μλ: it slides the negative way
    f.slide(i, sigma, y, watch.p)
    events.append(_event(t, watch.contacts.names[k], sigma, "slip"))
    return restart(y, True)


def settle(watch, t, y, yp, events) -> bool:
    """After a restart: a sticking contact whose friction force is no longer admissible (a
    force that jumped at a breakpoint) slips at once. Returns whether a mode changed."""
    f = watch.contacts.friction
    if not f.n:
        return False
    out = watch.contacts.outputs(t, y, yp, watch.p)
    changed = False
    for i, k in enumerate(f.contact):
        if not watch.contacts.closed(k, watch.p) or watch.p[f.mode[i]] != 0:
            continue
        way = f.decide(i, y, watch.p, out, 0.0)
        if way:
            f.slide(i, way, y, watch.p)
            events.append(_event(t, watch.contacts.names[k], watch.p[f.mode[i]], "slip"))
            changed = True
    return changed


__all__ = ["Friction", "STICK_SLACK", "on_close", "on_event", "settle", "slides_on"]
