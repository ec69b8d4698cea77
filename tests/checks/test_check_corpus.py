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

Values phc computes at its own random samples (``f·e = …`` of a non-passive law, ``max |J +
Jᵀ| = …`` of a modulated J) stand in ``expected.txt`` as placeholders (``<sampled->``, see
:mod:`golden`); every case also runs with every sampler's seed shifted, so no expected line
pins a sample.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from golden import matches, resolved, shift_seeds

from phc.cli import main
from time_limits import SUBPROCESS_TIMEOUT

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


def test_placeholders_stand_only_for_sampled_numbers():
    line = "model.yaml:10:7: osc: f·e = <sampled-> < 0 at f = [<sampled>]; max |J + Jᵀ| = <sampled+> [PHC-E406]"
    assert matches(line, "model.yaml:10:7: osc: f·e = -0.00112 < 0 at f = [0.047]; max |J + Jᵀ| = 2.5e-05 [PHC-E406]")
    assert matches(line, "model.yaml:10:7: osc: f·e = -3 < 0 at f = [-1.2e+03]; max |J + Jᵀ| = 0.251 [PHC-E406]")
    assert not matches(line, "model.yaml:10:7: osc: f·e = 0.5 < 0 at f = [0.047]; max |J + Jᵀ| = 0.25 [PHC-E406]")
    assert not matches(line, "model.yaml:10:7: osc: f·e = -0.5 < 0 at f = [0.047]; max |J + Jᵀ| = 0 [PHC-E406]")
    assert not matches(line, "model.yaml:10:7: osc: f·e = -0.5 < 0 at f = [x]; max |J + Jᵀ| = 0.25 [PHC-E406]")
    assert not matches(line, "model.yaml:10:8: osc: f·e = -0.5 < 0 at f = [0.1]; max |J + Jᵀ| = 0.25 [PHC-E406]")
    assert matches("a = 1.57 (max 0.3)", "a = 1.57 (max 0.3)") and not matches("a = 1.57", "a = 1.58")


@pytest.mark.parametrize("seed_shift", [0, 7], ids=["seeds", "shifted-seeds"])
@pytest.mark.parametrize("case", _params())
def test_check_reports_expected_diagnostics(case, seed_shift, capsys, monkeypatch):
    shift_seeds(monkeypatch, seed_shift)
    monkeypatch.chdir(INVALID / case)
    code, out, err = _check(capsys, ["model.yaml"])
    for text in (out, err):
        assert "Traceback" not in text
        assert "internal error" not in text
    assert code == 1, f"exit code {code}\nstdout:\n{out}\nstderr:\n{err}"
    got = [_normalise(line) for line in (out + "\n" + err).splitlines() if LOCATED.match(line)]
    assert got == resolved([_normalise(x) for x in _expected(case)], got)


@pytest.mark.parametrize("seed_shift", [0, 7], ids=["seeds", "shifted-seeds"])
def test_the_failing_sample_of_a_non_passive_law_is_its_own(seed_shift, capsys, monkeypatch):
    """resistive_not_passive has e_R = −r f_R with r = 0.5: the power printed is −r f² at the
    flow printed (f to 3 decimals, the power to 3 digits), whatever the samples are."""
    shift_seeds(monkeypatch, seed_shift)
    monkeypatch.chdir(INVALID / "resistive_not_passive")
    _, out, err = _check(capsys, ["model.yaml"])
    m = re.search(r"f·e = (\S+) < 0 at f = \[(\S+)\]", out + err)
    assert m, out + err
    power, flow = float(m.group(1)), float(m.group(2))
    assert power < 0 and abs(power + 0.5 * flow**2) <= 0.5 * (2 * abs(flow) * 5e-4 + 2.5e-7) + 5e-3 * abs(power)


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
        out, err = proc.communicate(timeout=SUBPROCESS_TIMEOUT)
        assert proc.returncode == 1, err
        outputs.append(out + err)
    assert "[PHC-E421]" in outputs[0]
    assert all(o == outputs[0] for o in outputs), "\n---\n".join(outputs)
