"""JSON Schemas of the model language, generated from the pydantic models.

``python -m phc.spec.export`` (or ``phc schema --write --dir schemas``) writes them; the files in ``schemas/`` are never hand-edited, and a test fails when they are
stale. The schemas are for editors and users' CI; phc itself validates with pydantic.
"""

from __future__ import annotations

import json
from pathlib import Path

from phc.spec.base import EXPR_DESCRIPTION
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


def build_schema(name: str = "model.schema.json") -> dict:
    """The JSON Schema (draft 2020-12) for one of :data:`SCHEMAS`."""
    model = SCHEMAS[name]
    schema = model.model_json_schema(mode="validation")
    _describe_expressions(schema)
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
