"""Frictional impacts of several contacts at once: Newton's law in the normal direction,
Coulomb's in the tangential one, solved jointly (the impact law of Ch. Glocker, *Set-Valued
Force Laws*, Springer 2001; F. Pfeiffer, Ch. Glocker, *Multibody Dynamics with Unilateral
Contacts*, Wiley 1996, on the woodpecker toy).

Input: the event driver's :class:`~phc.simulation.events.Watch` at an impact of one or more
open contacts (gap fell through zero, ġ⁻ < 0). Output: the consistent state after the jump,
the contacts' modes after it, and their events (:func:`joint_impact`).

The contacts involved are the impacting ones and every closed contact. With the impulses
Λ_N,i along the normals n_i = ∂g_i/∂x and Λ_T,i along the tangents t_i = ∂s_i/∂x of the
frictional ones, the momenta jump, p⁺ = p⁻ + Σ Λ_N,i n_i + Λ_T,i t_i, positions continuous.
The rates after it are affine in the impulses, (ġ⁺, v_T⁺) = (ġ⁻, v_T⁻) + W Λ, and the
Delassus matrix W (W_ij = the change of rate i under a unit impulse j, i.e. dᵢᵀ M⁻¹ dⱼ) is
measured exactly from consistent states, the contacts held open, as
:class:`~phc.simulation.impacts.Contacts` measures the single slope. For each contact:

* normal (Newton): ξ_i = ġ_i⁺ + e_i ġ_i⁻ ≥ 0, Λ_N,i ≥ 0, ξ_i Λ_N,i = 0 (ġ⁻ = 0 at a closed
  contact, so it stays closed or lifts off);
* tangential (Coulomb, no tangential restitution): |Λ_T,i| ≤ μ_i Λ_N,i; sticking v_T,i⁺ = 0,
  or sliding Λ_T,i = −μ_i Λ_N,i sign(v_T,i⁺).

For the handful of contacts of one impact the linear complementarity problem is solved
exactly by enumeration (:func:`solve`): each contact is free (Λ = 0), or active and sticking,
sliding + or sliding − (frictionless: active); each combination is a linear system, and the
first whose solution satisfies every inequality is the impulse. The kinetic energy lost is
booked as dissipated (H(t) − H(0) + E(t) stays exact), and a jump that would gain energy
(Newton's law with friction can, for e > 0 and coupled tangents: Kane's paradox) stops the
run with a message instead.
"""

from __future__ import annotations

from itertools import product
from typing import Optional

import numpy as np

from phc.errors import InconsistentInitialError

MAX_CONTACTS = 8
"""Most contacts of one joint impact (the enumeration has up to 4^k linear systems)."""
FEASIBLE = 1e-9
"""Relative slack of the inequalities of a case (of the rates' and impulses' scales)."""


