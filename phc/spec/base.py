"""The strict pydantic base shared by every input model (the `*Spec` layer).

A model file is data: the spec layer only checks shapes, types and names.
Expressions stay strings (or numbers) here; they are parsed against the names
in scope by :mod:`phc.elaborate` through the whitelisting parser in
:mod:`phc.spec.expressions`, never by ``eval``.
"""

from __future__ import annotations

import re
from typing import Annotated, Union

from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, StrictFloat, StrictInt,
                      WithJsonSchema)
from pydantic_core import PydanticCustomError

from phc.spec.expressions import FUNCTIONS

IDENTIFIER_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
"""A name, matched with ``fullmatch`` (``$`` would accept a trailing newline)."""

RESERVED: dict[str, str] = {
    "t": "time",
    "pi": "the constant π",
    "H": "the total energy, an output of every model",
    **{name: "a function of the expression language" for name in FUNCTIONS},
}
"""Names phc gives a meaning in expressions and outputs; a model may not declare them."""


class SpecModel(BaseModel):
    """Base of all spec models: unknown keys are errors, numbers must be finite."""

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        frozen=True,
        use_attribute_docstrings=True,
        populate_by_name=True,
    )


def _check_identifier(name: str) -> str:
    if not IDENTIFIER_RE.fullmatch(name):
        shown = f"`{name}`" if name.isprintable() else repr(name)  # a newline stays visible
        raise ValueError(f"{shown} is not a valid name; use a letter followed by letters, digits or `_`")
    if name in RESERVED:
        raise ValueError(f"`{name}` is reserved by phc ({RESERVED[name]}); choose another name")
    return name


IDENTIFIER_PATTERN = "^[A-Za-z][A-Za-z0-9_]*$"
""":data:`IDENTIFIER_RE` as the JSON Schema states it (with the reserved names excluded,
:func:`phc.spec.export.build_schema`)."""

Identifier = Annotated[str, AfterValidator(_check_identifier),
                       WithJsonSchema({"type": "string", "pattern": IDENTIFIER_PATTERN})]
"""A name: a letter followed by letters, digits or underscores."""

EXPR_DESCRIPTION = ("A number or an expression string over parameters, states and `t` "
                    "(operators + - * / **, functions sin cos tan exp log sqrt abs min max atan2 ifelse ...).")
"""What the JSON Schema says of an expression-valued key that has no description of its own
(:func:`phc.spec.export.build_schema` adds it; a key's docstring is its description)."""

Expr = Annotated[Union[StrictInt, StrictFloat, str], Field()]
"""A number, or an expression string parsed by the whitelisting parser. (No description
here: it would replace the docstrings of the keys that use it.)"""


def _unit_text(value):
    """`unit: 1` (a YAML number) is the dimensionless unit, as `unit: "1"` is; any other
    number is refused with that hint (a unit is text: `N/m`)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if value == 1:
            return "1"
        raise PydanticCustomError(
            "PHC-E013", f"expected a unit (text such as `N/m`), got the number `{value:g}` hint: the only number "
            "that is a unit is `1` (dimensionless)")
    return value

Unit = Annotated[str, BeforeValidator(_unit_text), WithJsonSchema({
    "anyOf": [{"type": "string"}, {"const": 1}],
})]
"""A unit: text read by pint (`N/m`, `kg*m^2`, `rad/s`), or `1` (also as a YAML number) for a
dimensionless quantity (docs/units.md)."""

Vector = list[Expr]
Matrix = list[list[Expr]]

Switch = Annotated[bool, WithJsonSchema({
    "anyOf": [{"type": "boolean"}, {"enum": ["on", "off", "yes", "no", "true", "false"]}],
    "description": "on or off (YAML 1.1 reads `on`/`off` as booleans, YAML 1.2 tools as strings: both are accepted)",
})]
"""A switch written `on`/`off` (or `true`/`false`). phc's YAML reader turns `on`/`off` into
booleans as YAML 1.1 does; editors and CI checkers that read YAML 1.2 see the strings, so
the JSON Schema accepts both."""

