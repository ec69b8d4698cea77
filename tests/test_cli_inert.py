"""Hostile names and values (issue 32 items 4 and 5).

* **inert output**: a file name holding ESC, BEL, a line break and ``::error file=…::…``
  reaches the text, GitHub, JSON and SARIF formats and the sweep's report, and none of
  them carries a control character or starts a line with a workflow command it did not
  mean (:func:`phc.inert.inert`; GitHub's own escaping of properties and messages);
* **errors**: numbers too large for a float, empty and over-long paths, a bad scheduler,
  fields longer than the csv module's limit and damaged resume files each end in one
  usage or located line and a non-zero exit, never a traceback or "internal error".
"""

from __future__ import annotations

import csv
import importlib.util
import json
import re
import shutil
from pathlib import Path
from urllib.parse import unquote

import pytest

from phc.cli import main
from phc.inert import inert

ROOT = Path(__file__).resolve().parents[1]
MSD = ROOT / "models" / "mass_spring_damper.yaml"
HOSTILE = "x\n::error file=README.md,line=1::injected\x1b[31m\x07.yaml"
"""A file name with a line break, a workflow command, ESC (a colour) and BEL."""
LEADING = "::error file=a.yaml::boom.yaml"
"""A file name that starts with a workflow command."""
NINES = "9" * 400
CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")  # all C0 but tab and newline, DEL, C1
_PROPERTY = {"%": "%25", "\r": "%0D", "\n": "%0A", ":": "%3A", ",": "%2C"}


def _unescape_property(text: str) -> str:
    for char, code in _PROPERTY.items():
        if char != "%":
            text = text.replace(code, char)
    return text.replace("%25", "%")


def _workflow_command(line: str):
    """(command, properties) of a line the GitHub runner reads as a workflow command (the
    runner's own test: after leading blanks, `::`, a second `::`), else None."""
    text = line.lstrip()
    if not text.startswith("::") or text.find("::", 2) < 0:
        return None
    info = text[2:text.find("::", 2)]
    name, _, props = info.partition(" ")
    pairs = [p.split("=", 1) for p in props.split(",") if p]
    return name, {k: _unescape_property(v) for k, v in pairs}


def _no_control(text: str) -> None:
    assert not CONTROL.search(text), repr(CONTROL.search(text).group())
    assert "\r" not in text


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "internal error" not in err and "Traceback" not in err
    return lines[0]