def solve(W, before, restitution, mu) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """The impulses of the impact law (module docstring) for contacts i = 0..k−1.

    Parameters
    ----------
    W : (k + f, k + f) array
        The Delassus matrix in the order (normals of the k contacts, tangents of the f
        frictional ones).
    before : (k + f,) array
        The rates before the impact, (ġ⁻, v_T⁻).
    restitution : (k,) array
        Newton's e_i.
    mu : (k,) array
        Coulomb's μ_i, NaN for a frictionless contact (no tangent row).

    Returns ``(Λ, rates after)`` in the order of `W`, or None if no case is feasible."""
    W = np.asarray(W, dtype=float)
    before = np.asarray(before, dtype=float)
    mu = np.asarray(mu, dtype=float)
    k = len(restitution)
    frictional = np.flatnonzero(~np.isnan(mu))
    tangent = {int(i): k + j for j, i in enumerate(frictional)}
    n = k + len(frictional)
    target = -np.asarray(restitution, dtype=float) * np.minimum(before[:k], 0.0)  # ξ = 0: ġ⁺ = −e ġ⁻
    speed = float(np.abs(before).max(initial=0.0)) or 1.0
    size = speed / max(float(np.abs(np.diag(W)).max(initial=0.0)), 1e-300)
    cases = [(0, 1, 2, 3) if i in tangent else (0, 1) for i in range(k)]
    for case in product(*cases):  # 0 free, 1 active (sticking), 2 sliding +, 3 sliding −
        A, rhs = np.zeros((n, n)), np.zeros(n)
        for i, c in enumerate(case):
            t = tangent.get(i)
            if c == 0:
                A[i, i] = 1.0
                if t is not None:
                    A[t, t] = 1.0
                continue
            A[i], rhs[i] = W[i], target[i] - before[i]
            if t is None:
                continue
            if c == 1:
                A[t], rhs[t] = W[t], -before[t]
            else:
                A[t, t], A[t, i] = 1.0, (mu[i] if c == 2 else -mu[i])
        try:
            lam = np.linalg.solve(A, rhs)
        except np.linalg.LinAlgError:
            lam = np.linalg.lstsq(A, rhs, rcond=None)[0]
            if np.abs(A @ lam - rhs).max(initial=0.0) > FEASIBLE * speed:
                continue
        after = before + W @ lam
        ok = True
        for i, c in enumerate(case):
            t = tangent.get(i)
            if c == 0:
                ok = after[i] - target[i] >= -FEASIBLE * speed
            else:
                ok = lam[i] >= -FEASIBLE * size
                if t is not None and c == 1:
                    ok = ok and abs(lam[t]) <= mu[i] * max(lam[i], 0.0) * (1 + FEASIBLE) + FEASIBLE * size
                elif c == 2:
                    ok = ok and after[t] >= -FEASIBLE * speed
                elif c == 3:
                    ok = ok and after[t] <= FEASIBLE * speed
            if not ok:
                break
        if ok:
            return lam, after
    return None


def involved(watch, impacts) -> list[int]:
    """The contacts of a joint impact: `impacts` (open, falling through zero) and the closed ones."""
    contacts = watch.contacts
    return sorted(set(impacts) | {k for k in range(contacts.n) if contacts.closed(k, watch.p)})


def wanted(watch, impacts) -> bool:
    """Whether an impact of `impacts` needs the joint law: friction at a contact involved, or
    more than one contact (a single frictionless one keeps Newton's jump along its normal)."""
    ks = involved(watch, impacts)
    return len(ks) > 1 or any(watch.contacts.friction.of[k] is not None for k in ks)


