"""The negative corpus: every folder of ``tests/models/invalid/`` is one user mistake.

Layout (in the style of check-jsonschema's positive/negative example folders)::

    invalid/<case>/model.yaml     the model that `phc validate` must reject
    invalid/<case>/expected.txt   the exact stderr lines of `phc validate model.yaml`
    invalid/<case>/xfail.txt      optional: phc gets this case wrong today (the text is the reason)
    invalid/<case>/*.yaml         optional: files the model nests

Paths in ``expected.txt``
    The tests run the CLI *from inside the case folder* (``monkeypatch.chdir``) and pass
    the relative name ``model.yaml``, so every diagnostic line starts with
    ``model.yaml:LINE:COL:`` and a nested file shows up under its name relative to the case
    folder (``oscillator.yaml:7:11: ...``). No path rewriting is needed; ``expected.txt`` holds
    the lines exactly as a user running ``phc validate model.yaml`` in that folder sees them
    (one line per problem: ``file:line:col: path: message. hint: ... [PHC-Exxx]``).

Expected files are written from what a user needs (right location, clear message), not
copied from phc's output. When phc is wrong (wrong line/col, a misleading or missing
message, a crash), the case keeps the *correct* expected lines and gets an ``xfail.txt``
explaining the bug: the test is marked ``xfail(strict=True)``, so it starts failing (XPASS)
the day phc is fixed, and then the ``xfail.txt`` must be removed. Where the correct text of
a not-yet-existing diagnostic is a proposal, ``xfail.txt`` says so; adjust ``expected.txt``
to the wording chosen by the fix. An ``xfail.txt`` line ``also: build_dae`` marks the
second check (``phc.build_dae`` reports errors) as expected to fail too, for bugs where phc
does not see the mistake at all or crashes.

Values phc computes at its own random samples (the mismatch of a rigid port's
``position`` at sampled ``q``) stand in ``expected.txt`` as placeholders (``<sampled+>``,
see :mod:`golden`); every case also runs with every sampler's seed shifted, so no expected
line pins a sample.

To add a case: make the folder, write ``model.yaml``, write ``expected.txt`` by hand, run
``python -m pytest tests/models -q -k <case>``.
"""

from __future__ import annotations

import re
import uuid
from pathlib import Path

import pytest
from golden import resolved, shift_seeds

import phc
from phc.cli import main
from phc.errors import ModelError

HERE = Path(__file__).parent
INVALID = HERE / "invalid"
CASES = sorted(p.name for p in INVALID.iterdir() if (p / "model.yaml").is_file())
CORPUS_MARKERS = (Path("/tmp/phc_corpus_yaml_tag_pwned"), Path("/tmp/phc_corpus_expr_pwned"))
"""Files the payloads of the cases `yaml_python_tag` and `expr_import_call` would create."""
LINE_RE = re.compile(r"^[\w./-]+\.yaml:\d+:\d+: .+ \[PHC-[EW]\d{3}\]$")


def _xfail(case: str) -> tuple[str | None, bool]:
    """(reason, also_build_dae) from the case's xfail.txt, or (None, False)."""
    path = INVALID / case / "xfail.txt"
    if not path.is_file():
        return None, False
    lines = path.read_text(encoding="utf-8").splitlines()
    also = any(line.strip() == "also: build_dae" for line in lines)
    reason = " ".join(line.strip() for line in lines if line.strip() and line.strip() != "also: build_dae")
    return reason, also


def _params(check_build_dae: bool = False) -> list:
    out = []
    for case in CASES:
        reason, also = _xfail(case)
        marks = []
        if reason is not None and (not check_build_dae or also):
            marks.append(pytest.mark.xfail(strict=True, reason=reason))
        out.append(pytest.param(case, id=case, marks=marks))
    return out


def _expected(case: str) -> list[str]:
    text = (INVALID / case / "expected.txt").read_text(encoding="utf-8")
    return [line for line in text.splitlines() if line.strip()]


