"""The negative corpus of ``phc check`` (:func:`phc.cli.cmd_check`, :mod:`phc.checks.certify`):
every folder of ``tests/checks/invalid/`` is one model that is not a port-Hamiltonian
system, for a reason the seed's section 2 names (not a Dirac structure, a coupling map Γ
that is not onto, a non-passive resistive law, ...).

Layout (as ``tests/models/invalid/``)::

    invalid/<case>/model.yaml     the model; a trailing comment says what is wrong
    invalid/<case>/expected.txt   the located diagnostic lines of `phc check model.yaml`
    invalid/<case>/xfail.txt      optional: phc gets this case wrong today (the text is the bug)

The test runs ``phc check model.yaml`` in-process from inside the case folder, so every
located line starts with ``model.yaml:LINE:COL:``. It requires exit code 1, no traceback or
internal error, and the lines matching ``^model\\.yaml:\\d+:\\d+: `` on stdout and stderr
(the certificate table around them is not compared) equal ``expected.txt`` exactly.
Expected lines are written from what a user needs; where phc is wrong the case keeps the
correct lines and an ``xfail.txt`` (strict: it fails loudly once phc is fixed).

One normalisation: the sampled state after ``e.g.`` in PHC-E421 (``e.g. a = 1, b = 2``) is
compared as a set of ``name = value`` items, because phc lists it in hash order today;
that bug has its own strict xfail test below.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from phc.cli import main

HERE = Path(__file__).parent
INVALID = HERE / "invalid"
CASES = sorted(p.name for p in INVALID.iterdir() if (p / "model.yaml").is_file())
LOCATED = re.compile(r"^model\.yaml:\d+:\d+: ")
LINE_RE = re.compile(r"^model\.yaml:\d+:\d+: .+ \[PHC-[EW]\d{3}\]$")
EG = re.compile(r"(e\.g\. )([^;)]*)")
REQUIRED_CODES = {"PHC-E204", "PHC-E205", "PHC-E402", "PHC-E410", "PHC-E420", "PHC-E421", "PHC-E406"}


def _xfail(case: str):
    path = INVALID / case / "xfail.txt"
    return " ".join(path.read_text(encoding="utf-8").split()) if path.is_file() else None


def _params() -> list:
    out = []
    for case in CASES:
        reason = _xfail(case)
        marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
        out.append(pytest.param(case, id=case, marks=marks))
    return out


def _expected(case: str) -> list[str]:
    text = (INVALID / case / "expected.txt").read_text(encoding="utf-8")
    return [line for line in text.splitlines() if line.strip()]


def _normalise(line: str) -> str:
    """Sort the `name = value` items of a sampled state listed after `e.g.`."""
    def sort_items(match):
        items = match.group(2).split(", ")
        if all(" = " in item for item in items):
            return match.group(1) + ", ".join(sorted(items))
        return match.group(0)

    return EG.sub(sort_items, line)


def _check(capsys, args) -> tuple[int, str, str]:
    code = main(["check", *args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# -- the corpus itself -------------------------------------------------------------


def test_corpus_is_complete():
    assert len(CASES) >= 10
    codes = set()
    for case in CASES:
        lines = _expected(case)
        assert lines, f"{case}: expected.txt is empty"
        for line in lines:
            assert LINE_RE.match(line), f"{case}: not a located diagnostic line: {line!r}"
            codes.add(line.rsplit("[", 1)[1].rstrip("]"))
        reason = _xfail(case)
        assert reason is None or len(reason) > 40, f"{case}: xfail.txt must explain the bug"
        assert (INVALID / case / "model.yaml").read_text(encoding="utf-8").rstrip().splitlines()[-1].startswith("#"), \
            f"{case}: model.yaml should end with a comment saying what is wrong"
    assert REQUIRED_CODES <= codes


def test_normalise_only_reorders_sampled_values():
    line = "x (at 1 of 3 sampled states, e.g. w.th = 1.57, w.p = 0.3); y (e.g. two sources, two terminations)"
    assert _normalise(line) == ("x (at 1 of 3 sampled states, e.g. w.p = 0.3, w.th = 1.57); "
                                "y (e.g. two sources, two terminations)")


# -- phc check: exit code 1, no traceback, exactly the expected located lines -------------


@pytest.mark.parametrize("case", _params())
def test_check_reports_expected_diagnostics(case, capsys, monkeypatch):
    monkeypatch.chdir(INVALID / case)
    code, out, err = _check(capsys, ["model.yaml"])
    for text in (out, err):
        assert "Traceback" not in text
        assert "internal error" not in text
    assert code == 1, f"exit code {code}\nstdout:\n{out}\nstderr:\n{err}"
    got = [line for line in (out + "\n" + err).splitlines() if LOCATED.match(line)]
    assert [_normalise(x) for x in got] == [_normalise(x) for x in _expected(case)]


@pytest.mark.parametrize("case", _params())
def test_check_json_says_not_certified(case, capsys, monkeypatch):
    """The JSON report agrees: not certified, and the expected codes are among its diagnostics."""
    import json

    monkeypatch.chdir(INVALID / case)
    code, out, _ = _check(capsys, ["model.yaml", "--format", "json"])
    assert code == 1
    report = json.loads(out)
    assert report["certified"] is False
    codes = {d["code"] for d in report["diagnostics"]}
    assert {line.rsplit("[", 1)[1].rstrip("]") for line in _expected(case)} <= codes


# -- a warning alone does not fail the check -------------------------------------------


TWO_PARTS = """\
format_version: 1
name: two_parts
components:
  m1: {type: mass, m: 1.0}
  s1: {type: spring, k: 1.0}
  m2: {type: mass, m: 2.0}
  s2: {type: spring, k: 3.0}
