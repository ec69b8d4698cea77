"""The hostile corpus: model and scene files written to attack phc, each refused with a
located one-line error and nothing executed.

Every folder of ``tests/models/hostile/`` is one attack (the first line of its ``model.yaml``
or ``scene.yaml`` says which): code injection through every string that reaches generated
code (names, references, expressions, file names), YAML tags, anchors and aliases, deep
nesting, huge numbers, NaN and infinity, encodings, byte order marks, NUL and control
characters, terminal escape sequences, very long text, duplicate keys, path traversal and
malformed CSV tables. Cases that need files git cannot hold (FIFOs, symlinks out of the
tree, binary ``.npz`` archives) or that are too large to keep are made by :data:`GENERATED`.

Layout of a case folder::

    model.yaml      the model (the entry point unless there is a scene.yaml)
    scene.yaml      optional: the entry point is this scene, which uses model.yaml
    expected.txt    the exact stderr lines of `phc validate ENTRY` run inside the folder, or
    expected.re     one regular expression per line, each matching one stderr line in full
                    (for messages owned by code still in flux: the location and code matter), or
    accept.txt      the input is valid (hostile text where free text is allowed): it must
                    validate, compile and simulate, and its text must not become code
    xfail.txt       optional: "being fixed: <area> ..." — a strict xfail for a known gap
    *.csv, ...      files the model refers to

What every case must satisfy: exit code 1 (0 for ``accept.txt``), nothing on stdout, no
traceback or "internal error", every stderr line ``file:line:col: ... [PHC-Exxx]`` with the
file inside the case folder, no line quoting the content of a system file, the whole run
under :data:`TIME_LIMIT` seconds, and the canary :data:`CANARY` — the file every payload
would create — never appearing. Expected lines were written from what a user needs and
checked by hand, like ``tests/models/invalid/``.

To add a case: make the folder, write the model, write ``expected.txt`` (or ``.re``), run
``python -m pytest tests/models/test_hostile_corpus.py -q -k <case>``.
"""

from __future__ import annotations

import ast
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.cli import main
from time_limits import time_limit

HERE = Path(__file__).parent
HOSTILE = HERE / "hostile"
CASES = sorted(p.name for p in HOSTILE.iterdir() if (p / "model.yaml").is_file())
CANARY = Path("/tmp/phc_hostile_canary")
"""The file every payload of the corpus would create (an absolute path: whatever the working
directory of a payload)."""
TIME_LIMIT = 20
"""CPU seconds a case may take (:func:`time_limits.time_limit`: a hang is a failure, not a stuck CI job)."""
LINE_RE = re.compile(r"^(?P<file>[\w.-]+\.(?:yaml|csv|npz)):\d+:\d+: .+ \[PHC-E\d{3}\]$")
SECRETS = ("root:", "/bin/", "AWS_SECRET", "hunter2", "PATH=")
"""Text from system or secret files that no message may quote."""
KINDS = ("expected.txt", "expected.re", "accept.txt")


@pytest.fixture(autouse=True)
def canary():
    assert not CANARY.exists(), f"{CANARY} exists before the test: an earlier run executed a payload " \
                                "(find out which, then remove the file)"
    yield CANARY
    assert not CANARY.exists(), f"a payload ran: {CANARY} was created"


def _kind(folder: Path) -> str:
    found = [k for k in KINDS if (folder / k).is_file()]
    assert len(found) == 1, f"{folder.name}: needs exactly one of {KINDS}, has {found}"
    return found[0]


def _lines(path: Path) -> list[str]:
    return [line for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def _params() -> list:
    out = []
    for case in CASES:
        xfail = HOSTILE / case / "xfail.txt"
        marks = [pytest.mark.xfail(strict=True, reason=" ".join(xfail.read_text().split()))] if xfail.is_file() else []
        out.append(pytest.param(case, id=case, marks=marks))
    return out


def _validate(folder: Path, capsys) -> tuple[int, str, str]:
    entry = "scene.yaml" if (folder / "scene.yaml").is_file() else "model.yaml"
    with time_limit(TIME_LIMIT):
        code = main(["validate", entry])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def check_refused(folder: Path, code: int, out: str, err: str) -> list[str]:
    """The common contract of a refused case; returns the stderr lines."""
    for text in (out, err):
        assert "Traceback" not in text and "internal error" not in text, err
    assert code == 1, f"exit code {code}; stderr:\n{err}"
    assert out == ""
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines, "no diagnostic"
    for line in lines:
        match = LINE_RE.match(line)
        assert match, f"not a located one-line diagnostic: {line!r}"
        assert (folder / match.group("file")).exists(), f"located outside the case's files: {line!r}"
        assert not any(s in line for s in SECRETS), f"quotes a file's content: {line!r}"
        assert len(line) < 1200, f"a diagnostic of {len(line)} characters"
    return lines


def check_expected(folder: Path, lines: list[str]) -> None:
    kind = _kind(folder)
    if kind == "expected.txt":
        assert lines == _lines(folder / kind)
    else:
        patterns = _lines(folder / kind)
        assert len(lines) == len(patterns), f"{len(lines)} lines, expected {len(patterns)}:\n" + "\n".join(lines)
        for line, pattern in zip(lines, patterns):
            assert re.fullmatch(pattern, line), f"{line!r}\ndoes not match\n{pattern!r}"


def _no_calls_to_dangerous_names(source: str) -> None:
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, (ast.Name, ast.Attribute)):
            name = node.func.id if isinstance(node.func, ast.Name) else node.func.attr
            assert name not in ("open", "__import__", "eval", "exec", "system", "check_call"), \
                f"the generated module calls `{name}`"