def _validate(capsys, args: list[str]) -> tuple[int, str, str]:
    code = main(["validate", *args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# -- the corpus itself -------------------------------------------------------------

def test_corpus_is_complete():
    assert len(CASES) >= 30
    for case in CASES:
        folder = INVALID / case
        assert (folder / "expected.txt").is_file(), f"{case}: expected.txt missing"
        lines = _expected(case)
        assert lines, f"{case}: expected.txt is empty"
        for line in lines:
            assert LINE_RE.match(line), f"{case}: not a diagnostic line: {line!r}"
        reason, _ = _xfail(case)
        assert reason is None or len(reason) > 40, f"{case}: xfail.txt must explain the bug"


# -- phc validate: exit code 1, no traceback, exactly the expected lines ------------

@pytest.mark.parametrize("seed_shift", [0, 7], ids=["seeds", "shifted-seeds"])
@pytest.mark.parametrize("case", _params())
def test_validate_reports_expected_diagnostics(case, seed_shift, capsys, monkeypatch):
    shift_seeds(monkeypatch, seed_shift)
    monkeypatch.chdir(INVALID / case)
    code, out, err = _validate(capsys, ["model.yaml"])
    for text in (out, err):
        assert "Traceback" not in text
        assert "internal error" not in text
    assert code == 1, f"exit code {code}; stderr:\n{err}"
    assert out == ""
    assert not any(p.exists() for p in CORPUS_MARKERS), "a corpus payload ran code"
    got = [line for line in err.splitlines() if line.strip()]
    assert got == resolved(_expected(case), got)


# -- the library entry point agrees ----------------------------------------------

@pytest.mark.parametrize("case", _params(check_build_dae=True))
def test_build_dae_reports_errors(case, monkeypatch):
    monkeypatch.chdir(INVALID / case)
    dae, diags = phc.build_dae("model.yaml")
    assert dae is None
    assert diags.has_errors


# -- safety: a model file is data, nothing in it is executed -------------------------

def _marker() -> Path:
    # an absolute path, so a payload would create it whatever its working directory
    return Path("/tmp") / f"phc_pwned_{uuid.uuid4().hex}"


EXPRESSION_PAYLOADS = [
    "__import__('os').system('touch {marker}')",
    "().__class__.__bases__[0].__subclasses__()",
    "(lambda: __import__('os').system('touch {marker}'))()",
    "[__import__('os').system('touch {marker}') for _ in (1,)][0]",
    "eval(\"__import__('os').system('touch {marker}')\")",
    "exec('import os; os.system(\"touch {marker}\")')",
]

YAML_TAG_PAYLOADS = [
    "!!python/object/apply:os.system ['touch {marker}']",
    "!!python/object/apply:subprocess.check_call [['touch', '{marker}']]",
    "!!python/object/new:os.system ['touch {marker}']",
    "!!python/name:os.system",
]


def _expression_model(expr: str) -> str:
    quoted = "'" + expr.replace("'", "''") + "'"   # a YAML single-quoted scalar
    return (
        "format_version: 1\n"
        "components:\n"
        "  mass: {type: mass, m: 1.0}\n"
        "  spring:\n"
        "    type: spring\n"
        f"    k: {quoted}\n"
        "connections:\n"
        "  - [mass.port, spring.port]\n"
    )


def _tag_model(tag: str) -> str:
    return (
        "format_version: 1\n"
        "parameters:\n"
        f"  k: {tag}\n"
        "components:\n"
        "  mass: {type: mass, m: 1.0}\n"
        "  spring: {type: spring, k: k}\n"
        "connections:\n"
        "  - [mass.port, spring.port]\n"
    )


def _assert_refused(path: Path, marker: Path, capsys) -> None:
    code, out, err = _validate(capsys, [str(path)])
    assert code == 1, err
    assert "Traceback" not in err and "internal error" not in err
    assert f"{path.parent}/" in err
    assert "[PHC-E101]" in err or "[PHC-E001]" in err   # refused as an expression or a YAML tag
    dae, diags = phc.build_dae(path)
    assert dae is None and diags.has_errors
    with pytest.raises(ModelError):
        phc.compile_model(path)
    assert not marker.exists(), f"a model file ran code: {marker} was created"


@pytest.mark.parametrize("payload", EXPRESSION_PAYLOADS)
def test_expression_cannot_run_code(payload, tmp_path, capsys):
    marker = _marker()
    path = tmp_path / "model.yaml"
    path.write_text(_expression_model(payload.format(marker=marker)), encoding="utf-8")
    _assert_refused(path, marker, capsys)


@pytest.mark.parametrize("payload", YAML_TAG_PAYLOADS)
def test_yaml_tag_cannot_run_code(payload, tmp_path, capsys):
    marker = _marker()
    path = tmp_path / "model.yaml"
    path.write_text(_tag_model(payload.format(marker=marker)), encoding="utf-8")
    _assert_refused(path, marker, capsys)


def test_yaml_tag_in_nested_file_cannot_run_code(tmp_path, capsys):
    marker = _marker()
    (tmp_path / "inner.yaml").write_text(
        _tag_model(YAML_TAG_PAYLOADS[0].format(marker=marker)) + "ports:\n  handle: {port: mass.port}\n",
        encoding="utf-8")
    path = tmp_path / "model.yaml"
    path.write_text("format_version: 1\ncomponents:\n  inner: {type: model, file: inner.yaml}\n",
                    encoding="utf-8")
    _assert_refused(path, marker, capsys)


def test_corpus_payloads_did_not_run():
    """The corpus cases `yaml_python_tag` and `expr_import_call` name fixed marker files."""
    assert not any(p.exists() for p in CORPUS_MARKERS)
