"""User mistakes on the command line are errors with a message, never `internal error`."""

from __future__ import annotations

import json
from pathlib import Path

from phc.cli import main

MODELS = Path(__file__).resolve().parents[1] / "models"


def test_schema_by_short_name(capsys):
    for name in ("model", "scene"):
        assert main(["schema", "--name", name]) == 0
        schema = json.loads(capsys.readouterr().out)
        assert schema["$schema"].startswith("https://json-schema.org/")


def test_animate_of_a_model_with_nothing_planar_is_an_error_not_an_internal_error(tmp_path, capsys):
    code = main(["animate", str(MODELS / "rlc_circuit.yaml"), "-o", str(tmp_path / "a.gif")])
    err = capsys.readouterr().err
    assert code != 0
    assert "internal error" not in err and "nothing planar to draw" in err
