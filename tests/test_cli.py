"""Tests for the command line :mod:`phc.cli` (``phc validate | compile | simulate``), run
in-process through :func:`phc.cli.main`, plus ``python -m phc`` and the pre-commit hook
definition ``.pre-commit-hooks.yaml``.

Exit codes: 0 success, 1 model errors, 2 usage errors; a user mistake is one line on
stderr, never a traceback.
"""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import yaml

import phc
from phc.cli import main
from time_limits import SUBPROCESS_TIMEOUT

REPO = Path(__file__).resolve().parents[1]
MODELS = REPO / "models"
MODEL_FILES = sorted(MODELS.glob("*.yaml"))
MSD = str(MODELS / "mass_spring_damper.yaml")
PENDULUM = str(MODELS / "pendulum.yaml")


def error_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


# -- validate ----------------------------------------------------------------------


def test_validate_all_shipped_models(capsys):
    assert main(["validate", *map(str, MODEL_FILES)]) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert [line.split(": ok ")[0] for line in lines] == [str(p) for p in MODEL_FILES]
    n = len(MODEL_FILES)  # the summary of several files goes to stderr
    # one shipped model is wired against the drawn sign on purpose, the example of the sign
    # hint (docs/signs.md, tests/test_cli_multi.py): validate says so, as check does
    *hints, summary = captured.err.splitlines()
    assert [(h.split(":")[0], h.split("[")[-1]) for h in hints] == [
        (str(MODELS / "thermal_ladder.yaml"), "PHC-W230]")]
    assert summary == f"phc validate: {n} files, {n} ok, 0 failed; 0 error(s), 1 warning(s)"


