"""Benchmark figures that cannot go stale (issue 30 item 5).

benchmarks/depends.toml declares, for every benchmark, the command that measures it, the
result files that show its current figures and the files it depends on (its script, its
models, the parts of phc on its path). Every result file carries the commit it was
measured at (the header benchmarks/record.py writes). Here, with git:

* a result file whose commit is older than the last commit touching any of its
  dependencies fails, naming the file, the commits since and the command to rerun;
* a result file without a commit fails; so does a declared dependency that matches no
  tracked file (a misspelt path would make every result look fresh);
* every benchmark script is declared, every module of phc is some benchmark's
  dependency or declared unmeasured, and every data file under benchmarks/ is a result,
  an output of a benchmark's run, or history (measured once for a comparison);
* the generated parts of benchmarks/README.md (the index of the current figures and the
  tables of the result files) are what the result files say now.

Without git history (no ``.git``, a shallow clone, no ``git``) the comparisons skip with
the reason; CI's fresh clone has the history.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
MANIFEST = BENCHMARKS / "depends.toml"
COMMIT = re.compile(r"; commit ([0-9a-f]{7,40})( \(with uncommitted changes\))?\.")
DATA = {".md", ".json", ".csv", ".png"}

sys.path.insert(0, str(BENCHMARKS))
import readme_results  # noqa: E402


def _manifest() -> dict:
    return tomllib.loads(MANIFEST.read_text(encoding="utf-8"))


def _depends(name: str, manifest: dict | None = None) -> list[str]:
    """The benchmark's dependencies with the @groups expanded."""
    manifest = manifest or _manifest()
    out = []
    for entry in manifest["benchmarks"][name]["depends"]:
        if entry.startswith("@"):
            out += manifest["groups"][entry[1:]]
        else:
            out.append(entry)
    return out


def _results() -> list[tuple[str, str]]:
    manifest = _manifest()
    return [(name, path) for name, spec in manifest["benchmarks"].items() for path in spec["results"]]


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, timeout=60)


def _history_reason() -> str | None:
    """Why the git comparisons cannot run here, or None."""
    if shutil.which("git") is None:
        return "git is not installed"
    top = _git("rev-parse", "--show-toplevel")
    if top.returncode != 0 or Path(top.stdout.strip()).resolve() != ROOT.resolve():
        return f"{ROOT} is not a git checkout (no .git): the commits of the result files cannot be compared"
    if _git("rev-parse", "--is-shallow-repository").stdout.strip() == "true":
        return "shallow clone: the history needed to order the result files' commits is missing"
    return None


@pytest.fixture(scope="module")
def git_history():
    reason = _history_reason()
    if reason:
        pytest.skip(reason)


# ---------------------------------------------------------------------------------------
# the declarations


def test_every_benchmark_script_is_declared():
    declared = {dep for name in _manifest()["benchmarks"] for dep in _depends(name)}
    scripts = {p.relative_to(ROOT).as_posix() for p in BENCHMARKS.glob("bench_*.py")}
    missing = sorted(scripts - declared)
    assert not missing, f"benchmark scripts missing from {MANIFEST.relative_to(ROOT)}: {missing}"


def test_every_phc_module_is_measured_or_declared_unmeasured():
    """A new module of phc lands in some benchmark's dependencies (or in [unmeasured])."""
    manifest = _manifest()
    covered = {dep.rstrip("/") for name in manifest["benchmarks"] for dep in _depends(name, manifest)}
    covered |= set(manifest["unmeasured"]["files"])
    modules = [p.relative_to(ROOT).as_posix() for p in sorted((ROOT / "phc").rglob("*.py"))]
    left_out = [m for m in modules if not any(m == c or m.startswith(c + "/") for c in covered)]
    assert not left_out, (f"phc modules that no benchmark in {MANIFEST.relative_to(ROOT)} depends on: {left_out}; "
                          "add them to the `depends` (or a group) of the benchmarks that run them, or to "
                          "[unmeasured]")


