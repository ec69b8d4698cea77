"""CI-friendly checking (issue 15 item 7, and the sign hint of item 1):

* ``phc validate|check|compile`` take several files: one located line per problem across
  the files, exit 1 when any fails, a summary line;
* ``kind: part``: a model file that is a reusable piece, validated without closing its
  exposed ports, nested by models, refused where a complete model is needed;
* ``--format github`` (workflow-command annotations) and ``--format sarif`` (a SARIF 2.1.0
  log, checked here against the properties the SARIF 2.1.0 standard requires);
* the PHC-W230 hint of ``phc check`` on connections that turn the sign of a voltage,
  checked against the closed form of a charging RC circuit;
* the label column of ``phc check`` for nested connections.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import jsonschema
import numpy as np
import pytest

import phc
from phc.cli import main
from phc.cli.report_formats import github_annotations
from model_texts import GEAR_PART, USES_GEAR  # a nested gear stage and a model that uses it

REPO = Path(__file__).resolve().parents[1]
MSD = REPO / "models" / "mass_spring_damper.yaml"


USES_GEAR_N4 = USES_GEAR.replace("file: gear.yaml}", "file: gear.yaml, parameters: {N: 4.0}}").replace("  n_out: 11\n", "")

DANGLING = """\
format_version: 1
name: dangling
components:
  s: {type: spring, k: 2.0, terminals: [a, b]}
ports:
  a: {port: s.a}
