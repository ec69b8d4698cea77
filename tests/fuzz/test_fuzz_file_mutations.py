"""A cached run equals an uncached one, whatever happens to the files a model refers to
(issue 32, "Done when": the fuzzer mutates referenced files between two runs).

A model tree — a top model, a part it includes (`parts/gear.yaml`), an input table
(`data/torque.csv`) — is changed between runs of ``phc simulate`` by a random sequence of
the edits a user (or a build tool) makes: a value edited, a file deleted or restored, a
symbolic link repointed (file or directory), a file replaced by a directory or made
invalid, a column renamed, the same bytes written again, and new bytes of the same size
with the old modification time put back. After every edit the command runs twice: with
the cached front end (:mod:`phc.codegen.fastpath`, which may answer from a record of an earlier
state of the tree) and with it switched off (``PHC_FRONT_END_CACHE=0``). The two must
agree: the same exit status; on success the same CSV, byte for byte; on failure the same
error codes, each in a located one-line message.

The default run is derandomized and small; ``-m slow`` draws fresh sequences, 20 times as
many (``PHC_FUZZ_EXAMPLES`` sets the count).
"""

from __future__ import annotations

import contextlib
import inspect
import io
import os
import re
import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from phc.codegen import fastpath
from phc.cli import main

EXAMPLES = 5
"""Edit sequences in the default run (each runs the command twice per edit)."""
SLOW_FACTOR = 20

PART = """\
format_version: 1
name: gear_stage
kind: part
parameters:
  N: {ratio}
components:
  g: {{type: transformer, ratio: N, domain_a: mechanical.rotational}}
ports:
  input: {{port: g.a}}
  output: {{port: g.b}}
"""

TOP = """\
format_version: 1
name: driven_gear
parameters:
  J: 0.5
components:
  stage: {type: model, file: parts/gear.yaml}
  load: {type: mass, m: J, domain: mechanical.rotational}
connections:
  - [stage.output, load.port]
ports:
  drive: {port: stage.input}
simulation:
  t_end: 1.0
  n_out: 11
  initial: {load.p: 0.0}
  outputs: {p: load.p}
  inputs:
    drive:
      effort: {file: data/torque.csv, column: tau}
"""


def _table(scale: float, column: str = "tau") -> str:
    return f"t,{column}\n" + "".join(f"{t:.1f},{scale * (1.0 + t):.6g}\n" for t in (0.0, 0.5, 1.0))


def _build(root: Path) -> Path:
    """The tree every sequence starts from; returns the top model."""
    for version, ratio in (("parts_v1", "3.0"), ("parts_v2", "5.0")):
        (root / version).mkdir()
        (root / version / "gear.yaml").write_text(PART.format(ratio=ratio), encoding="utf-8")
    (root / "parts").symlink_to("parts_v1")
    (root / "data").mkdir()
    (root / "data" / "torque.csv").write_text(_table(2.0), encoding="utf-8")
    top = root / "top.yaml"
    top.write_text(TOP, encoding="utf-8")
    return top


def _remove(path: Path) -> None:
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.is_dir():
        shutil.rmtree(path)


def _same_size_same_time(path: Path, text: str) -> None:
    """New content of the old length with the old modification time put back (a cache
    that trusted size and time would answer for the old file)."""
    if not path.is_file():
        return
    old = path.read_text(encoding="utf-8")
    stat = path.stat()
    new = text[: len(old)].ljust(len(old))
    path.write_text(new, encoding="utf-8")
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))


def _edit(root: Path, edit: tuple) -> None:
    kind, value = edit
    parts = root / "parts"
    part = parts / "gear.yaml"
    table = root / "data" / "torque.csv"
    if kind == "ratio":  # edit the part through the link (the target file changes)
        if part.is_file():
            part.write_text(PART.format(ratio=value), encoding="utf-8")
    elif kind == "relink directory":
        _remove(parts)
        parts.symlink_to(value)
    elif kind == "relink file":  # parts/ a real directory whose gear.yaml links to one version
        if parts.is_symlink():
            target = parts.resolve()
            parts.unlink()
            shutil.copytree(target, parts)
        _remove(part)
        part.symlink_to(Path("..") / value / "gear.yaml")
    elif kind == "delete part":
        _remove(part)
    elif kind == "restore part":
        if not part.exists():
            part.parent.mkdir(exist_ok=True)
            _remove(part)  # a dangling link
            part.write_text(PART.format(ratio="4.0"), encoding="utf-8")
    elif kind == "invalid part":
        if part.is_file():
            part.write_text(PART.format(ratio="3.0").replace("ratio: N", "ratio: [N"), encoding="utf-8")
    elif kind == "part is a directory":
        _remove(part)
        part.mkdir(parents=True)
    elif kind == "table scale":
        _remove(table)
        table.write_text(_table(value), encoding="utf-8")
    elif kind == "table column":
        _remove(table)
        table.write_text(_table(2.0, column=value), encoding="utf-8")
    elif kind == "delete table":
        _remove(table)
    elif kind == "same bytes":
        for path in (part, table):
            if path.is_file():
                path.write_bytes(path.read_bytes())
    elif kind == "same size, same time":
        _same_size_same_time(table, _table(value))
    else:
        raise AssertionError(kind)