@pytest.fixture
def hostile(tmp_path, monkeypatch):
    """Two broken model files with hostile names and a valid one, in the current folder."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / HOSTILE).write_text("a: [\n")
    (tmp_path / LEADING).write_text("a: [\n")
    shutil.copy(MSD, tmp_path / "ok.yaml")
    return [HOSTILE, LEADING, "ok.yaml"]


# -- the one escaping ---------------------------------------------------------------------

@pytest.mark.parametrize("text, shown", [
    ("a\x1bb", "a\\x1bb"),
    ("bell\x07", "bell\\x07"),
    ("two\nlines\r", "two\\x0alines\\x0d"),
    ("\u202eevil", "\\u202eevil"),
    ("::error::x", "\\x3a:error::x"),
    ("  \t::warning::x", "  \t\\x3a:warning::x"),
    ("a ##[error]b", "a ##\\x5berror]b"),
    ("plain: a::b, c", "plain: a::b, c"),
])
def test_inert_escapes_control_characters_and_workflow_commands(text, shown):
    assert inert(text) == shown
    assert inert(inert(text)) == shown  # escaping twice changes nothing more


# -- inert output -------------------------------------------------------------------------

def test_text_format_shows_hostile_file_names_as_visible_escapes(hostile, capsys):
    assert main(["validate", *hostile]) == 1
    captured = capsys.readouterr()
    for text in (captured.out, captured.err):
        _no_control(text)
        assert not [line for line in text.splitlines() if line.lstrip().startswith("::")]
    lines = captured.err.splitlines()
    assert lines[0].startswith("x\\x0a::error file=README.md,line=1::injected\\x1b[31m\\x07.yaml:2:1: ")
    assert lines[1].startswith("\\x3a:error file=a.yaml::boom.yaml:2:1: ")
    assert lines[0].endswith("[PHC-E001]")
    assert "\\x1b[31m\\x07.yaml, \\x3a:error" in lines[-1]  # the summary names them the same way
    assert captured.out.startswith("ok.yaml: ok (")


def test_github_format_escapes_the_file_property_and_starts_no_other_command(hostile, capsys):
    assert main(["validate", "--format", "github", *hostile]) == 1
    captured = capsys.readouterr()
    _no_control(captured.out + captured.err)
    commands = [c for c in map(_workflow_command, captured.out.splitlines()) if c is not None]
    assert [name for name, _ in commands] == ["error", "error"]  # one per broken file, nothing injected
    files = [props["file"] for _, props in commands]
    assert files == [inert(HOSTILE).replace("\\x0a", "\n"), LEADING]  # GitHub's %0A, %3A, %2C read back
    for _, props in commands:
        assert set(props) == {"file", "line", "col", "title"} and props["line"] == "2"
    assert not [line for line in captured.err.splitlines() if line.lstrip().startswith("::")]


@pytest.mark.parametrize("fmt", ["json", "sarif"])
def test_json_and_sarif_escape_as_json_does(hostile, fmt, capsys):
    assert main(["validate", "--format", fmt, *hostile]) == 1
    out = capsys.readouterr().out
    _no_control(out)
    data = json.loads(out)
    if fmt == "json":
        assert [entry["file"] for entry in data] == hostile  # the names themselves, JSON-escaped
    else:
        uris = [unquote(a["location"]["uri"]) for a in data["runs"][0]["artifacts"]]
        assert uris == hostile  # percent-encoded URIs


@pytest.mark.parametrize("long", [False, True])
def test_a_sweeps_failed_rows_and_resumed_messages_are_inert(long, tmp_path, capsys):
    """A resumed results file whose message cell holds ESC, BEL, a line break and a
    workflow command; `long`: also more characters than the csv module reads by default,
    and a series file whose first cell is `²` (a digit to str.isdigit, not to int)."""
    out = tmp_path / "r.csv"
    argv = ["sweep", str(MSD), "--param", "k=1,2", "--t-end", "0.05", "--quiet", "--workers", "1",
            "--out", str(out), "--series", str(tmp_path / "s.csv")]
    assert main(argv) == 0
    capsys.readouterr()
    limit = csv.field_size_limit()
    with open(out, newline="") as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    message = "\x1b[2J\x07boom\n::error file=x::injected " + ("y" * (limit + 10) if long else "y")
    rows[1][header.index("success")] = "false"
    rows[1][header.index("message")] = message
    with open(out, "w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows[:2])  # point 1 is run again
    if long:
        series = (tmp_path / "s.csv").read_text().splitlines()
        (tmp_path / "s.csv").write_text("\n".join(series[:2] + ["²" + series[1][1:]]) + "\n")
    assert main([*argv, "--resume"]) == 1  # the failed row
    captured = capsys.readouterr()
    _no_control(captured.out + captured.err)
    failed = [line for line in captured.out.splitlines() if "FAILED    point 0" in line]
    assert len(failed) == 1 and "\\x1b[2J\\x07boom ::error file=x::injected y" in failed[0]
    assert not [line for line in captured.out.splitlines() if line.lstrip().startswith("::")]
    assert csv.field_size_limit() == limit  # the process keeps its csv limit


def test_a_resume_description_that_is_not_an_object_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "r.csv").write_text("point\n")
    (tmp_path / "r.sweep.json").write_text("[]")
    assert main(["sweep", str(MSD), "--param", "k=1,2", "--quiet", "--out", "r.csv", "--resume"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert line.startswith("phc sweep: error: cannot resume `r.csv`: its description `r.sweep.json` is not"), line


def test_a_scenes_hostile_name_is_inert_in_the_summary_and_the_progress_line(tmp_path, monkeypatch, capsys):
    """A scene without `name:` is named after its file: here ESC, BEL and a workflow command."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(MSD, tmp_path / "m.yaml")
    scene = tmp_path / "::error file=a::b\x1b]0;title\x07.yaml"
    scene.write_text("format_version: 1\nmodel: m.yaml\nt_end: 0.05\nn_out: 3\noutputs: {x: spring.x}\n")
    assert main(["simulate", scene.name]) == 0
    captured = capsys.readouterr()
    _no_control(captured.out + captured.err)
    first = captured.out.splitlines()[0]
    assert first.startswith("\\x3a:error file=a::b\\x1b]0;title\\x07 (scene of "), first
    assert not [line for line in (captured.out + captured.err).splitlines() if line.lstrip().startswith("::")]


