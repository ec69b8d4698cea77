"""Scene entries are located in the scene and never dropped without a word.

A scene that prunes a component (it cannot influence the requested outputs) leaves that
component's entries unused: each gets a located warning (PHC-W608), since a typo in them
could not be found either. A scene's `nominal` is located in the scene file (it was
reported in the model file, at an unrelated line). `t_start` after `t_end` is refused
where it is written."""

from __future__ import annotations

from pathlib import Path

from phc.cli import main

MODEL = """\
format_version: 1
name: hanging
parameters: {m: 0.4, g: 9.81, k: 25.0, c: 0.3, m2: 1.0, k2: 9.0}
components:
  body:
    type: rigid
    q: [y]
    v: [vy]
    M: [[m]]
    V: {gravity: m*g*y, spring: k*y**2/2}
    damping: [c*vy]
  other: {type: mass, m: m2}
  osc: {type: spring, k: k2}
connections:
  - [other.port, osc.port]
simulation:
  t_end: 1.0
  initial: {body.y: 0.05, body.p_vy: 0, osc.x: 0.2, other.p: 0}
  outputs: {y: body.y, x2: osc.x}
"""


def _files(tmp_path: Path, scene: str) -> Path:
    (tmp_path / "hanging.yaml").write_text(MODEL, encoding="utf-8")
    (tmp_path / "scenes").mkdir()
    path = tmp_path / "scenes" / "s.yaml"
    path.write_text("format_version: 1\nmodel: ../hanging.yaml\n" + scene + "outputs:\n  y: body.y\n",
                    encoding="utf-8")
    return path


def test_entries_of_a_pruned_component_are_reported_unused(tmp_path, capsys):
    path = _files(tmp_path, "initial: {osc.q: 0.3}\neffects:\n  other: {damping: off}\n")
    assert main(["validate", str(path)]) == 0  # a warning, not an error: the scene still runs
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "PHC-W608" in ln]
    assert len(lines) == 2, err
    assert any(ln.startswith(f"{path}:3:11: warning: `initial` of `osc.q` is not used") for ln in lines), lines
    assert any(ln.startswith(f"{path}:5:3: warning: `effects` of `other` is not used") for ln in lines), lines
    assert all("prune: false" in ln for ln in lines)


def test_entries_of_a_kept_component_give_no_warning(tmp_path, capsys):
    path = _files(tmp_path, "initial: {body.y: 0.1}\n")
    assert main(["validate", str(path)]) == 0
    assert "PHC-W608" not in capsys.readouterr().err


def test_a_scenes_nominal_is_located_in_the_scene(tmp_path, capsys):
    path = _files(tmp_path, "nominal: {body.z: 1.0}\n")
    assert main(["validate", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith(f"{path}:3:11: nominal.body.z: `body.z` is not a state"), err
    assert err[0].endswith("[PHC-E210]")


def test_t_start_after_t_end_is_refused_where_it_is_written(tmp_path, capsys):
    path = tmp_path / "m.yaml"
    path.write_text(MODEL.replace("  t_end: 1.0\n", "  t_end: 1.0\n  t_start: 2.0\n"), encoding="utf-8")
    assert main(["validate", str(path)]) == 1
    line = capsys.readouterr().err.strip().splitlines()[0]
    assert line.startswith(f"{path}:18:12: simulation.t_start: `t_start` (2.0) must be before `t_end` (1.0)"), line


def test_simulate_prints_the_models_warnings_also_from_its_cache(tmp_path, capsys, monkeypatch):
    """`phc simulate` printed no warning where `phc validate` did; a second run, from the
    cached front end, prints the same."""
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    path = _files(tmp_path, "initial: {osc.x: 0.3}\n")
    for _ in range(2):
        assert main(["simulate", str(path), "--quiet"]) == 0
        err = capsys.readouterr().err
        assert f"{path}:3:11: warning: `initial` of `osc.x` is not used" in err, err
