"""Tests for the published JSON Schema of the model language (:mod:`phc.spec.export`,
``phc schema`` in :mod:`phc.cli`).

The schema in ``schemas/`` must be up to date with the pydantic models, the check must
detect a stale copy, and the independent :mod:`jsonschema` validator must agree with
pydantic on the shipped models and on a broken one.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import jsonschema
import pydantic
import pytest
import yaml

from phc.cli import main
from phc.spec import ModelSpec
from phc.spec.export import SCHEMAS, schema_text

REPO = Path(__file__).resolve().parents[1]
SCHEMA_DIR = REPO / "schemas"
SCHEMA_FILE = SCHEMA_DIR / "model.schema.json"
MODEL_FILES = sorted((REPO / "models").glob("*.yaml"))
SCHEMA_COMMENT = "# yaml-language-server: $schema="


def load_yaml(path: Path):
    return yaml.safe_load(path.read_text())


def validator() -> jsonschema.Draft202012Validator:
    return jsonschema.Draft202012Validator(json.loads(SCHEMA_FILE.read_text()))




# -- phc schema --check ------------------------------------------------------------


def test_schema_check_passes_on_the_repository(capsys):
    assert main(["schema", "--check", "--dir", str(SCHEMA_DIR)]) == 0
    captured = capsys.readouterr()
    assert "up to date" in captured.out
    assert captured.err == ""


def test_schema_check_detects_a_stale_copy(tmp_path, capsys):
    schema = json.loads(SCHEMA_FILE.read_text())
    schema["description"] = "edited by hand"
    (tmp_path / "model.schema.json").write_text(json.dumps(schema, indent=2) + "\n")
    (tmp_path / "scene.schema.json").write_text((SCHEMA_DIR / "scene.schema.json").read_text())
    assert main(["schema", "--check", "--dir", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "model.schema.json" in err[0]
    assert f"phc schema --write --dir {tmp_path}" in err[0]


def test_schema_check_detects_a_missing_file(tmp_path, capsys):
    assert main(["schema", "--check", "--dir", str(tmp_path)]) == 1
    assert f"phc schema --write --dir {tmp_path}" in capsys.readouterr().err


def test_schema_write_then_check_round_trips(tmp_path, capsys):
    assert main(["schema", "--write", "--dir", str(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(SCHEMAS)
    for name in SCHEMAS:
        assert (tmp_path / name).read_text() == schema_text(name)
    assert main(["schema", "--check", "--dir", str(tmp_path)]) == 0


def test_schema_is_a_valid_draft_2020_12_schema():
    schema = json.loads(SCHEMA_FILE.read_text())
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    jsonschema.Draft202012Validator.check_schema(schema)


# -- models against the schema -----------------------------------------------------


@pytest.mark.parametrize("path", [
    pytest.param(p, id=p.stem)
    for p in MODEL_FILES
])
def test_shipped_model_validates_against_the_json_schema(path):
    errors = [f"{list(e.absolute_path)}: {e.message}" for e in validator().iter_errors(load_yaml(path))]
    assert errors == []


@pytest.mark.parametrize("path", MODEL_FILES, ids=[p.stem for p in MODEL_FILES])
def test_shipped_model_validates_with_pydantic(path):
    spec = ModelSpec.model_validate(load_yaml(path))
    assert spec.name == path.stem


@pytest.mark.parametrize("path", MODEL_FILES, ids=[p.stem for p in MODEL_FILES])
def test_shipped_model_declares_the_schema_on_its_first_line(path):
    first = path.read_text().splitlines()[0]
    assert first.startswith(SCHEMA_COMMENT)
    target = (path.parent / first[len(SCHEMA_COMMENT):].strip()).resolve()
    assert target == SCHEMA_FILE.resolve()


@pytest.mark.parametrize("where", ["top", "component", "simulation"])
def test_unknown_key_fails_both_jsonschema_and_pydantic(where):
    data = copy.deepcopy(load_yaml(REPO / "models" / "pendulum.yaml"))  # no connection shorthand
    assert list(validator().iter_errors(data)) == []
    if where == "top":
        data["colour"] = "red"
    elif where == "component":
        data["components"]["pendulum"]["mass"] = 1.0
    else:
        data["simulation"]["t_stop"] = 3.0
    assert list(validator().iter_errors(data)) != []
    with pytest.raises(pydantic.ValidationError):
        ModelSpec.model_validate(data)


@pytest.mark.parametrize("where, name", [("parameters", "2x"), ("parameters", "pi"), ("components", "my-mass"),
                                         ("outputs", "t"), ("parameters", "sin")])
def test_a_name_phc_refuses_fails_the_json_schema_too(where, name):
    """Names are a letter followed by letters, digits or `_`, and not reserved: the schema
    said only `object`, so a user's CI accepted `my-mass` or `pi` that phc refuses."""
    data = copy.deepcopy(load_yaml(REPO / "models" / "pendulum.yaml"))
    if where == "parameters":
        data["parameters"][name] = 1.0
    elif where == "components":
        data["components"][name] = {"type": "mass", "m": 1.0}
    else:
        data["simulation"]["outputs"][name] = "pendulum.x"
    assert list(validator().iter_errors(data)) != []
    with pytest.raises(pydantic.ValidationError):
        ModelSpec.model_validate(data)