def test_argparse_errors_quote_arguments_inert(capsys):
    with pytest.raises(SystemExit) as done:
        main(["simulate", str(MSD), "\n::error file=x::injected\x1b[2J"])
    assert done.value.code == 2
    err = capsys.readouterr().err
    _no_control(err)
    assert not [line for line in err.splitlines() if line.lstrip().startswith("::")]
    assert "unrecognized arguments: \\x0a::error file=x::injected\\x1b[2J" in err


def test_graph_names_a_hostile_model_in_one_dot_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    text = "".join(line for line in MSD.read_text().splitlines(keepends=True) if not line.startswith("name:"))
    (tmp_path / "g\n}\x1b[31m.yaml").write_text(text)  # a model without `name:` is named after its file
    assert main(["graph", "g\n}\x1b[31m.yaml"]) == 0
    out = capsys.readouterr().out
    _no_control(out)
    assert out.splitlines()[0] == 'graph "g\\x0a}\\x1b[31m" {'


# -- errors -------------------------------------------------------------------------------

@pytest.mark.parametrize("argv, env, start", [
    (["validate", str(MSD), "--max-memory", NINES], {}, "phc validate: error: --max-memory `999"),
    (["check", str(MSD), "--max-memory", "1e999G"], {}, "phc check: error: --max-memory `1e999G` is not"),
    (["validate", str(MSD)], {"PHC_MAX_MEMORY": NINES}, "phc validate: error: PHC_MAX_MEMORY: `999"),
    (["cache", "info"], {"PHC_CACHE_MAX_MB": NINES}, "phc cache: error: PHC_CACHE_MAX_MB must be"),
    (["cache", "info"], {"PHC_CACHE_MAX_MB": "lots"}, "phc cache: error: PHC_CACHE_MAX_MB: `lots` is not"),
    (["sweep", str(MSD), "--param", "k=uniform:1:2", "--samples", "2", "--seed", "-1", "--out", "r.csv"], {},
     "phc sweep: error: --seed must be a whole number from 0 to 4294967295, got -1"),
    (["simulate", str(MSD), "--out", ""], {}, "phc simulate: error: --out is empty"),
    (["sweep", str(MSD), "--param", "k=1,2", "--out", ""], {}, "phc sweep: error: --out is empty"),
    (["compile", str(MSD), "-o", ""], {}, "phc compile: error: -o is empty"),
    (["validate", str(MSD), "--allow-path", "d" * 5000], {}, "phc validate: error: --allow-path `ddd"),
    (["compile", str(MSD), "-o", "d" * 5000], {}, "phc compile: error: -o `ddd"),
    (["simulate", str(MSD), "--out", "d" * 5000 + ".csv"], {}, "phc simulate: error: --out `ddd"),
    (["bench", str(MSD), "--out-dir", "d" * 5000], {}, "phc bench: error: --out-dir `ddd"),
])
def test_out_of_range_values_are_one_line_usage_errors(argv, env, start, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    assert main(argv) == 2
    captured = capsys.readouterr()
    line = one_error_line(captured.err)
    assert line.startswith(start), line
    assert len(line) < 400  # a long value is shortened in the message
    assert captured.out == ""
    assert not list(tmp_path.iterdir())  # refused before any work


@pytest.mark.skipif(importlib.util.find_spec("distributed") is None, reason="needs dask.distributed")
@pytest.mark.parametrize("address", ["not an address", "tcp://host", "tcp://host:99999"])
def test_a_malformed_scheduler_is_a_usage_error_before_any_work(address, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["sweep", str(MSD), "--param", "k=1,2", "--quiet", "--out", "r.csv", "--executor", "dask",
                 "--scheduler", address]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert line.startswith(f"phc sweep: error: --scheduler `{address}` is neither"), line
    assert not list(tmp_path.glob("r.*"))


@pytest.mark.skipif(importlib.util.find_spec("distributed") is None, reason="needs dask.distributed")
def test_an_unreachable_scheduler_is_a_usage_error(tmp_path, monkeypatch, capsys):
    import distributed

    def refused(*args, **kwargs):  # what Client raises once its connection timeout has passed
        raise OSError("Timed out trying to connect to tcp://127.0.0.1:1 after 30 s")

    monkeypatch.setattr(distributed, "Client", refused)
    assert main(["sweep", str(MSD), "--param", "k=1,2", "--quiet", "--out", str(tmp_path / "r.csv"),
                 "--executor", "dask", "--scheduler", "tcp://127.0.0.1:1"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert line.startswith("phc sweep: error: --scheduler `tcp://127.0.0.1:1`: cannot connect"), line


def _scene(folder: Path, reference_values: str) -> Path:
    shutil.copy(MSD, folder / "msd_model.yaml")
    path = folder / "msd.yaml"
    path.write_text("format_version: 1\nmodel: msd_model.yaml\nname: msd\nt_end: 1.0\nn_out: 11\n"
                    "outputs: {x: spring.x}\n" + reference_values)
    return path


def test_a_reference_cell_longer_than_the_csv_limit_is_a_located_error(tmp_path, capsys):
    limit = csv.field_size_limit()
    (tmp_path / "ref.csv").write_text("t,x\n0.5," + "a" * (limit + 10) + "\n")
    path = _scene(tmp_path, "reference_values: {file: ref.csv}\n")
    assert main(["validate", str(path)]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert line.startswith(f"{tmp_path / 'ref.csv'}:2:5: ") and "is not a number" in line, line
    assert csv.field_size_limit() == limit


def test_bench_reference_replaces_a_scenes_missing_reference_file(tmp_path, capsys):
    (tmp_path / "mine.csv").write_text("t,x\n0.5,0.1\n")
    path = _scene(tmp_path, "reference_values: {file: missing.csv}\n")
    assert main(["bench", str(path), "--reference", str(tmp_path / "mine.csv"), "--solver", "midpoint",
                 "--step", "0.1", "--quiet", "--no-plot", "--out-dir", str(tmp_path / "out")]) == 0
    assert f"published reference ({tmp_path / 'mine.csv'}, 1 point): x" in capsys.readouterr().out
    assert main(["bench", str(path), "--solver", "midpoint", "--step", "0.1", "--quiet", "--no-plot",
                 "--out-dir", str(tmp_path / "out")]) == 1  # without --reference the scene's file is needed
    assert "`missing.csv` not found" in capsys.readouterr().err


def test_reading_long_csv_fields_leaves_the_process_limit_alone():
    from phc.io import csv_rows

    limit = csv.field_size_limit()
    assert csv_rows(["a," + "b" * (limit * 2) + "\n"]) == [["a", "b" * (limit * 2)]]
    assert csv.field_size_limit() == limit
