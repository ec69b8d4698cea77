"""What a model file says is used, or reported where it is written: settings the chosen
solver ignores, typos in the pieces of an input, and event conditions as the user wrote them."""

from __future__ import annotations

import re
import textwrap
import warnings
from pathlib import Path

import pytest

from phc.cli import main
from phc.errors import IgnoredOptionWarning


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
    assert f"{path}:{line}:{col}: simulation.inputs.drive.effort[0].{typo}: unknown key `{typo}`. " \
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


# ---------------------------------------------------------------------------------------
# accuracy settings of the file that the solver of the run ignores (PHC-W250)


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    """A private front-end cache and key (as in tests/test_fastpath.py)."""
    from phc.codegen import fastpath

    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    monkeypatch.delenv(fastpath.ENV_SWITCH, raising=False)


OSCILLATOR = """\
format_version: 1
components:
  m: {{type: mass, m: 1.0}}
  k: {{type: spring, k: 4.0}}
connections:
  - [m.port, k.port]
simulation:
  t_end: 0.5
  n_out: 11
{settings}
  initial: {{k.x: 0.1}}
"""

RUN = ["--quiet"]


def _simulate(capsys, path: Path, *extra: str) -> list[str]:
    assert main(["simulate", str(path), *RUN, *extra]) == 0
    return [line for line in capsys.readouterr().err.splitlines() if "warning" in line]


def _expected(path: Path, key: str, entry: str, solver: str) -> str:
    line, col = _line_of(path, f"{key}:")
    return f"{path}:{line}:{col}: warning: {entry}: solver `{solver}` ignores `{key}`"


def _hit(path: Path, *extra: str) -> bool:
    from phc.codegen import fastpath
    from phc.cli import build_parser

    return fastpath.lookup(build_parser().parse_args(["simulate", str(path), *RUN, *extra]), {}) is not None


def test_tolerances_in_the_file_with_a_fixed_step_solver_warn_where_written(tmp_path, capsys, cache, monkeypatch):
    import phc.cli.commands

    path = _write(tmp_path, "m.yaml", OSCILLATOR.format(
        settings="  solver: midpoint\n  rtol: 1.0e-6\n  atol: 1.0e-9"))
    for run in range(2):  # the second run starts from the cached front end and says it again
        assert _hit(path) == (run == 1)
        with monkeypatch.context() as patch:
            if run == 1:  # from the record, without reading the file again
                patch.setattr(phc.cli.commands, "_written_options", lambda path: pytest.fail("file read again"))
            lines = _simulate(capsys, path)
        assert len(lines) == 2, lines
        for line, key in zip(lines, ("rtol", "atol")):
            assert line.startswith(_expected(path, key, f"simulation.{key}", "midpoint")), line
            assert "its accuracy is set by `step`" in line and line.endswith("[PHC-W250]")
    # no warning for defaults the file does not write, nor for settings kept for the other solver
    plain = _write(tmp_path, "plain.yaml", OSCILLATOR.format(settings="  solver: midpoint"))
    assert _simulate(capsys, plain) == [] and _simulate(capsys, plain, "--solver", "ida") == []
    both = _write(tmp_path, "both.yaml", OSCILLATOR.format(
        settings="  solver: midpoint\n  step: 0.01\n  rtol: 1.0e-6  # for --solver ida"))
    assert _simulate(capsys, both) == [] and _simulate(capsys, both, "--solver", "ida") == []


def test_tolerances_in_the_file_with_solver_midpoint_on_the_command_line(tmp_path, capsys, cache):
    path = _write(tmp_path, "m.yaml", OSCILLATOR.format(settings="  rtol: 1.0e-6\n  max_order: 2"))
    assert _simulate(capsys, path) == []  # IDA uses both
    # the settings are for the file's own solver (IDA): one line, at the first, not one per setting
    lines = _simulate(capsys, path, "--solver", "midpoint")
    where = _expected(path, "rtol", "", "").split(": warning: ")[0]
    assert lines == [f"{where}: warning: `simulation.rtol`, `simulation.max_order` are for the file's solver `ida`: "
                     "`--solver midpoint` ignores them and steps at the output interval. hint: give `--step` to "
                     "set this run's accuracy [PHC-W250]"], lines
    # a step on the command line says how the fixed-step run's accuracy is set: no warning
    assert _simulate(capsys, path, "--solver", "midpoint", "--step", "0.01") == []
    # a command-line value replaces the file's: the option is reported, not the file's entry
    # (the API's IgnoredOptionWarning, an error in this suite, is what the CLI prints here)
    with warnings.catch_warnings():
        warnings.simplefilter("always", IgnoredOptionWarning)
        lines = _simulate(capsys, path, "--solver", "midpoint", "--rtol", "1e-3")
    max_order = _expected(path, "max_order", "", "").split(": warning: ")[0]
    assert len(lines) == 2 and lines[0].startswith(f"{max_order}: warning: `simulation.max_order` is for the file's "
                                                   "solver `ida`: `--solver midpoint` ignores it"), lines
    assert lines[1] == "phc: warning: solver `midpoint` ignores `rtol` (a fixed-step method: its accuracy is set by " \
                       "`step`)"


def test_a_step_in_the_file_with_ida_warns_where_written(tmp_path, capsys, cache):
    path = _write(tmp_path, "m.yaml", OSCILLATOR.format(settings="  step: 0.01"))
    lines = _simulate(capsys, path)
    assert len(lines) == 1 and lines[0].startswith(_expected(path, "step", "simulation.step", "ida")), lines
    assert "its steps follow `rtol` and `atol`" in lines[0]
    assert _simulate(capsys, path, "--solver", "midpoint") == []


def test_a_scene_setting_is_located_in_the_scene(tmp_path, capsys, cache):
    _write(tmp_path, "m.yaml", OSCILLATOR.format(settings="  atol: 1.0e-9"))
    scene = _write(tmp_path, "s.yaml", """\
        format_version: 1
        model: m.yaml
        solver: midpoint
        accuracy: {rtol: 1.0e-6}
        outputs: {x: k.x}
        """)
    lines = _simulate(capsys, scene)
    assert len(lines) == 2, lines
    assert lines[0].startswith(_expected(scene, "rtol", "accuracy.rtol", "midpoint"))
    assert lines[1].startswith(_expected(tmp_path / "m.yaml", "atol", "simulation.atol", "midpoint"))