"""


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def located(text: str) -> list[str]:
    return [line for line in text.splitlines() if re.match(r"^\S+:\d+:\d+: ", line)]


# -- several files -------------------------------------------------------------------


def test_validate_several_files_one_line_per_problem_and_a_summary(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write(tmp_path, "gear.yaml", GEAR_PART)
    write(tmp_path, "bad.yaml", DANGLING)
    write(tmp_path, "uses.yaml", USES_GEAR_N4)
    status = main(["validate", "gear.yaml", "bad.yaml", "uses.yaml"])
    out, err = capsys.readouterr()
    assert status == 1
    problems = located(err)
    assert problems == [problems[0]] and problems[0].startswith("bad.yaml:4:")
    assert "PHC-E208" in problems[0] and "s.b" in problems[0]
    assert "gear.yaml: part ok" in out and "uses.yaml: ok" in out
    assert "phc validate: 3 files, 2 ok, 1 failed; 1 error(s), 0 warning(s) in bad.yaml" in err


def test_check_several_files_fails_when_one_fails(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write(tmp_path, "gear.yaml", GEAR_PART)
    write(tmp_path, "bad.yaml", DANGLING)
    assert main(["check", str(MSD), "gear.yaml"]) == 0
    out, err = capsys.readouterr()
    assert "mass_spring_damper: certified" in out and "gear.yaml: part ok" in out
    assert "phc check: 2 files, 2 ok, 0 failed" in err
    assert main(["check", str(MSD), "bad.yaml"]) == 1
    out, err = capsys.readouterr()
    assert [line.split(":")[0] for line in located(err)] == ["bad.yaml"]
    assert "2 files, 1 ok, 1 failed" in err


def test_check_json_of_several_files_is_a_list(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write(tmp_path, "gear.yaml", GEAR_PART)
    assert main(["check", "--format", "json", "--samples", "0", str(MSD), "gear.yaml"]) == 0
    reports = json.loads(capsys.readouterr().out)
    assert [r.get("kind", "model") for r in reports] == ["model", "part"]
    assert reports[0]["certified"] is True and reports[1]["valid"] is True


def test_compile_several_files_writes_each_and_reports_the_failures(tmp_path, capsys):
    write(tmp_path, "bad.yaml", DANGLING)
    out_dir = tmp_path / "gen"
    status = main(["compile", str(MSD), str(tmp_path / "bad.yaml"), "-o", str(out_dir), "--backend", "numpy"])
    out, err = capsys.readouterr()
    assert status == 1
    assert (out_dir / "mass_spring_damper.py").is_file()
    assert located(err) and all("bad.yaml" in line for line in located(err))
    assert "2 files, 1 ok, 1 failed" in err


# -- kind: part ---------------------------------------------------------------------


def test_a_part_validates_where_the_same_file_as_a_model_is_unbalanced(tmp_path, capsys):
    part = write(tmp_path, "gear.yaml", GEAR_PART)
    model = write(tmp_path, "gear_model.yaml", GEAR_PART.replace("kind: part\n", ""))
    assert main(["validate", str(part)]) == 0
    assert "part ok (1 component(s); exposes input, output" in capsys.readouterr().out
    assert main(["validate", str(model)]) == 1
    assert "PHC-E303" in capsys.readouterr().err


def test_a_model_nesting_a_part_runs_with_the_gear_ratio(tmp_path):
    write(tmp_path, "gear.yaml", GEAR_PART)
    model = write(tmp_path, "uses.yaml", USES_GEAR_N4)
    compiled = phc.compile_model(model)
    result = phc.simulate(compiled, n_out=11)
    # a torque tau on the input shaft of a gear f_b = N f_a is tau/N on the output, so the
    # load's momentum grows as tau t / N
    assert result.success
    np.testing.assert_allclose(result.outputs["p"], 2.0 * result.t / 4.0, rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("command", [["simulate"], ["compile"], ["linearize"], ["graph"]])
def test_a_part_is_refused_where_a_complete_model_is_needed(tmp_path, capsys, command):
    part = write(tmp_path, "gear.yaml", GEAR_PART)
    assert main([*command, str(part)]) == 1
    lines = located(capsys.readouterr().err)
    assert len(lines) == 1 and lines[0].startswith(f"{part}:3:7: kind: ") and lines[0].endswith("[PHC-E216]")


def test_a_scene_of_a_part_is_refused(tmp_path, capsys):
    part = write(tmp_path, "gear.yaml", GEAR_PART)
    scene = write(tmp_path, "scene.yaml", "format_version: 1\nmodel: gear.yaml\nt_end: 1.0\n"
                  "inputs:\n  input: {flow: 1.0}\n  output: {effort: 0.0}\n")
    for command in ("validate", "simulate"):
        assert main([command, str(scene)]) == 1
        lines = located(capsys.readouterr().err)
        assert [line.split(": ")[0] for line in lines] == [f"{part}:3:7"] and "[PHC-E216]" in lines[0]


def test_a_part_needs_ports_and_has_no_simulation_section(tmp_path, capsys):
    bad = write(tmp_path, "p.yaml", "format_version: 1\nkind: part\ncomponents:\n  m: {type: mass, m: 1.0}\n"
                "connections: []\nsimulation:\n  t_end: 1.0\n")
    assert main(["validate", str(bad)]) == 1
    lines = located(capsys.readouterr().err)
    e217 = [line for line in lines if "PHC-E217" in line]
    assert [line.split(":")[1] for line in e217] == ["2", "6"]
    assert "exposes at least one port" in e217[0] and "no `simulation` section" in e217[1]


def test_the_schema_accepts_kind():
    schema = json.loads((REPO / "schemas" / "model.schema.json").read_text())
    assert schema["properties"]["kind"]["enum"] == ["model", "part"]


# -- --format github ----------------------------------------------------------------


def test_github_annotations(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write(tmp_path, "bad.yaml", DANGLING)
    assert main(["validate", "--format", "github", "bad.yaml", str(MSD)]) == 1
    out, err = capsys.readouterr()
    annotations = [line for line in out.splitlines() if line.startswith("::")]
    assert len(annotations) == 1
    match = re.fullmatch(r"::error file=([^,]+),line=(\d+),col=(\d+),title=(PHC-E\d{3})::(.+)", annotations[0])
    assert match, annotations[0]
    assert match.groups()[:4] == ("bad.yaml", "4", "6", "PHC-E208")
    assert "port `s.b` is not connected" in match.group(5) and "hint: connect it" in match.group(5)
    assert err.splitlines() == ["phc validate: 2 files, 1 ok, 1 failed; 1 error(s), 0 warning(s) in bad.yaml"]


def test_github_annotations_escape_what_the_workflow_commands_parse():
    from phc.diagnostics import Diagnostic
    from phc.frontend.source import SourceSpan

    d = Diagnostic("PHC-W201", "50% done\nnext", span=SourceSpan("dir,a:b/x.yaml", 2, 3), severity="warning")
    (line,) = github_annotations([d])
    assert line == "::warning file=dir%2Ca%3Ab/x.yaml,line=2,col=3,title=PHC-W201::50%25 done next"
    (info,) = github_annotations([Diagnostic("PHC-I214", "note", severity="info")], "m.yaml")
    assert info == "::notice file=m.yaml,title=PHC-I214::note"


# -- --format sarif -----------------------------------------------------------------

# What the SARIF 2.1.0 standard (OASIS, sections 3.13 sarifLog, 3.14 run, 3.18 tool,
# 3.19 toolComponent, 3.27 result, 3.28 location, 3.29 physicalLocation, 3.4
# artifactLocation, 3.30 region, 3.49 reportingDescriptor, 3.11 message) requires of the
# objects phc writes, and what GitHub code scanning reads (a ruleId, a message text, a
# location with a file and a start line).
_MESSAGE = {"type": "object", "anyOf": [{"required": ["text"]}, {"required": ["id"]}],
            "properties": {"text": {"type": "string", "minLength": 1}}}
_RULE = {"type": "object", "required": ["id"],
         "properties": {"id": {"type": "string"}, "shortDescription": _MESSAGE, "help": _MESSAGE}}
_DRIVER = {"type": "object", "required": ["name"],
           "properties": {"name": {"type": "string", "minLength": 1}, "version": {"type": "string"},
                          "rules": {"type": "array", "uniqueItems": True, "items": _RULE}}}
_ARTIFACT_LOCATION = {"type": "object", "required": ["uri"],
                      "properties": {"uri": {"type": "string", "format": "uri-reference"},
                                     "index": {"type": "integer", "minimum": 0}}}
_REGION = {"type": "object", "required": ["startLine"],
           "properties": {"startLine": {"type": "integer", "minimum": 1},
                          "startColumn": {"type": "integer", "minimum": 1}}}
_LOCATION = {"type": "object", "required": ["physicalLocation"],
             "properties": {"physicalLocation": {
                 "type": "object", "required": ["artifactLocation", "region"],
                 "properties": {"artifactLocation": _ARTIFACT_LOCATION, "region": _REGION}}}}
_RESULT = {"type": "object", "required": ["ruleId", "message", "locations"],
           "properties": {"ruleId": {"type": "string", "pattern": "^PHC-[EWI][0-9]{3}$"},
                          "ruleIndex": {"type": "integer", "minimum": 0},
                          "level": {"enum": ["none", "note", "warning", "error"]},
                          "message": _MESSAGE,
                          "locations": {"type": "array", "minItems": 1, "items": _LOCATION}}}
_RUN = {"type": "object", "required": ["tool", "results"],
        "properties": {"tool": {"type": "object", "required": ["driver"], "properties": {"driver": _DRIVER}},
                       "columnKind": {"enum": ["utf16CodeUnits", "unicodeCodePoints"]},
                       "artifacts": {"type": "array", "items": {"type": "object", "required": ["location"],
                                                                "properties": {"location": _ARTIFACT_LOCATION}}},
                       "results": {"type": "array", "items": _RESULT}}}
SARIF_SUBSET = {"type": "object", "required": ["version", "runs"],
                "properties": {"$schema": {"type": "string", "format": "uri"}, "version": {"const": "2.1.0"},
                               "runs": {"type": "array", "minItems": 1, "items": _RUN}}}


def test_sarif_log_has_the_shape_the_standard_requires(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write(tmp_path, "bad.yaml", DANGLING)
    write(tmp_path, "also bad.yaml", DANGLING.replace("ports:\n  a: {port: s.a}\n", "") + "oops: 1\n")
    assert main(["validate", "--format", "sarif", "bad.yaml", "also bad.yaml", str(MSD)]) == 1
    out, err = capsys.readouterr()
    log = json.loads(out)  # stdout is the log alone; file lines and the summary go to stderr
    jsonschema.validate(log, SARIF_SUBSET, format_checker=jsonschema.FormatChecker())
    assert "phc validate: 3 files, 1 ok, 2 failed" in err
    run = log["runs"][0]
    rules = [r["id"] for r in run["tool"]["driver"]["rules"]]
    results = run["results"]
    assert {r["ruleId"] for r in results} == set(rules) == {"PHC-E208", "PHC-E010"}
    for r in results:
        assert rules[r["ruleIndex"]] == r["ruleId"]
        loc = r["locations"][0]["physicalLocation"]
        assert run["artifacts"][loc["artifactLocation"]["index"]]["location"]["uri"] == loc["artifactLocation"]["uri"]
    first = next(r for r in results if r["locations"][0]["physicalLocation"]["artifactLocation"]["uri"] == "bad.yaml")
    assert first["level"] == "error"
    assert first["locations"][0]["physicalLocation"]["region"] == {"startLine": 4, "startColumn": 6}
    assert "also%20bad.yaml" in {r["locations"][0]["physicalLocation"]["artifactLocation"]["uri"] for r in results}


def test_sarif_of_a_clean_run_has_no_results(capsys):
    assert main(["check", "--format", "sarif", "--samples", "0", str(MSD)]) == 0
    log = json.loads(capsys.readouterr().out)
    jsonschema.validate(log, SARIF_SUBSET)
    assert log["runs"][0]["results"] == []


# -- the sign hint (PHC-W230) --------------------------------------------------------

RC = """\
format_version: 1
name: rc
parameters: {{V: 12.0, R: 2.0, C: 0.25}}
components:
  src: {{type: effort_source, domain: electrical, value: V}}
  r: {{type: resistor, R: R, terminals: [a, b]}}
{node}  cap: {{type: capacitor, C: C}}
connections:
  - [src.port, r.a]
{wiring}simulation:
  t_end: 1.0
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {{cap.q: 0.0}}
  outputs: {{q: cap.q}}
