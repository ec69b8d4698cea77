"""The JSON Schemas accept the shipped files as a YAML 1.2 tool reads them (editors, CI
checkers): there `on`/`off` are strings, not booleans."""

from __future__ import annotations

import json
import re
from pathlib import Path

import jsonschema
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


class Yaml12Loader(yaml.SafeLoader):
    """PyYAML with YAML 1.2's booleans: only true/false (on/off/yes/no stay strings)."""


Yaml12Loader.yaml_implicit_resolvers = {
    key: [(tag, rx) for tag, rx in resolvers if tag != "tag:yaml.org,2002:bool"]
    for key, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
Yaml12Loader.add_implicit_resolver("tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
                                   list("tTfF"))


def _files():
    return sorted(ROOT.glob("models/*.yaml")) + sorted(ROOT.glob("models/scenes/*.yaml"))


@pytest.mark.parametrize("path", _files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_shipped_files_validate_as_yaml_1_2(path):
    data = yaml.load(path.read_text(), Loader=Yaml12Loader)
    name = "scene" if path.parent.name == "scenes" else "model"
    schema = json.loads((ROOT / "schemas" / f"{name}.schema.json").read_text())
    jsonschema.validate(data, schema)


def test_the_yaml_1_2_loader_reads_off_as_a_string():
    assert yaml.load("a: off", Loader=Yaml12Loader) == {"a": "off"}
