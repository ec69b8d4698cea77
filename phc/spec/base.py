"""The strict pydantic base shared by every input model (the `*Spec` layer).

A model file is data: the spec layer only checks shapes, types and names.
Expressions stay strings (or numbers) here; they are parsed against the names
in scope by :mod:`phc.frontend.elaborate` through the whitelisting parser in
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
    """Base of all spec models: unknown keys are errors, numbers must be finite.

    A key's docstring (the string after its annotation) is its description in the JSON
    Schema. It is read when a schema is written (:func:`attach_docstrings`), not when the
    class is made: pydantic's ``use_attribute_docstrings`` reads every class's source as it
    is defined (about 0.15 s CPU for phc's specs, in every process that validates a file)."""

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        frozen=True,
        populate_by_name=True,
        defer_build=True,
    )


def _own_docstrings(cls: type) -> dict[str, str]:
    """``name: docstring`` of the keys annotated in `cls`'s own body (a string right after an
    annotated name), as pydantic's ``use_attribute_docstrings`` reads them."""
    import ast
    import inspect
    import textwrap

    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):  # no source (an interactive session): no descriptions
        return {}
    body = next((node for node in ast.parse(source).body if isinstance(node, ast.ClassDef)), None)
    found: dict[str, str] = {}
    previous = None
    for node in body.body if body is not None else ():
        if (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)
                and isinstance(previous, ast.AnnAssign) and isinstance(previous.target, ast.Name)):
            found[previous.target.id] = inspect.cleandoc(node.value.value)
        previous = node
    return found


def attach_docstrings() -> None:
    """Give every key of every :class:`SpecModel` subclass defined so far without a
    ``description`` its docstring (from the class that annotates it), and rebuild the
    classes' schemas so that their JSON Schemas carry them. Idempotent."""
    classes, todo = [], [SpecModel]
    while todo:
        cls = todo.pop()
        for sub in cls.__subclasses__():
            if sub not in classes:
                classes.append(sub)
                todo.append(sub)
    docs: dict = {}
    changed = False
    for cls in classes:
        for name, field in cls.model_fields.items():
            if field.description is not None:
                continue
            owner = next((c for c in cls.__mro__ if name in c.__dict__.get("__annotations__", {})), None)
            if owner is None:
                continue
            if owner not in docs:
                docs[owner] = _own_docstrings(owner)
            if name in docs[owner]:
                field.description = docs[owner][name]
                changed = True
    if not changed:
        return
    # rebuilt after the classes their keys hold (pydantic reuses a class's built schema in
    # the schemas of the classes that hold it)
    import typing

    def held(tp, out: set) -> set:
        if isinstance(tp, type) and tp in members:
            out.add(tp)
        for arg in typing.get_args(tp):
            held(arg, out)
        return out

    members = set(classes)
    needs = {cls: {c for f in cls.model_fields.values() for c in held(f.annotation, set())} - {cls}
             for cls in classes}
    done: set = set()

    def rebuild(cls, path=()):
        if cls in done or cls in path:
            return
        for dep in needs[cls]:
            rebuild(dep, (*path, cls))
        cls.model_rebuild(force=True)
        done.add(cls)

    for cls in classes:
        rebuild(cls)


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

