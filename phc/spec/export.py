"""JSON Schemas of the model language, generated from the pydantic models.

``python -m phc.spec.export`` (or ``phc schema --write --dir schemas``) writes them; the files in ``schemas/`` are never hand-edited, and a test fails when they are
stale. The schemas are for editors and users' CI; phc itself validates with pydantic.
"""

from __future__ import annotations

import json
from pathlib import Path

from phc.spec.base import EXPR_DESCRIPTION, IDENTIFIER_PATTERN, RESERVED, attach_docstrings
from phc.spec.model import ModelSpec
from phc.spec.scene import SceneSpec

SCHEMA_BASE_ID = "https://phc.dev/schemas/"
SCHEMAS = {"model.schema.json": ModelSpec, "scene.schema.json": SceneSpec}


def _describe_expressions(node) -> None:
    """Give expression-valued keys without a docstring the generic description."""
    if isinstance(node, dict):
        options = node.get("anyOf")
        if (isinstance(options, list) and "description" not in node and "title" in node
                and {o.get("type") for o in options} >= {"number", "string"}
                and all(o.get("type") in ("integer", "number", "string", "null") for o in options)):
            node["description"] = EXPR_DESCRIPTION
        for value in node.values():
            _describe_expressions(value)
    elif isinstance(node, list):
        for value in node:
            _describe_expressions(value)


def _names(node) -> None:
    """Names (parameters, components, ports, outputs, ...) as phc accepts them: a mapping
    keyed by names gets ``propertyNames`` (pydantic writes ``patternProperties``, which
    would let any other key through), and every name excludes the reserved ones."""
    if isinstance(node, dict):
        pattern_props = node.get("patternProperties")
        if isinstance(pattern_props, dict) and set(pattern_props) == {IDENTIFIER_PATTERN}:
            node.pop("patternProperties")
            node["additionalProperties"] = pattern_props[IDENTIFIER_PATTERN]
            node["propertyNames"] = {"$ref": "#/$defs/Name"}
        elif node.get("type") == "string" and node.get("pattern") == IDENTIFIER_PATTERN:
            del node["type"], node["pattern"]
            node["$ref"] = "#/$defs/Name"
        for value in node.values():
            _names(value)
    elif isinstance(node, list):
        for value in node:
            _names(value)


NAME_SCHEMA = {"type": "string", "pattern": IDENTIFIER_PATTERN, "not": {"enum": sorted(RESERVED)},
               "description": "A name: a letter followed by letters, digits or `_`, not one phc reserves "
                              "(`t`, `pi`, function names, ...)."}


def build_schema(name: str = "model.schema.json") -> dict:
    """The JSON Schema (draft 2020-12) for one of :data:`SCHEMAS`."""
    model = SCHEMAS[name]
    attach_docstrings()  # the keys' docstrings are their descriptions
    schema = model.model_json_schema(mode="validation")
    _describe_expressions(schema)
    _names(schema)
    schema.setdefault("$defs", {})["Name"] = NAME_SCHEMA
    if name == "model.schema.json":
        # The shorthand `- [a.port, b.port]` is accepted by a mode="before" validator
        # that pydantic's schema cannot see; publish it so editors accept it too.
        conn = schema["properties"]["connections"]
        conn["items"] = {"anyOf": [conn["items"], {
            "type": "array", "items": {"type": "string"}, "minItems": 2, "maxItems": 2,
            "description": "Shorthand for `{between: [a, b]}`."}]}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": SCHEMA_BASE_ID + name,
        **schema,
    }


def schema_text(name: str = "model.schema.json") -> str:
    return json.dumps(build_schema(name), indent=2, ensure_ascii=False, sort_keys=False) + "\n"


def write_schemas(directory: str | Path = "schemas") -> list[Path]:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for name in SCHEMAS:
        path = directory / name
        path.write_text(schema_text(name))
        written.append(path)
    return written


def stale_schemas(directory: str | Path = "schemas") -> list[str]:
    """Names of schema files in `directory` that differ from the generated ones."""
    out = []
    for name in SCHEMAS:
        path = Path(directory) / name
        if not path.is_file() or path.read_text() != schema_text(name):
            out.append(str(path))
    return out


if __name__ == "__main__":
    for p in write_schemas():
        print(f"wrote {p}")