# -- the corpus ----------------------------------------------------------------------

def test_corpus_is_complete():
    assert len(CASES) >= 80
    for case in CASES:
        folder = HOSTILE / case
        kind = _kind(folder)
        if kind == "expected.txt":
            for line in _lines(folder / kind):
                assert LINE_RE.match(line), f"{case}: not a diagnostic line: {line!r}"
        if kind == "expected.re":
            for pattern in _lines(folder / kind):
                re.compile(pattern)
        xfail = folder / "xfail.txt"
        if xfail.is_file():
            assert xfail.read_text().startswith("being fixed: "), f"{case}: xfail.txt names the area being fixed"


@pytest.mark.parametrize("case", _params())
def test_hostile_case(case, tmp_path, capsys, monkeypatch):
    folder = tmp_path / case
    shutil.copytree(HOSTILE / case, folder, symlinks=True)
    monkeypatch.chdir(folder)
    code, out, err = _validate(folder, capsys)
    if _kind(folder) == "accept.txt":
        assert code == 0 and "internal error" not in err, err
        entry = "scene.yaml" if (folder / "scene.yaml").is_file() else "model.yaml"
        with time_limit(TIME_LIMIT):
            compiled = phc.compile_model(entry)
            result = phc.simulate(compiled)
        assert result.success
        _no_calls_to_dangerous_names(compiled.source)
        return
    lines = check_refused(folder, code, out, err)
    check_expected(folder, lines)
    dae, diags = phc.build_dae("scene.yaml" if (folder / "scene.yaml").is_file() else "model.yaml")
    assert dae is None and diags.has_errors


# -- generated cases: files git cannot hold, or too large to keep -------------------------

MODEL = """\
format_version: 1
components:
  mass: {type: mass, m: 1.0}
  spring: {type: spring, k: 2.0}
connections:
  - [mass.port, spring.port]
"""

TABLE_MODEL = """\
format_version: 1
components:
  mass: {type: mass, m: 1.0}
ports:
  force: {port: mass.port}
simulation:
  inputs:
    force:
      effort: {file: table.csv, column: F}
"""

NESTED_MODEL = """\
format_version: 1
components:
  inner: {type: model, file: inner.yaml}
"""

NPZ_MODEL = """\
format_version: 1
components:
  lin:
    type: linear_phs
    states: 2
    matrices: m.npz
    J: J
    ports:
      tip: {B: [[0], [1]], domain: mechanical.translational}
  free: {type: zero_effort, domain: mechanical.translational}
connections:
  - [lin.tip, free.port]
"""

TABLE_FILE = r"model\.yaml:9:22: simulation\.inputs\.force\.effort\.file: table `table\.csv` .+ \[PHC-E(116|213)\]"
NPZ_FILE = r"model\.yaml:6:15: components\.lin\.matrices: matrices file `m\.npz` .+ \[PHC-E1(16|30)\]"
NPZ_ARRAY = r"model\.yaml:7:8: components\.lin\.J: .*array `J` in `m\.npz`.+ \[PHC-E131\]"


def _write(folder: Path, files: dict) -> None:
    for name, content in files.items():
        (folder / name).write_bytes(content.encode() if isinstance(content, str) else content)


def _block_nesting(folder: Path) -> None:
    _write(folder, {"model.yaml": "format_version: 1\nparameters:\n"
                    + "".join(" " * (i + 2) + f"k{i}:\n" for i in range(1500)) + MODEL[18:]})


def _long_line(folder: Path) -> None:  # a line of 150 kB: a flow mapping with a bad name at its end
    _write(folder, {"model.yaml": "format_version: 1\nparameters: {" +
                    ", ".join(f"p{i}: {i}" for i in range(10000)) + ", 'bad key': 1}\n" + MODEL[18:]})


def _fifo(name: str, model: str):
    def make(folder: Path) -> None:
        _write(folder, {"model.yaml": model})
        os.mkfifo(folder / name)
    return make


def _symlink(name: str, target: str, model: str):
    def make(folder: Path) -> None:
        _write(folder, {"model.yaml": model})
        os.symlink(target, folder / name)
    return make


def _npz(**arrays):
    def make(folder: Path) -> None:
        _write(folder, {"model.yaml": NPZ_MODEL})
        np.savez(folder / "m.npz", **arrays)
    return make