connections:
  - [m1.port, s1.port]
  - [m2.port, s2.port]
"""


def test_unconnected_sub_assemblies_warn_but_certify(tmp_path, capsys, monkeypatch):
    (tmp_path / "model.yaml").write_text(TWO_PARTS)
    monkeypatch.chdir(tmp_path)
    code, out, err = _check(capsys, ["model.yaml"])
    assert "Traceback" not in out + err and "internal error" not in out + err
    assert code == 0, out + err
    assert out.splitlines()[0].startswith("two_parts: certified")
    warnings = [line for line in (out + err).splitlines() if "[PHC-W201]" in line]
    assert len(warnings) == 1
    assert "warning:" in warnings[0]
    assert "2 independent parts" in warnings[0]
    assert "{m1, s1}" in warnings[0] and "{m2, s2}" in warnings[0]
    assert "independent parts: 2" in out


# -- output must not depend on the interpreter's hash seed -----------------------------------


WHEEL_ON_SUPPORT = """\
format_version: 1
components:
  wheel:
    type: rigid
    q: [th]
    M: [[1]]
    ports:
      drive:
        B: [["cos(th)"]]
  stop: {type: zero_flow}
connections:
  - [stop.port, wheel.drive]
simulation:
  initial: {wheel.th: 1.5707963267948966}
"""


def test_check_output_does_not_depend_on_hash_seed(tmp_path):
    (tmp_path / "model.yaml").write_text(WHEEL_ON_SUPPORT)
    env = dict(os.environ)
    procs = []
    for seed in ("0", "1"):   # two seeds that give different orders with phc as of this test
        env["PYTHONHASHSEED"] = seed
        procs.append(subprocess.Popen([sys.executable, "-m", "phc", "check", "model.yaml"], cwd=tmp_path,
                                      env=dict(env), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                      text=True))
    outputs = []
    for proc in procs:
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 1, err
        outputs.append(out + err)
    assert "[PHC-E421]" in outputs[0]
    assert all(o == outputs[0] for o in outputs), "\n---\n".join(outputs)
