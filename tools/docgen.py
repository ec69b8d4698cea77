"""Reference pages generated from the code (used by the MkDocs hook `tools/mkdocs_hooks.py`).

* :func:`model_reference`, :func:`components_reference`, :func:`scene_reference`: the model
  and scene languages, from the JSON Schemas that :mod:`phc.spec.export` builds from the
  pydantic models — the same source as ``schemas/*.json`` and phc's own validation;
* :func:`cli_reference`: every ``phc`` subcommand and option, from the argparse parser of
  :mod:`phc.cli`;
* :func:`diagnostic_codes`: the codes ``PHC-Exxx`` / ``PHC-Wxxx`` that phc's sources emit
  (the diagnostics page documents each one; ``tests/test_docs.py`` checks it does).

Nothing here is typed by hand except the wording around the generated tables.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXPR_DESCRIPTION_START = "A number or an expression string"


# ---------------------------------------------------------------------------------------
# JSON Schema -> Markdown


def _anchor(name: str) -> str:
    return name.lower()


_REST_LITERAL = re.compile(r"``(?!`)(.+?)(?<!`)``(?!`)", re.S)
"""A reST inline literal ``x`` (docstrings), not a Markdown fence."""


def _inline(text: str) -> str:
    """reST inline literals as Markdown code spans: ``x`` → `x`."""
    return _REST_LITERAL.sub(lambda m: f"`{m.group(1)}`", text)


def _esc(text: str) -> str:
    """Text for one table cell: one line, pipes escaped, reST literals as code spans."""
    return _inline(" ".join(str(text).split())).replace("|", "\\|")


class _SchemaDoc:
    """Renders the object definitions of one JSON Schema."""

    def __init__(self, schema: dict, titles: dict[str, str] | None = None, anchors: dict[str, str] | None = None):
        self.schema = schema
        self.defs = schema.get("$defs", {})
        self.titles = titles or {}
        self.anchors = anchors or {}
        self.wanted: list[str] = []  # nested definitions referenced by rendered ones

    def title(self, name: str) -> str:
        return self.titles.get(name, name)

    def link(self, ref: str) -> str:
        name = ref.rsplit("/", 1)[-1]
        if name not in self.wanted:
            self.wanted.append(name)
        return f"[{self.title(name)}](#{self.anchor(name)})"

    def anchor(self, name: str) -> str:
        return self.anchors.get(name, _anchor(name))

    def type_text(self, prop: dict) -> tuple[str, bool]:
        """(type in words, accepts null)."""
        if "$ref" in prop:
            return self.link(prop["$ref"]), False
        if "anyOf" in prop or "oneOf" in prop:
            options = prop.get("anyOf") or prop.get("oneOf")
            kinds = {o.get("type") for o in options}
            nullable = "null" in kinds
            options = [o for o in options if o.get("type") != "null"]
            if {"number", "string"} <= {o.get("type") for o in options} and all(
                    o.get("type") in ("integer", "number", "string") for o in options):
                return "expression", nullable
            texts = []
            scalar = [o for o in options if o.get("type") in ("integer", "number", "string") and len(o) == 1]
            if {o["type"] for o in scalar} == {"integer", "number", "string"}:  # an expression, or else
                texts.append("expression")
                options = [o for o in options if o not in scalar]
            for o in options:
                text, _ = self.type_text(o)
                if text not in texts:
                    texts.append(text)
            return " or ".join(texts), nullable
        if "const" in prop:
            return f"`{json.dumps(prop['const'])}`", False
        if "enum" in prop:
            return "one of " + ", ".join(f"`{v}`" for v in prop["enum"]), False
        kind = prop.get("type")
        if kind == "array":
            if "prefixItems" in prop:
                items = [self.type_text(i)[0] for i in prop["prefixItems"]]
                return f"list ({', '.join(items)})", False
            item = prop.get("items")
            if not item:
                return "list", False
            text, _ = self.type_text(item)
            if text.startswith("list of expression"):
                return "matrix (list of rows of expressions)", False
            return f"list of {text}", False
        if kind == "object":
            value = prop.get("additionalProperties")
            keys = prop.get("propertyNames", {})
            key_text = "name"
            if "enum" in keys:
                key_text = "/".join(f"`{k}`" for k in keys["enum"])
            if isinstance(value, dict):
                text, _ = self.type_text(value)
                return f"mapping {key_text} → {text}", False
            return "mapping", False
        if isinstance(kind, list):
            return " or ".join(kind), "null" in kind
        return {"integer": "integer", "number": "number", "string": "string", "boolean": "`true`/`false`",
                None: "any"}.get(kind, str(kind)), False

    @staticmethod
    def bounds(prop: dict) -> str:
        out = []
        for key, sym in (("minimum", "≥"), ("exclusiveMinimum", ">"), ("maximum", "≤"), ("exclusiveMaximum", "<")):
            if key in prop:
                out.append(f"{sym} {prop[key]:g}" if isinstance(prop[key], (int, float)) else f"{sym} {prop[key]}")
        if "minItems" in prop:
            out.append(f"at least {prop['minItems']} entries")
        if "maxItems" in prop and prop.get("maxItems") != prop.get("minItems"):
            out.append(f"at most {prop['maxItems']} entries")
        if "minProperties" in prop:
            out.append(f"at least {prop['minProperties']} entries")
        return ", ".join(out)

    def table(self, definition: dict, skip: tuple[str, ...] = (), types: dict[str, str] | None = None) -> str:
        props = definition.get("properties", {})
        required = set(definition.get("required", ()))
        rows = ["| key | type | default | description |", "|---|---|---|---|"]
        for key, prop in props.items():
            if key in skip:
                continue
            text, nullable = (types[key], False) if types and key in types else self.type_text(prop)
            bounds = self.bounds(prop)
            if bounds:
                text += f" ({bounds})"
            if key in required:
                default = "**required**"
            elif "default" in prop:
                value = prop["default"]
                default = "—" if value is None else f"`{json.dumps(value, ensure_ascii=False)}`"
            else:
                default = "—"
            desc = prop.get("description", "")
            if desc.startswith(EXPR_DESCRIPTION_START):
                desc = ""  # the generic text of the expression type, said once on the page
            rows.append(f"| `{key}` | {_esc(text)} | {_esc(default)} | {_esc(desc)} |")
        return "\n".join(rows)

    def section(self, name: str, level: int = 3, heading: str | None = None, skip: tuple[str, ...] = ()) -> str:
        definition = self.defs[name]
        title = heading or self.title(name)
        parts = [f"{'#' * level} {title} {{#{self.anchor(name)}}}", ""]
        desc = definition.get("description")
        if desc:
            parts += [_dedent_description(desc), ""]
        if definition.get("properties"):
            parts += [self.table(definition, skip), ""]
        return "\n".join(parts)

    def nested_sections(self, done: set[str], level: int = 3) -> str:
        out = []
        while True:
            todo = [n for n in self.wanted if n not in done]
            if not todo:
                break
            for name in todo:
                done.add(name)
                out.append(self.section(name, level))
        return "\n".join(out)


def _dedent_description(text: str) -> str:
    """A class docstring as Markdown: reST ``literal`` → `literal` (outside the code
    blocks), ``::`` blocks fenced."""
    lines = text.splitlines()
    out, in_block = [], False
    prose: list[str] = []  # the lines since the last code block, converted together

    def flush() -> None:
        out.append(_inline("\n".join(prose)))
        prose.clear()

    for line in lines:
        if in_block:
            if line.strip() and not line.startswith("    "):
                while out and not out[-1].strip():
                    out.pop()
                out.append("```")
                out.append("")
                in_block = False
            elif line.strip() or out[-1] != "```text":  # no blank first line in the block
                out.append(line[4:] if line.startswith("    ") else line)
                continue
            else:
                continue
        if line.rstrip().endswith("::"):
            prose.append(line.rstrip()[:-1] if not line.rstrip().endswith(" ::") else line.rstrip()[:-3])
            flush()
            out.append("")
            out.append("```text")
            in_block = True
            continue
        prose.append(line)
    if in_block:
        while out and not out[-1].strip():
            out.pop()
        out.append("```")
    elif prose:
        flush()
    return "\n".join(out)


def _schema(name: str) -> dict:
    from phc.spec.export import build_schema

    return build_schema(name)


def component_types() -> dict[str, str]:
    """`type:` value → name of its definition in the model schema."""
    mapping = _schema("model.schema.json")["properties"]["components"]["additionalProperties"]["discriminator"]["mapping"]
    return {key: ref.rsplit("/", 1)[-1] for key, ref in sorted(mapping.items())}


def components_reference() -> str:
    """Every component type with its keys, from the model schema."""
    schema = _schema("model.schema.json")
    types = component_types()
    titles = {definition: f"`{key}`" for key, definition in types.items()}
    anchors = {definition: key.replace("_", "-") for key, definition in types.items()}
    doc = _SchemaDoc(schema, titles, anchors)
    parts = [
        "Every key of every component type, generated from the pydantic models of `phc/spec/` "
        "(the same source as `schemas/model.schema.json`). *expression* means a number or a "
        "string in the [expression language](model-language.md#expressions): "
        "" + _esc(_expr_description(schema)),
        "",
        "| `type` | what it is |",
        "|---|---|",
    ]
    for key, definition in types.items():
        first = _esc(schema["$defs"][definition].get("description", "").split("\n\n")[0])
        first = first[:-2] + "." if first.endswith("::") else first
        parts.append(f"| [`{key}`](#{anchors[definition]}) | {first} |")
    parts.append("")
    parts.append("## Component types")
    parts.append("")
    for key, definition in types.items():
        parts.append(doc.section(definition, 3, skip=("type",)))
    parts.append("## Objects used by the component types")
    parts.append("")
    parts.append(doc.nested_sections(set(types.values()), 3))
    return "\n".join(parts)


def _expr_description(schema: dict) -> str:
    for definition in schema.get("$defs", {}).values():
        for prop in definition.get("properties", {}).values():
            desc = prop.get("description", "")
            if desc.startswith(EXPR_DESCRIPTION_START):
                return desc
    return ""


def model_reference() -> str:
    """The top level of a model file and the objects it uses (components excluded)."""
    schema = _schema("model.schema.json")
    doc = _SchemaDoc(schema)
    types = set(component_types().values())
    top = {"description": schema.get("description", ""), "properties": schema["properties"],
           "required": schema.get("required", [])}
    component = "mapping name → component (one of the [component types](components.md))"
    parts = ["### Top level", "", _dedent_description(top["description"]), "",
             doc.table(top, types={"components": component}), ""]
    parts.append(doc.nested_sections(set(types), 3))
    return "\n".join(parts)


def scene_reference() -> str:
    """The keys of a scene file, from the scene schema."""
    schema = _schema("scene.schema.json")
    doc = _SchemaDoc(schema)
    top = {"description": schema.get("description", ""), "properties": schema["properties"],
           "required": schema.get("required", [])}
    parts = ["### Top level", "", _dedent_description(top["description"]), "", doc.table(top), ""]
    parts.append(doc.nested_sections(set(), 3))
    return "\n".join(parts)


# ---------------------------------------------------------------------------------------
# argparse -> Markdown


def _option_row(action: argparse.Action) -> str | None:
    if isinstance(action, argparse._HelpAction) or action.help == argparse.SUPPRESS:
        return None
    if action.option_strings:
        names = ", ".join(f"`{s}`" for s in action.option_strings)
        if action.nargs != 0:
            metavar = action.metavar or (("{" + ",".join(map(str, action.choices)) + "}") if action.choices
                                         else action.dest.upper())
            if isinstance(metavar, tuple):
                metavar = " ".join(metavar)
            names += f" `{metavar}`"
    else:
        names = f"`{action.metavar or action.dest}`"
    help_text = action.help or ""
    if action.choices and not action.option_strings and not isinstance(action, argparse._SubParsersAction):
        help_text += (" " if help_text else "") + "(one of " + ", ".join(f"`{c}`" for c in action.choices) + ")"
    default = action.default
    if (action.option_strings and action.nargs != 0 and default not in (None, argparse.SUPPRESS)
            and not isinstance(default, (bool, list)) and "default" not in help_text):
        help_text += f" (default `{default}`)"
    if isinstance(action, argparse._AppendAction) and "repeatable" not in help_text:
        help_text += " (repeatable)"
    return f"| {names} | {_esc(help_text)} |"


def cli_reference() -> str:
    """`phc --help` and every subcommand's options, from :func:`phc.cli.build_parser`."""
    from phc.cli import build_parser

    parser = build_parser()
    parser.prog = "phc"
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {choice.dest: choice.help for choice in sub._choices_actions}
    parts = ["```text", parser.format_usage().strip(), "```", ""]
    parts += ["| command | what it does |", "|---|---|"]
    for name in sub.choices:
        parts.append(f"| [`phc {name}`](#phc-{name}) | {_esc(helps.get(name, ''))} |")
    parts.append("")
    rows = [r for r in (_option_row(a) for a in parser._actions if not isinstance(a, argparse._SubParsersAction)) if r]
    if rows:
        parts += ["Options of `phc` itself:", "", "| option | meaning |", "|---|---|", *rows, ""]
    for name, subparser in sub.choices.items():
        parts += [f"## `phc {name}` {{#phc-{name}}}", ""]
        if helps.get(name):
            parts += [helps[name][0].upper() + helps[name][1:] + ".", ""]
        usage = subparser.format_usage().strip()
        usage = re.sub(r"^usage: ", "", usage)
        parts += ["```text", " ".join(usage.split()), "```", ""]
        rows = [r for r in (_option_row(a) for a in subparser._actions) if r]
        if rows:
            parts += ["| argument | meaning |", "|---|---|", *rows, ""]
        nested = [a for a in subparser._actions if isinstance(a, argparse._SubParsersAction)]
        for action in nested:
            for child_name, child in action.choices.items():
                child_usage = " ".join(re.sub(r"^usage: ", "", child.format_usage().strip()).split())
                parts += [f"`{child_usage}`", ""]
    return "\n".join(parts)


# ---------------------------------------------------------------------------------------
# diagnostic codes

CODE_RE = re.compile(r"PHC-[EW]\d{3}")


def diagnostic_codes() -> dict[str, list[str]]:
    """Every code phc's sources mention → the source files that mention it."""
    out: dict[str, list[str]] = {}
    for path in sorted((ROOT / "phc").rglob("*.py")):
        for code in sorted(set(CODE_RE.findall(path.read_text(encoding="utf-8")))):
            out.setdefault(code, []).append(str(path.relative_to(ROOT)))
    return dict(sorted(out.items()))


GENERATORS = {
    "components": components_reference,
    "model-file": model_reference,
    "scene-file": scene_reference,
    "cli": cli_reference,
}
"""Marker name in a docs page (``<!-- generate: NAME -->``) → function returning Markdown."""
