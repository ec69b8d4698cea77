"""Effects: optional physics a component can switch on or off (issue "Scenes").

A library component declares its effects as a typed model (``MovingBeamEffects``, ...,
in :mod:`phc.spec.components`); user-defined components (``phs``, ``rigid``) declare
theirs as ``effects: {name: default}``, and may use each name as a 0/1 factor in their
expressions or name a term of their Hamiltonian / potential after it. A scene overrides
effects per component; lowering reads the resulting values, so an effect that is off is
never generated. What lowering leaves out is recorded in its
:class:`~phc.frontend.lowering.ComponentLowering` (``left_out``) and reported by ``phc simulate``
and ``phc compile``.
"""

from __future__ import annotations

from typing import Any, Optional

import pydantic
import sympy as sp

from phc.frontend.source_map import path_text


def effect_names(spec) -> dict[str, Any]:
    """The effects of a component spec with their current values ({} when it has none)."""
    effects = getattr(spec, "effects", None)
    if effects is None:
        return {}
    if isinstance(effects, pydantic.BaseModel):
        return effects.model_dump()
    from phc.library import registry

    entry = registry.find(spec.type)
    values = dict(entry.implicit_effects) if entry is not None else {}
    for term_owner in ("hamiltonian", "V"):
        terms = getattr(spec, term_owner, None)
        if isinstance(terms, dict):
            for name in terms:
                values.setdefault(name, True)
    values.update(effects)
    return values


def _types_with_effects() -> str:
    """The registered component types whose entries have an `effects` field, as a list."""
    from phc.library import registry

    found = [name for name in registry.names() if "effects" in registry.get(name).spec.model_fields]
    return ", ".join(found[:-1]) + (" and " if len(found) > 1 else "") + found[-1] if found else "no type"


def is_on(spec, name: str) -> bool:
    """Whether effect `name` of a component is on (unknown names count as on)."""
    return bool(effect_names(spec).get(name, True))


def apply_overrides(spec, overrides: dict[str, Any]) -> tuple[Any, Optional[str]]:
    """A copy of `spec` with the effect values in `overrides`; or (spec, message) when an
    override names an effect the component does not have or gives a wrong value."""
    current = effect_names(spec)
    if not current and getattr(spec, "effects", None) is None:
        return spec, (f"`{spec.type}` components have no optional effects; effects exist for "
                      f"{_types_with_effects()}")
    unknown = [k for k in overrides if k not in current]
    if unknown:
        return spec, (f"`{spec.type}` component has no effect `{unknown[0]}`; its effects: "
                      f"{', '.join(sorted(current)) or 'none declared'}")
    effects = spec.effects
    if isinstance(effects, pydantic.BaseModel):
        try:
            new = type(effects).model_validate({**effects.model_dump(exclude_unset=True), **overrides})
        except pydantic.ValidationError as err:
            first = err.errors()[0]
            where = path_text(first["loc"])
            return spec, f"effect `{where}`: {first['msg']}"
    else:
        bad = [k for k, v in overrides.items() if not isinstance(v, bool)]
        if bad:
            return spec, f"effect `{bad[0]}` of a `{spec.type}` component is on or off (true/false)"
        new = {**effects, **overrides}
    return spec.model_copy(update={"effects": new}), None


def user_effect_scope(spec) -> dict[str, sp.Integer]:
    """0/1 factors for the effects declared by a user-defined component."""
    return {name: sp.Integer(1 if on else 0) for name, on in (getattr(spec, "effects", None) or {}).items()}


def summed_terms(b, ctx, spec, field: str, path, scope) -> tuple[sp.Expr, list[str]]:
    """The value of an `Expr | {term: Expr}` field; terms named after an effect that is off
    are dropped (their names are returned)."""
    value = getattr(spec, field)
    if not isinstance(value, dict):
        return b.expr(ctx, value, (*path, field), scope), []
    total, dropped = sp.Integer(0), []
    for term, expr in value.items():
        if not is_on(spec, term):
            dropped.append(term)
            continue
        total += b.expr(ctx, expr, (*path, field, term), scope)
    return total, dropped