def joint_impact(watch, impacts, t, y, yp, events, dif, energy):
    """The jump of the contacts `impacts` (open, ġ⁻ < 0 at t) with every closed contact, by
    the impact law, and the modes after it: an impacting contact coming to rest (its rebound
    below the rest speed, or accumulating) takes a plastic jump and closes; a closed contact
    that separates opens; one that stays sticks where v_T⁺ = 0 and slides with the sign of
    v_T⁺ otherwise. Raises :class:`~phc.simulation.events._ContactRest` where the run stops."""
    from phc.simulation.events import Event, _ContactRest, _close, _restart  # events imports this module

    contacts, f = watch.contacts, watch.contacts.friction
    ks = involved(watch, impacts)
    if len(ks) > MAX_CONTACTS:
        raise _ContactRest(f"{len(ks)} contacts at one impact at t = {t:.6g} (at most {MAX_CONTACTS})")
    names = [contacts.names[k] for k in ks]
    closed = {k: watch.p[contacts.mode[k]] for k in ks if contacts.mode[k] is not None}
    sliding = {k: watch.p[f.mode[f.of[k]]] for k in ks if f.of[k] is not None}
    for k in closed:  # held open while the jump is measured and taken
        watch.p[contacts.mode[k]] = 0.0
    fixed = dif | set(energy)

    def restart(z):
        return _restart(watch, t, z, fixed)

    def rates(z, zp):
        out = contacts.outputs(t, z, zp, watch.p)
        return np.array([out[contacts.rate[k]] for k in ks] + [z[f.slip[f.of[k]]] for k in ks if f.of[k] is not None])

    try:
        y, yp = restart(y)
        out = contacts.outputs(t, y, yp, watch.p)
        directions = [contacts._normal(k, out, len(y)) for k in ks]
        for k in ks:
            i = f.of[k]
            if i is not None:
                d = np.zeros(len(y))
                for o, pj in f.tangents[i]:
                    d[pj] += out[o]
                directions.append(d)
        before = rates(y, yp)
        W = np.column_stack([rates(*restart(y + d)) - before for d in directions])
    except InconsistentInitialError as err:
        for k, mode in closed.items():
            watch.p[contacts.mode[k]] = mode
        raise _ContactRest(f"the impact of {', '.join(f'`{n}`' for n in names)} at t = {t:.6g} cannot be "
                           "measured: " + "; ".join(err.problems)) from None
    W = 0.5 * (W + W.T)  # symmetric in exact arithmetic (dᵢᵀ M⁻¹ dⱼ)
    k_n = len(ks)
    resting = []
    e = np.zeros(k_n)
    for a, k in enumerate(ks):
        if k in impacts and before[a] < 0:
            watch.handled.append((t, contacts.names[k], "contact"))
            events.append(Event(t, contacts.names[k], -1, "impact", contacts.names[k]))
            e[a] = float(out[contacts.restitution[k]])
            if contacts.book(k, t, out, float(before[a]), watch.span, e[a]):
                contacts.hits[k].clear()
                resting.append(k)
                e[a] = 0.0
        elif before[a] < 0 and k not in closed:
            e[a] = float(out[contacts.restitution[k]])
    mu = np.array([float(out[f.mu[f.of[k]]]) if f.of[k] is not None else np.nan for k in ks])
    solution = solve(W, before, e, mu)
    if solution is None:
        raise _ContactRest(f"the impact of {', '.join(f'`{n}`' for n in names)} at t = {t:.6g} has no solution of "
                           "Newton's and Coulomb's laws (docs/events.md)")
    lam, after = solution
    new = y + sum(l * d for l, d in zip(lam, directions))
    h_before = float(contacts.mod.hamiltonian(t, y, watch.p))
    lost = h_before - float(contacts.mod.hamiltonian(t, new, watch.p))
    work = float(np.abs(lam).sum() * np.abs(before).max(initial=0.0))  # the scale of the impulses' work
    if lost < -(1e-9 * work + 1e3 * np.finfo(float).eps * abs(h_before)):
        raise _ContactRest(f"the impact of {', '.join(f'`{n}`' for n in names)} at t = {t:.6g} would gain "
                           f"{-lost:.3g} of energy (Newton's law with friction: docs/events.md)")
    new[list(contacts.mod.VARIABLES).index("energy.supplied")] += lost
    # the modes after the jump
    speed = float(np.abs(before).max(initial=0.0))
    tangents = {k: k_n + j for j, k in enumerate(k for k in ks if f.of[k] is not None)}
    y, yp = restart(new)
    for a, k in enumerate(ks):
        if k in closed and closed[k] > 0:
            if after[a] > FEASIBLE * speed and lam[a] <= 0:
                watch.p[contacts.mode[k]] = 0.0
                contacts.offset[k] = 1e-12 * (1.0 + float(np.abs(y).max(initial=0.0)))
                watch.handled.append((t, contacts.names[k], "contact"))
                events.append(Event(t, contacts.names[k], 1, "open", contacts.names[k]))
                continue
            watch.p[contacts.mode[k]] = closed[k]
            if k in tangents:
                v = float(after[tangents[k]])
                sigma = 0.0 if abs(v) <= FEASIBLE * speed else float(np.sign(v))
                if sigma != sliding[k]:
                    if sigma:
                        f.slide(f.of[k], sigma, y, watch.p)
                    else:
                        watch.p[f.mode[f.of[k]]] = sigma
                    name = contacts.names[k]
                    events.append(Event(t, name, int(sigma), "stick" if sigma == 0 else "slip", f"{name}.friction"))
    for k in resting:
        y, yp, _ = _close(watch, k, t, y, yp, events, dif, energy)
    if resting:
        return y, yp
    try:
        return restart(y)
    except InconsistentInitialError:  # a stick holds v_T = 0: the momenta move by the round-off of v_T⁺
        return _restart(watch, t, y, set(energy))


__all__ = ["FEASIBLE", "MAX_CONTACTS", "involved", "joint_impact", "solve", "wanted"]
