"""What to say when a model names a state that does not exist (`simulation.initial`,
`simulation.nominal`; PHC-E210): states of the same kind, never a momentum for a
position.

A state's kind follows from its component type where the registry knows it (a lumped
storage element stores effort·time, a momentum, or flow·time, a displacement:
``Units.storage`` in :mod:`phc.library.registry`), else from its name (`x`, `theta`: positions;
`p`: momenta). The kind a user wants follows from the name written (`body.x` asks for a
position). A `mass` has only its momentum `p` unless it has `position: true`: asked for
`body.x`, the message says so, how to add the position, and names the positions the model
has.
"""

from __future__ import annotations

import difflib
import re
from typing import Optional

POSITION, MOMENTUM, VELOCITY = "position", "momentum", "velocity"

_WORDS = {
    POSITION: {"x", "y", "z", "s", "q", "w", "theta", "phi", "psi", "alpha", "beta", "angle", "pos", "position",
               "displacement", "elongation", "deflection", "stroke", "travel"},
    MOMENTUM: {"p", "momentum", "h", "impulse"},
    VELOCITY: {"v", "vx", "vy", "vz", "u", "omega", "speed", "velocity", "vel", "xdot", "xd", "rate"},
}

_STORED = {  # (storage of the type, domain) -> what the state is
    ("e", "mechanical.translational"): "momentum", ("e", "mechanical.rotational"): "angular momentum",
    ("e", "electrical"): "flux linkage", ("e", "hydraulic"): "pressure momentum",
    ("f", "mechanical.translational"): "displacement", ("f", "mechanical.rotational"): "angle",
    ("f", "electrical"): "charge", ("f", "hydraulic"): "volume", ("f", "thermal"): "heat",
}


def word_kind(local: str) -> Optional[str]:
    """The kind a state's local name suggests (`x` a position, `p` a momentum), or None."""
    word = re.sub(r"\[\d+\]$", "", local).lower()
    word = re.sub(r"_?\d+$", "", word) or word  # x1, theta_2
    return next((kind for kind, words in _WORDS.items() if word in words), None)


class _States:
    """The model's states with their component, kind, domain and what they are."""

    def __init__(self, elab, names) -> None:
        from phc.library.registry import find

        domains: dict[str, set] = {}
        for port in getattr(elab, "ports", {}).values():
            domains.setdefault(port.component, set()).add(port.domain)
        self.names = sorted(n for n in names if n != "energy.supplied")
        self.component = {v.name: v.component for v in elab.variables if v.role == "state"}
        self.type: dict[str, str] = {}
        self.domain: dict[str, Optional[str]] = {}
        self.kind: dict[str, Optional[str]] = {}
        self.what: dict[str, str] = {}
        specs = getattr(elab, "component_specs", {})
        for comp, spec in specs.items():
            self.type[comp] = getattr(spec, "type", "")
            doms = domains.get(comp, set())
            self.domain[comp] = next(iter(doms)) if len(doms) == 1 else None
        for name in self.names:
            comp = self.component.get(name, name.rpartition(".")[0])
            entry = find(self.type.get(comp))
            units = getattr(entry, "units", None)
            storage = units.storage_of(name[len(comp) + 1:]) if units is not None and units.storage else None
            kind = {"e": MOMENTUM, "f": POSITION}.get(storage) if storage else word_kind(name.rpartition(".")[2])
            self.kind[name] = kind
            self.what[name] = _STORED.get((storage, self.domain.get(comp)), kind or "state")

    def of(self, comp: str) -> list[str]:
        return [n for n in self.names if self.component.get(n) == comp]


def unknown_state(name: str, elab, names) -> tuple[str, str]:
    """``(addition to the message, hint)`` for `name`, which is not among the states `names`
    of the elaboration `elab`: the addition says what the named component has instead
    (``": `body` (a mass) has no position state, only its momentum `body.p`"``; empty when
    that is not the trouble), the hint names states of the kind `name` asks for."""
    from phc.library.registry import find

    states = _States(elab, names)
    comp, _, local = name.rpartition(".")
    want = word_kind(local)
    own = states.of(comp) if comp else []

    def shown(items) -> str:
        items = list(items)
        text = ", ".join(f"`{s}`" for s in items[:8])
        return text + (f" (and {len(items) - 8} more)" if len(items) > 8 else "")

    def alike(exclude: str = "") -> list[str]:
        domain = states.domain.get(comp)
        family = domain.split(".")[0] if domain else None
        return [s for s in states.names if states.kind[s] == want and states.component.get(s) != exclude
                and (family is None or (states.domain.get(states.component.get(s)) or "").startswith(family))]

    if own and want is not None and not any(states.kind[s] == want for s in own):
        kind_type = states.type.get(comp) or "component"
        has = ", ".join(f"its {states.what[s]} `{s}`" for s in own[:4]) + (" ..." if len(own) > 4 else "")
        extra = f": `{comp}` (a {kind_type}) has no {want} state, only {has}"
        momenta = [s for s in own if states.kind[s] == MOMENTUM]
        if want == VELOCITY and momenta:  # a mass moving at v: its momentum m·v
            return extra, f"give its momentum {shown(momenta[:1])} (mass × velocity) instead"
        same = alike(exclude=comp)
        hint = (f"{want} states in this model: {shown(same)}" if same
                else f"give the value of {shown(own[:1])} instead")
        if want == POSITION and "position" in getattr(getattr(find(states.type.get(comp)), "spec", None),
                                                      "model_fields", {}):
            hint = f"`position: true` on `{comp}` adds its position `{comp}.x`; or: " + hint
        return extra, hint
    pool = [s for s in states.names if want is None or states.kind[s] in (want, None)]
    if own:
        pool = [s for s in own if s in pool] or pool
    close = [s for s in pool if s.lower() == name.lower()] or difflib.get_close_matches(name, pool, n=3, cutoff=0.6)
    if close:
        return "", "did you mean " + _either(close) + "?"
    if own:
        return "", f"states of `{comp}`: {shown(own)}"
    return "", f"states: {shown(states.names)}"


def _either(names: list[str]) -> str:
    quoted = [f"`{n}`" for n in names]
    return quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " or " + quoted[-1]
