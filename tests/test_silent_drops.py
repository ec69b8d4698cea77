"""What a model file says is used, or reported where it is written: settings the chosen
solver ignores, typos in the pieces of an input, and event conditions as the user wrote them."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import pytest

from phc.cli import main


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text).lstrip())
    return path


def _line_of(path: Path, needle: str) -> tuple[int, int]:
    """1-based line and column of the first occurrence of `needle` in the file."""
    for i, line in enumerate(path.read_text().splitlines(), 1):
        if needle in line:
            return i, line.index(needle) + 1
    raise AssertionError(f"{needle!r} not in {path}")


# ---------------------------------------------------------------------------------------
# a typo in an input piece names the unknown key


PIECES = """\
format_version: 1
components:
  m: {{type: mass, m: 1.0}}
ports:
  drive: {{port: m.port}}
simulation:
  t_end: 1.0
  inputs:
    drive:
      effort:
        - {piece}
        - {{value: 0.0}}
"""


@pytest.mark.parametrize("piece, typo, meant, missing", [
    ("{until: 0.5, valeu: 1.0}", "valeu", "value", ["value"]),
    ("{untl: 0.5, value: 1.0}", "untl", "until", []),
])
def test_typo_in_an_input_piece_is_an_unknown_key_of_the_piece(tmp_path, capsys, piece, typo, meant, missing):
    path = _write(tmp_path, "m.yaml", PIECES.format(piece=piece))
    assert main(["validate", str(path)]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    line, col = _line_of(path, typo)
    assert f"{path}:{line}:{col}: simulation.inputs.drive.effort.0.{typo}: unknown key `{typo}`. " \
           f"hint: did you mean `{meant}`? [PHC-E010]" in lines
    # nothing about the keys of a table (`file`, `column`), nor the correct keys called unknown
    assert not [x for x in lines if "`file`" in x or "`column`" in x], lines
    unknown = re.findall(r"unknown key `([^`]+)`", "\n".join(lines))
    assert unknown == [typo], lines
    assert sorted(re.findall(r"missing required key `([^`]+)`", "\n".join(lines))) == missing
    assert len(lines) == 1 + len(missing)
    _signals_read_as_before()


def _signals_read_as_before():
    """Pieces, tables and vectors of signals still read as they did."""
    from phc.spec.model import InputSpec, PieceSpec, TableSpec

    pieces = InputSpec.model_validate({"effort": [{"until": 0.5, "value": 1}, {"value": "sin(t)"}]}).effort
    assert [type(x) for x in pieces] == [PieceSpec, PieceSpec] and pieces[1].value == "sin(t)"
    table = InputSpec.model_validate({"flow": {"file": "u.csv", "column": "u"}}).flow
    assert isinstance(table, TableSpec) and table.column == "u"
    vector = InputSpec.model_validate({"effort": [0, "t", [{"value": 2}],
                                                  {"file": "u.csv", "column": "v"}]}).effort
    assert vector[:2] == [0, "t"] and isinstance(vector[2][0], PieceSpec) and isinstance(vector[3], TableSpec)
    tables = InputSpec.model_validate({"effort": [{"file": "u.csv", "column": "a"},
                                                  {"file": "u.csv", "column": "b"}]}).effort
    assert [t.column for t in tables] == ["a", "b"]