EDITS = st.one_of(
    st.tuples(st.just("ratio"), st.sampled_from(["2.0", "3.0", "7.0"])),
    st.tuples(st.just("relink directory"), st.sampled_from(["parts_v1", "parts_v2"])),
    st.tuples(st.just("relink file"), st.sampled_from(["parts_v1", "parts_v2"])),
    st.tuples(st.sampled_from(["delete part", "restore part", "invalid part", "part is a directory",
                               "delete table", "same bytes"]), st.none()),
    st.tuples(st.just("table scale"), st.sampled_from([1.0, 2.0, 3.0])),
    st.tuples(st.just("table column"), st.sampled_from(["tau", "torque"])),
    st.tuples(st.just("same size, same time"), st.sampled_from([3.0, 4.0])),
)

CODE = re.compile(r"\[PHC-[EW]\d{3}\]")


def _simulate(top: Path, out: Path, cached: bool) -> tuple[int, str, bytes]:
    """(exit status, what it printed, the CSV it wrote or b"")."""
    _remove(out)
    stdout, stderr = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as env, contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        if cached:
            env.delenv(fastpath.ENV_SWITCH, raising=False)
        else:
            env.setenv(fastpath.ENV_SWITCH, "0")
        code = main(["simulate", str(top), "--out", str(out), "--quiet", "--no-certify"])
    return code, stdout.getvalue() + stderr.getvalue(), out.read_bytes() if out.is_file() else b""


def _check(root: Path, top: Path, history: list) -> int:
    """Run the command with and without the cached front end; returns the exit status."""
    cached = _simulate(top, root.parent / "cached.csv", cached=True)
    fresh = _simulate(top, root.parent / "fresh.csv", cached=False)
    where = f"after {history}"
    assert cached[0] == fresh[0], f"{where}: exit {cached[0]} (cached) vs {fresh[0]}\n{cached[1]}\n{fresh[1]}"
    if fresh[0] == 0:
        assert fresh[2], where
        assert cached[2] == fresh[2], f"{where}: the cached run wrote other results"
    else:
        assert sorted(CODE.findall(cached[1])) == sorted(CODE.findall(fresh[1])), f"{where}\n{cached[1]}\n{fresh[1]}"
        for text in (cached[1], fresh[1]):
            problems = [line for line in text.splitlines() if CODE.search(line)]
            assert problems, f"{where}: a failure without a located message\n{text}"
            assert "Traceback" not in text and "internal error" not in text, text
    return fresh[0]


def _run(edits: list) -> None:
    base = Path(tempfile.mkdtemp(prefix="phc-mutations-"))
    try:
        root = base / "model"
        root.mkdir()
        top = _build(root)
        with pytest.MonkeyPatch.context() as env:
            env.setenv("PHC_CACHE_DIR", str(base / "cache"))
            env.setenv("PHC_STATE_DIR", str(base / "state"))
            assert _check(root, top, []) == 0  # the tree as built runs: the comparisons are not vacuous
            history = []
            for edit in edits:
                _edit(root, edit)
                history.append(edit)
                _check(root, top, history)
    finally:
        shutil.rmtree(base, ignore_errors=True)


_COMMON = dict(deadline=None, database=None,
               suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@settings(max_examples=EXAMPLES, derandomize=True, **_COMMON)
@given(st.lists(EDITS, min_size=1, max_size=3))
def test_cached_and_uncached_runs_agree_after_edits(edits):
    _run(edits)


@pytest.mark.slow
@settings(max_examples=int(os.environ.get("PHC_FUZZ_EXAMPLES", EXAMPLES * SLOW_FACTOR)), derandomize=False,
          **_COMMON)
@given(st.lists(EDITS, min_size=1, max_size=6))
def test_cached_and_uncached_runs_agree_after_edits_random(edits):
    _run(edits)


def test_every_edit_is_drawn_by_the_strategy():
    """The edits the fuzzer knows are all reachable (a kind added to `_edit` and forgotten
    in `EDITS` would never run)."""
    kinds = {"ratio", "relink directory", "relink file", "delete part", "restore part", "invalid part",
             "part is a directory", "table scale", "table column", "delete table", "same bytes",
             "same size, same time"}
    source = Path(__file__).read_text(encoding="utf-8")
    assert kinds == set(re.findall(r'kind == "([^"]+)"', inspect.getsource(_edit)))
    drawn = source.split("EDITS = st.one_of(")[1].split("CODE =")[0]
    assert not [kind for kind in kinds if f'"{kind}"' not in drawn]