def test_every_data_file_under_benchmarks_is_declared():
    manifest = _manifest()
    declared = set(manifest["history"]["files"])
    for spec in manifest["benchmarks"].values():
        declared |= set(spec["results"]) | set(spec.get("outputs", []))
    files = {p.relative_to(ROOT).as_posix() for p in BENCHMARKS.rglob("*")
             if p.is_file() and p.suffix in DATA and p.parent != BENCHMARKS}
    undeclared = sorted(files - declared)
    assert not undeclared, (f"files under benchmarks/ that {MANIFEST.relative_to(ROOT)} does not declare as a "
                            f"result, an output or history: {undeclared}")
    missing = sorted(path for path in declared if not (ROOT / path).is_file())
    assert not missing, f"declared in {MANIFEST.relative_to(ROOT)} but missing: {missing}"


@pytest.mark.parametrize("name, path", _results(), ids=[path for _, path in _results()])
def test_result_file_carries_its_commit(name, path):
    if not (ROOT / path).is_file():
        pytest.fail(f"{path} is missing; run `{_manifest()['benchmarks'][name]['command']}`", pytrace=False)
    text = (ROOT / path).read_text(encoding="utf-8")
    assert COMMIT.search(text), (f"{path} does not say which commit it was measured at; rerun "
                                 f"`{_manifest()['benchmarks'][name]['command']}`")


def test_every_dependency_is_a_tracked_path(git_history):
    manifest = _manifest()
    for name in manifest["benchmarks"]:
        for dep in _depends(name, manifest):
            listed = _git("ls-files", "--", dep)
            assert listed.stdout.strip(), f"{MANIFEST.relative_to(ROOT)}: `{name}` depends on `{dep}`, which " \
                                          "matches no tracked file"


# ---------------------------------------------------------------------------------------
# freshness


@pytest.mark.parametrize("name, path", _results(), ids=[path for _, path in _results()])
def test_result_file_is_newer_than_the_code_it_measures(name, path, git_history):
    spec = _manifest()["benchmarks"][name]
    if not (ROOT / path).is_file():
        pytest.fail(f"{path} is missing; run `{spec['command']}`", pytrace=False)
    m = COMMIT.search((ROOT / path).read_text(encoding="utf-8"))
    if not m:
        pytest.fail(f"{path} carries no commit; rerun `{spec['command']}`", pytrace=False)
    measured = _git("rev-parse", "--verify", "--quiet", f"{m.group(1)}^{{commit}}").stdout.strip()
    if not measured:
        pytest.fail(f"{path} was measured at commit {m.group(1)}, which is not in this repository's history; "
                    f"rerun `{spec['command']}`", pytrace=False)
    paths = _depends(name)
    last = _git("log", "-1", "--format=%H", "--", *paths).stdout.strip()
    if not last:
        return  # nothing it depends on was ever committed
    ancestor = _git("merge-base", "--is-ancestor", last, measured)
    if ancestor.returncode == 0:
        return
    assert ancestor.returncode == 1, ancestor.stderr
    since = _git("log", "--format=%h %s", f"{measured}..HEAD", "--", *paths).stdout.splitlines()
    changed = _git("diff", "--name-only", measured, "HEAD", "--", *paths).stdout.split()
    shown = "\n  ".join(line[:140] for line in since[:5]) + (f"\n  ... {len(since) - 5} more" if len(since) > 5
                                                             else "")
    pytest.fail(f"{path} is stale: measured at {m.group(1)}, but {len(since)} later commit(s) changed what "
                f"`{name}` depends on ({', '.join(changed[:8])}{' ...' if len(changed) > 8 else ''}):\n  {shown}\n"
                f"rerun: {spec['command']}", pytrace=False)


# ---------------------------------------------------------------------------------------
# the README shows the result files as they are


def test_readme_shows_the_result_files_as_they_are():
    readme = BENCHMARKS / "README.md"
    text = readme.read_text(encoding="utf-8")
    expected = readme_results.refresh_readme(text)
    assert text == expected, ("benchmarks/README.md differs from its result files (a generated block was edited "
                              "by hand, or a result file changed since); run `python benchmarks/readme_results.py`")
    names = set(re.findall(r"<!-- results:(\w+) begin", text))
    missing = sorted({Path(path).stem for _, path in _results()} - names)
    assert not missing, f"benchmarks/README.md shows no block of the result files {missing}"