"""
DIRECT = RC.format(node="", wiring="  - [r.b, cap.port]\n")
THROUGH_NODE = RC.format(node="  n: {type: junction, kind: common_effort, domain: electrical, ports: [x, y]}\n",
                         wiring="  - [r.b, n.x]\n  - [n.y, cap.port]\n")


FED_NODE = """\
format_version: 1
name: fed
parameters: {V: 12.0, R: 2.0, C: 0.25}
components:
  src: {type: flow_source, domain: electrical, value: V/R}
  n: {type: junction, kind: common_effort, domain: electrical, ports: [s, c, r]}
  r: {type: resistor, R: R}
  cap: {type: capacitor, C: C}
connections:
  - [src.port, n.s]
  - [n.c, cap.port]
  - [n.r, r.port]
simulation:
  t_end: 1.0
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {cap.q: 0.0}
  outputs: {q: cap.q}
"""


@pytest.mark.parametrize("text, sign", [(DIRECT, 1.0), (THROUGH_NODE, 1.0), (FED_NODE, -1.0)],
                         ids=["direct", "through_node", "source_on_node"])
def test_sign_hint_marks_the_connection_where_the_voltage_turns(tmp_path, text, sign):
    """The charge of a capacitor charged through R from V is C V (1 − e^{−t/RC}). Joined to
    the resistor's terminal directly (a wire: docs/signs.md, series chains keep the sign you
    draw) or through a node it comes out as drawn; a current source V/R feeding the node of
    R ∥ C (the same Norton circuit) reads the node power-out like the node's own ports,
    so the charge comes out negated, and exactly then phc check warns, at that connection."""
    path = write(tmp_path, "rc.yaml", text)
    report = phc.certify_model(path, samples=0)
    hints = [d for d in report.diagnostics if d.code == "PHC-W230"]
    result = phc.simulate(phc.compile_model(path), n_out=21)
    t = result.t
    np.testing.assert_allclose(result.outputs["q"], sign * 0.25 * 12.0 * (1 - np.exp(-t / 0.5)),
                               rtol=1e-6, atol=1e-8)
    assert report.certified  # a hint, not an error
    if sign > 0:
        assert hints == []
    else:
        (hint,) = hints
        assert hint.severity == "warning" and hint.path == "connections[0]" and hint.span.line == 10
        assert "`src.port` and `n.s` both read the voltage power-out" in hint.message
        assert "negate the value of `src`" in hint.hint


def test_no_sign_hint_on_a_series_chain_of_two_terminal_elements():
    """`r_s.b` joined to `coil.a` is a wire, which keeps the sign as drawn (docs/signs.md);
    before, it turned the sign and phc warned there. tests/test_gallery.py checks the
    outputs `cap.q/C` and `coil.phi/L` against the circuit equations."""
    from phc.checks.signs import sign_hints
    from phc.pipeline import build_dae

    dae, _ = build_dae(REPO / "models" / "rlc_filter.yaml")
    assert sign_hints(dae.topology) == []
    assert dae.topology.wires == {"connections[1]"}


def test_sign_hint_names_a_source_feeding_a_node():
    from phc.checks.signs import sign_hints
    from phc.pipeline import build_dae

    dae, _ = build_dae(REPO / "models" / "thermal_ladder.yaml")
    (hint,) = sign_hints(dae.topology)  # the heater's value is −P for this reason
    assert "`heater.port` and `node1.heater` both read the temperature power-out" in hint.message
    assert "negate the value of `heater`" in hint.hint


def test_no_sign_hint_in_mechanics():
    """In mechanics the across variable is the flow, which a connection does not turn."""
    from phc.checks.signs import sign_hints
    from phc.pipeline import build_dae

    for name in ("two_mass_cubic", "quarter_car", "mass_spring_damper", "rlc_circuit"):
        path = REPO / "models" / f"{name}.yaml"
        if path.exists():
            dae, _ = build_dae(path)
            assert sign_hints(dae.topology) == [], name


# -- the label column of phc check ----------------------------------------------------


def test_check_columns_line_up_for_nested_labels(capsys):
    nested = REPO / "tests" / "models" / "valid" / "nested_oscillator.yaml"
    assert main(["check", "--samples", "0", str(nested)]) == 0
    out = capsys.readouterr().out.splitlines()
    block = out[out.index("connections (breadth-first; rank of Γ achieved / needed)") + 1:]
    rows = [line for line in block if "connections[" in line and " — " in line]
    assert any(r.split()[0] == "osc.connections[0]" for r in rows) and len(rows) == 2
    assert len({r.index(r.split()[1]) for r in rows}) == 1, rows  # the ports start in one column
    assert all(r.index(r.split()[1]) > len(r.split()[0]) + 2 for r in rows)  # a space after the label