def test_validate_json_reports_every_file(capsys):
    assert main(["validate", "--format", "json", *map(str, MODEL_FILES)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [(entry["file"], entry["valid"]) for entry in report] == [(str(p), True) for p in MODEL_FILES]


def test_validate_reports_a_broken_model_with_one_located_line(tmp_path, capsys):
    text = (MODELS / "pendulum.yaml").read_text().replace("    q: [x, y]\n", "    q: [x, y]\n    colour: red\n")
    broken = tmp_path / "broken.yaml"
    broken.write_text(text)
    line_no = text.splitlines().index("    colour: red") + 1
    assert main(["validate", str(broken)]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    [line] = error_lines(captured.err)
    assert re.match(rf"^{re.escape(str(broken))}:{line_no}:\d+: .*colour.*\[PHC-E010\]$", line)


def test_a_scene_names_its_model_file_by_a_normalized_relative_path(tmp_path, capsys, monkeypatch):
    """`model: ../m.yaml` in scenes/s.yaml: messages about the model say `m.yaml`, not
    `scenes/../m.yaml`; missing, it is looked for at `other.yaml`; through a symbolic link
    `..` leads elsewhere, and the path stays as written."""
    text = (MODELS / "pendulum.yaml").read_text().replace("    q: [x, y]\n", "    q: [x, y]\n    colour: red\n")
    (tmp_path / "m.yaml").write_text(text)
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "s.yaml").write_text("format_version: 1\nmodel: ../m.yaml\n")
    (tmp_path / "scenes" / "gone.yaml").write_text("format_version: 1\nmodel: ../other.yaml\n")
    monkeypatch.chdir(tmp_path)
    assert main(["validate", "scenes/s.yaml"]) == 1
    [line] = error_lines(capsys.readouterr().err)
    assert line.startswith("m.yaml:") and "[PHC-E010]" in line, line
    assert main(["validate", "scenes/gone.yaml"]) == 1
    [line] = error_lines(capsys.readouterr().err)
    assert "(looked for `other.yaml`)" in line, line
    elsewhere = tmp_path / "far" / "deep"
    elsewhere.mkdir(parents=True)
    (elsewhere / "s.yaml").write_text("format_version: 1\nmodel: ../m.yaml\n")
    (tmp_path / "far" / "m.yaml").write_text(text)
    (tmp_path / "link").symlink_to(elsewhere)
    assert main(["validate", "link/s.yaml"]) == 1
    [line] = error_lines(capsys.readouterr().err)
    assert line.startswith("link/../m.yaml:"), line  # far/m.yaml, not the m.yaml beside `link`


@pytest.mark.parametrize("command", ["validate", "compile", "simulate"])
def test_nonexistent_file_is_one_located_line(command, tmp_path, capsys):
    missing = str(tmp_path / "nosuch.yaml")
    assert main([command, missing]) == 1
    captured = capsys.readouterr()
    [line] = error_lines(captured.err)
    assert re.match(rf"^{re.escape(missing)}:\d+:\d+: .*\[PHC-E004\]$", line)
    assert "Traceback" not in captured.err + captured.out


# -- compile -----------------------------------------------------------------------


def test_compile_writes_the_generated_module(tmp_path, capsys):
    out_dir = tmp_path / "generated"
    assert main(["compile", MSD, "-o", str(out_dir)]) == 0
    target = out_dir / "mass_spring_damper.py"
    assert sorted(p.name for p in out_dir.iterdir()) == ["mass_spring_damper.py"]
    assert target.read_text() == phc.compile_model(MSD).source
    assert str(target) in capsys.readouterr().out


def test_compile_of_a_model_with_a_very_long_name_writes_a_shortened_file_name(tmp_path, capsys):
    """A 300-letter model name (a valid name) ended in an internal error: a file name is at
    most 255 bytes. The module's name is shortened, with a hash of the full name."""
    text = Path(MSD).read_text().replace("name: mass_spring_damper", "name: " + "a" * 300)
    assert "a" * 300 in text
    model = tmp_path / "long.yaml"
    model.write_text(text)
    assert main(["compile", str(model), "-o", str(tmp_path / "out")]) == 0
    (written,) = (tmp_path / "out").iterdir()
    assert written.name.startswith("a" * 100) and len(written.name) <= 125 and written.suffix == ".py"
    assert written.read_text() == phc.compile_model(model).source


# -- simulate ----------------------------------------------------------------------

SUMMARY_KEYS = {"success", "message", "n_states", "n_equations", "steps", "cpu_time_s", "energy_balance_error",
                "constraint_drift"}


def test_simulate_json_prints_one_summary_object(capsys):
    assert main(["simulate", PENDULUM, "--format", "json"]) == 0
    summary = json.loads(capsys.readouterr().out)  # the whole of stdout is one JSON document
    assert isinstance(summary, dict)
    assert SUMMARY_KEYS <= summary.keys()
    assert summary["success"] is True
    assert summary["n_states"] == 4  # x, y and two momenta
    assert summary["n_equations"] >= summary["n_states"]
    assert summary["steps"] > 0
    assert summary["cpu_time_s"] > 0
    assert 0 <= summary["energy_balance_error"] <= 1e-6
    assert 0 <= summary["constraint_drift"] <= 1e-8
    assert summary["t_final"] == 20.0


def test_simulate_text_summary(capsys):
    assert main(["simulate", MSD, "--quiet"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("mass_spring_damper: success")


def read_csv(path: Path) -> dict[str, np.ndarray]:
    with path.open(newline="") as handle:
        rows = list(csv.reader(handle))
    header, body = rows[0], np.array(rows[1:], dtype=float)
    assert len(set(header)) == len(header)
    return {name.split(" [")[0]: body[:, j] for j, name in enumerate(header)}  # `spring.x [m]`: docs/units.md


def read_npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as data:
        return {name: data[name] for name in data.files}


@pytest.mark.parametrize("suffix, reader", [(".csv", read_csv), (".npz", read_npz)])
def test_simulate_out_writes_time_and_variables(suffix, reader, tmp_path, capsys):
    out = tmp_path / f"x{suffix}"
    assert main(["simulate", MSD, "--quiet", "--n-out", "11", "--t-end", "1", "--out", str(out)]) == 0
    columns = reader(out)
    assert {"t", "mass.p", "spring.x", "output.x", "H"} <= columns.keys()
    assert columns["t"].tolist() == np.linspace(0.0, 1.0, 11).tolist()
    assert columns["spring.x"][0] == 0.5
    assert columns["mass.p"][0] == 0.0
    np.testing.assert_array_equal(columns["output.x"], columns["spring.x"])
    assert columns["H"][0] == pytest.approx(0.5 * 4.0 * 0.5**2, rel=1e-15)  # k x0² / 2
    assert str(out) in capsys.readouterr().out


def test_simulate_and_sweep_take_o_as_short_for_out(tmp_path):
    """`phc compile -o DIR` and `phc simulate -o FILE` alike: a new user's first guess."""
    from phc.cli.parser import build_parser

    out = tmp_path / "x.csv"
    assert main(["simulate", MSD, "--quiet", "--n-out", "3", "--t-end", "0.1", "-o", str(out)]) == 0
    assert out.read_text().startswith("t")
    assert build_parser().parse_args(["sweep", MSD, "-o", "r.csv"]).out == "r.csv"


def test_simulate_out_with_unknown_suffix_is_a_usage_error(tmp_path, capsys):
    out = tmp_path / "x.txt"
    assert main(["simulate", MSD, "--quiet", "--out", str(out)]) == 2
    captured = capsys.readouterr()
    [line] = error_lines(captured.err)
    assert str(out) in line
    assert captured.out == ""
    assert not out.exists()


def test_simulate_param_that_is_not_a_number_is_a_usage_error(capsys):
    assert main(["simulate", MSD, "--quiet", "--param", "k=abc"]) == 2
    captured = capsys.readouterr()
    [line] = error_lines(captured.err)
    assert "abc" in line
    assert captured.out == ""


def test_simulate_unknown_param_is_a_usage_error_naming_it(capsys):
    assert main(["simulate", MSD, "--quiet", "--param", "nosuch=1"]) == 2
    captured = capsys.readouterr()
    [line] = error_lines(captured.err)
    assert "`nosuch`" in line
    assert "Traceback" not in captured.err
    assert "internal error" not in captured.err


def test_simulate_param_overrides_the_parameter(tmp_path, capsys):
    # The stored energy at t0 is k x0²/2, so it shows which stiffness the run used.
    runs = {}
    for k in ("4", "9"):
        out = tmp_path / f"k{k}.npz"
        assert main(["simulate", MSD, "--quiet", "--t-end", "1", "--param", f"k={k}", "--out", str(out)]) == 0
        runs[k] = read_npz(out)
    assert runs["4"]["H"][0] == pytest.approx(0.5 * 4.0 * 0.25, rel=1e-15)
    assert runs["9"]["H"][0] == pytest.approx(0.5 * 9.0 * 0.25, rel=1e-15)


# -- python -m phc -----------------------------------------------------------------


def test_python_m_phc_version():
    proc = subprocess.run([sys.executable, "-m", "phc", "--version"], capture_output=True, text=True,
                          timeout=SUBPROCESS_TIMEOUT)
    assert proc.returncode == 0
    assert proc.stdout.strip() == f"phc {phc.__version__}"


# -- pre-commit hook ---------------------------------------------------------------


def load_hooks() -> list[dict]:
    return yaml.safe_load((REPO / ".pre-commit-hooks.yaml").read_text())


def test_pre_commit_hook_definition():
    hooks = load_hooks()
    assert [hook["id"] for hook in hooks] == ["phc-validate"]
    [hook] = hooks
    assert hook["entry"] == "phc validate"
    assert hook["language"] == "python"
    assert {"name", "files"} <= hook.keys()
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert hook["entry"].split()[0] in scripts  # the console script the python hook env installs


@pytest.mark.parametrize("path, selected", [
    ("models/pendulum.yaml", True),
    ("models/scenes/robot.yml", True),
    ("schemas/model.schema.json", False),
    (".github/workflows/ci.yaml", False),
    ("tests/models/invalid/unknown_key.yaml", False),
    (".pre-commit-config.yaml", False),
])
def test_pre_commit_hook_default_files_pattern(path, selected):
    [hook] = load_hooks()
    assert bool(re.search(hook["files"], path)) == selected


def test_pre_commit_hook_passes_on_the_shipped_models(capsys, monkeypatch):
    [hook] = load_hooks()
    monkeypatch.chdir(REPO)
    files = sorted(str(p.relative_to(REPO)) for p in REPO.rglob("*.y*ml") if re.search(hook["files"],
                                                                                        str(p.relative_to(REPO))))
    assert "models/pendulum.yaml" in files
    assert main([*hook["entry"].split()[1:], *files]) == 0


def test_an_initial_field_under_modes_says_which_keys_to_write_and_they_work(tmp_path, capsys, monkeypatch):
    """PHC-E215 for a field of a beam reduced by `modes`: the hint names the modal keys with
    an example, and that example, written as the hint says, is accepted."""
    model = """\
format_version: 1
components:
  beam: {type: euler_bernoulli_beam, length: 0.3, elements: 4, rhoA: 0.5, EI: 68.0}
  clamp: {type: zero_flow, domain: mechanical.translational}
  clamp_rot: {type: zero_flow, domain: mechanical.rotational}
  free: {type: zero_effort, domain: mechanical.translational}
  free_rot: {type: zero_effort, domain: mechanical.rotational}
connections:
  - [beam.a, clamp.port]
  - [beam.a_rot, clamp_rot.port]
  - [beam.b, free.port]
  - [beam.b_rot, free_rot.port]
"""
    monkeypatch.chdir(tmp_path)
    Path("field.yaml").write_text(model + "simulation:\n  initial:\n    beam.w: 0.001*xi**2\n")
    Path("plain.yaml").write_text(model)
    Path("s.yaml").write_text("format_version: 1\nmodel: field.yaml\neffects:\n  beam: {modes: 2}\n")
    assert main(["validate", "s.yaml"]) == 1
    [line] = error_lines(capsys.readouterr().err)
    assert "[PHC-E215]" in line and "instead of `beam.w`" in line, line
    example = re.search(r"e\.g\. `([^`]+)`", line).group(1)
    assert example == "beam.za[0]: 0.0", line
    Path("s2.yaml").write_text(f"format_version: 1\nmodel: plain.yaml\neffects:\n  beam: {{modes: 2}}\n"
                               f"initial:\n  {example}\n")
    assert main(["validate", "s2.yaml"]) == 0, capsys.readouterr().err