def _npz_bytes(content: bytes):
    def make(folder: Path) -> None:
        _write(folder, {"model.yaml": NPZ_MODEL, "m.npz": content})
    return make


def _truncated_npz(folder: Path) -> None:
    _npz(J=np.array([[0.0, 1.0], [-1.0, 0.0]]))(folder)
    with open(folder / "m.npz", "r+b") as f:
        f.truncate(100)


def _fifo_top_level(folder: Path) -> None:
    os.mkfifo(folder / "model.yaml")


GENERATED = {
    "fifo_top_level": (_fifo_top_level, [r"model\.yaml:1:1: cannot read `model\.yaml`: .+ \[PHC-E004\]"]),
    "block_nesting_1500": (_block_nesting, [r"model\.yaml:\d+:\d+: document nested too deeply .+ \[PHC-E003\]"]),
    "line_of_150_kilobytes": (_long_line, [
        r"model\.yaml:2:\d+: parameters\.bad key: `bad key` is not a valid name; .+ \[PHC-E016\]"]),
    "fifo_table": (_fifo("table.csv", TABLE_MODEL), [TABLE_FILE]),
    "fifo_nested_model": (_fifo("inner.yaml", NESTED_MODEL), [
        r"model\.yaml:3:30: components\.inner\.file: nested model file `inner\.yaml` .+ \[PHC-E116\]"]),
    "symlink_table_to_passwd": (_symlink("table.csv", "/etc/passwd", TABLE_MODEL), [TABLE_FILE]),
    "symlink_nested_to_dev_zero": (_symlink("inner.yaml", "/dev/zero", NESTED_MODEL), [
        r"model\.yaml:3:30: components\.inner\.file: nested model file `inner\.yaml` .+ \[PHC-E116\]"]),
    "npz_object_array": (_npz(J=np.array([[0, {"a": 1}], [None, 0]], dtype=object)), [NPZ_ARRAY]),
    "npz_3d": (_npz(J=np.zeros((2, 2, 2))), [NPZ_ARRAY]),
    "npz_strings": (_npz(J=np.array([["0", "1"], ["-1", "0"]])), [NPZ_ARRAY]),
    "npz_nan": (_npz(J=np.array([[0.0, np.nan], [-1.0, 0.0]])), [NPZ_ARRAY]),
    "npz_negative_index": (_npz(**{"J.data": np.array([1.0, -1.0]), "J.indices": np.array([-1, 0]),
                                   "J.indptr": np.array([0, 1, 2]), "J.shape": np.array([2, 2])}), [NPZ_ARRAY]),
    "npz_negative_shape": (_npz(**{"J.data": np.array([1.0]), "J.indices": np.array([0]),
                                   "J.indptr": np.array([0, 1, 1]), "J.shape": np.array([-2, 2])}), [NPZ_ARRAY]),
    "npz_truncated": (_truncated_npz, [NPZ_FILE]),
    "npz_not_a_zip": (_npz_bytes(b"J: [[0, 1], [-1, 0]]\n"), [NPZ_FILE]),
    "csv_field_of_200000_characters": (lambda folder: _write(folder, {
        "model.yaml": TABLE_MODEL, "table.csv": "t,F\n0," + "1" * 200_000 + "\n"}), [TABLE_FILE]),
}


@pytest.mark.parametrize("case", sorted(GENERATED))
def test_generated_hostile_case(case, tmp_path, capsys, monkeypatch):
    make, patterns = GENERATED[case]
    make(tmp_path)
    monkeypatch.chdir(tmp_path)
    code, out, err = _validate(tmp_path, capsys)
    lines = check_refused(tmp_path, code, out, err)
    assert len(lines) == len(patterns), "\n".join(lines)
    for line, pattern in zip(lines, patterns):
        assert re.fullmatch(pattern, line), f"{line!r}\ndoes not match\n{pattern!r}"


def test_inline_data_too_large_is_not_called_alias_expansion():
    """A document over the limit of values written without any alias (an inline matrix) is
    "too large", with a hint to move the data to a file; "alias expansion" is for aliases
    (billion laughs), whose limit counts the nodes they add.
    (A small limit: PyYAML composes some 15 000 nodes a second, too slow for 100 000 here.)"""
    from phc.frontend.source import load_yaml

    row = "[" + ", ".join(["0"] * 40) + "]"
    inline = "J:\n" + "".join(f"  - {row}\n" for _ in range(40))
    _, _, diags = load_yaml(inline, "m.yaml", max_nodes=1000, max_values=1000)
    assert [d.render() for d in diags] == [
        "m.yaml:2:3: document too large: more than 1000 values. hint: put large matrices into an `.npz` file "
        "(`matrices:` of a `linear_phs`) and long signals into a CSV table [PHC-E003]"]
    aliased = "a: &a " + row + "\nb: [" + ", ".join(["*a"] * 40) + "]\n"
    _, _, diags = load_yaml(aliased, "m.yaml", max_nodes=1000)
    assert len(diags) == 1 and "alias expansion" in diags[0].message