def test_wrong_type_fails_both_jsonschema_and_pydantic():
    data = copy.deepcopy(load_yaml(REPO / "models" / "pendulum.yaml"))
    data["simulation"]["n_out"] = "many"
    assert list(validator().iter_errors(data)) != []
    with pytest.raises(pydantic.ValidationError):
        ModelSpec.model_validate(data)


# -- scenes against the scene schema ----------------------------------------------------

SCENE_SCHEMA_FILE = SCHEMA_DIR / "scene.schema.json"
SCENE_FILES = sorted((REPO / "models" / "scenes").glob("*.yaml"))


def test_scene_schema_is_a_valid_draft_2020_12_schema():
    jsonschema.Draft202012Validator.check_schema(json.loads(SCENE_SCHEMA_FILE.read_text()))


@pytest.mark.parametrize("path", SCENE_FILES, ids=[p.stem for p in SCENE_FILES])
def test_shipped_scene_validates_against_the_scene_schema_and_declares_it(path):
    schema = json.loads(SCENE_SCHEMA_FILE.read_text())
    errors = [e.message for e in jsonschema.Draft202012Validator(schema).iter_errors(load_yaml(path))]
    assert errors == []
    first = path.read_text().splitlines()[0]
    assert first.startswith(SCHEMA_COMMENT)
    assert (path.parent / first[len(SCHEMA_COMMENT):].strip()).resolve() == SCENE_SCHEMA_FILE.resolve()


def test_scene_unknown_key_fails_both_jsonschema_and_pydantic():
    from phc.spec.scene import SceneSpec

    data = load_yaml(SCENE_FILES[0])
    data["effectz"] = {}
    schema = json.loads(SCENE_SCHEMA_FILE.read_text())
    assert list(jsonschema.Draft202012Validator(schema).iter_errors(data))
    with pytest.raises(pydantic.ValidationError):
        SceneSpec.model_validate(data)


def test_validating_a_model_file_reads_no_spec_source(tmp_path):
    """The keys' docstrings are the schema's descriptions, read when a schema is written
    (:func:`phc.spec.base.attach_docstrings`), not when the spec classes are made: reading
    every class's source (pydantic's ``use_attribute_docstrings``) cost every process that
    validates a file about 0.15 s CPU. In a fresh process, loading a model reads no source
    file of phc.spec (``inspect`` reads sources through ``linecache``)."""
    import subprocess
    import sys

    probe = ("import json, linecache, sys\n"
             "from phc.spec.load import load_spec\n"
             "spec, _, diags = load_spec(sys.argv[1])\n"
             "print(json.dumps({'ok': spec is not None, 'read': sorted(f for f in linecache.cache if 'spec' in f)}))\n")
    done = subprocess.run([sys.executable, "-c", probe, str(REPO / "models" / "flexible_slider_crank.yaml")],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    assert seen["ok"] and seen["read"] == []
