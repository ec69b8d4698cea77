"""The documentation's examples and promises (issue 19).

* every code block of README.md and docs/**/*.md is validated or run
  (:mod:`doc_examples` in tools/: YAML models validated, Python executed, console outputs
  compared with what phc prints — ``python tools/doc_examples.py --update`` rewrites them);
* every diagnostic code phc emits is documented, with an example, in
  docs/reference/diagnostics.md;
* the README stays short and keeps the two set-up commands CI runs;
* no LaTeX label of the paper, no "seed" and no path outside the repository in
  user-facing text; install hints name the distribution;
* the version lives in one place.

`mkdocs build --strict` itself runs in CI (`.ci/run`), not here.
"""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

import doc_examples  # noqa: E402
import docgen  # noqa: E402

import phc  # noqa: E402

# ---------------------------------------------------------------------------------------
# every block


def _blocks():
    out = []
    for path in doc_examples.doc_files():
        for index, block in enumerate(doc_examples.parse_blocks(path)):
            if not block.runs:
                continue
            marks = [pytest.mark.slow] if "slow" in block.options else []
            out.append(pytest.param(str(path), index, id=block.where, marks=marks))
    return out


_PAGES: dict[str, tuple[doc_examples.Page, list, set]] = {}


@pytest.fixture(scope="module", autouse=True)
def _close_pages():
    yield
    for page, _, _ in _PAGES.values():
        page.close()
    _PAGES.clear()


def _page(path: str):
    if path not in _PAGES:
        _PAGES[path] = (doc_examples.Page(Path(path)), doc_examples.parse_blocks(Path(path)), set())
    return _PAGES[path]


@pytest.mark.parametrize("path, index", _blocks())
def test_doc_block(path, index, request):
    """The block runs as the docs say. The blocks of a page share a working directory and
    a namespace; earlier blocks of the page run first when this one is run alone."""
    page, blocks, done = _page(path)
    run_slow = request.config.getoption("-m", default="") and "slow" in request.config.getoption("-m")
    for earlier in range(index):
        block = blocks[earlier]
        if earlier in done or not block.runs or ("slow" in block.options and not run_slow):
            continue
        doc_examples.run_block(block, page)
        done.add(earlier)
    failure = None
    try:
        doc_examples.run_block(blocks[index], page)
    except doc_examples.ExampleFailure as err:
        failure = str(err)
    if failure:
        pytest.fail(failure, pytrace=False)
    done.add(index)


def test_console_blocks_declare_their_tolerance_in_the_known_syntax():
    """`numbers=` parses on every console block and nowhere else; the old `numbers-vary`
    (every number masked, so a page could show figures of an older phc) is gone."""
    for path in doc_examples.doc_files():
        for block in doc_examples.parse_blocks(path):
            assert "numbers-vary" not in block.options, f"{block.where}: `numbers-vary` is gone, declare `numbers=`"
            if "numbers" in block.options:
                assert block.lang == "console", f"{block.where}: `numbers=` is for console blocks"
                doc_examples.block_tolerance(block)  # raises on an unknown item


def test_durations_are_masked_and_other_figures_compared():
    exact = doc_examples.Tolerance()
    solver = doc_examples.Tolerance.parse("solver")
    shown = "  work     535 steps, 655 residual and 29 Jacobian evaluations, 0.026 s CPU, t_final 10"
    assert doc_examples.same_line(shown, shown.replace("0.026 s CPU", "1.5 s CPU"), exact)
    assert doc_examples.same_line("certified (...; 0.08 s)", "certified (...; 12.3 s)", exact)
    assert not doc_examples.same_line(shown, shown.replace("535", "536"), exact)
    assert doc_examples.same_line(shown, shown.replace("535", "700"), solver)  # an adaptive count moved
    assert not doc_examples.same_line(shown, shown.replace("535", "1397"), solver)  # a stale page
    assert not doc_examples.same_line(shown, shown.replace("steps", "stops"), solver)  # text is exact
    balance = "  energy   balance error 6.985e-07 (relative 1.397e-06)"
    assert doc_examples.same_line(balance, "  energy   balance error 2.1e-06 (relative 4.2e-06)", solver)
    assert not doc_examples.same_line(balance, "  energy   balance error 2.405e-09 (relative 4.810e-09)", solver)
    assert not doc_examples.same_line(balance, "  energy   balance error -6.985e-07 (relative 1.397e-06)", solver)
    roundoff = doc_examples.Tolerance.parse("roundoff")
    assert doc_examples.same_line("isotropy 5.6e-16", "isotropy 0.0e+00", roundoff)
    # digits inside words are text, not figures: a changed code is a changed line
    assert not doc_examples.same_line("[PHC-E406]", "[PHC-E407]", doc_examples.Tolerance(rel=1.0))
    digits = doc_examples.Tolerance.parse("digits")
    assert doc_examples.same_line("1  0 ± 3.13209i", "1  0 ± 3.13210i", digits)
    assert not doc_examples.same_line("1  0 ± 3.13209i", "1  0 ± 3.2i", digits)
    with pytest.raises(doc_examples.ExampleFailure):
        doc_examples.Tolerance.parse("rel:0.1,abs:3")


def test_update_rewrites_outputs_still_within_the_tolerance(tmp_path):
    """`--update` writes the fresh output even where the shown one still passes, keeping
    the elisions; the test then passes with the new figures."""
    page = tmp_path / "page.md"
    command = "python -c \"print('start'); print('noise'); print('work 120 steps, 0.5 s CPU'); print('end 3')\""
    page.write_text("# page\n\n<!-- test: numbers=rel:0.5 -->\n```console\n"
                    f"$ {command}\nstart\n...\nwork 100 steps, 9.9 s CPU\nend 3\n```\n", encoding="utf-8")
    block = doc_examples.parse_blocks(page)[0]
    checker = doc_examples.Page(page)
    try:
        doc_examples.run_block(block, checker)  # 100 against 120: within rel 0.5
    finally:
        checker.close()
    assert doc_examples.update_file(page) == 1
    text = page.read_text(encoding="utf-8")
    assert "start\n...\nwork 120 steps, 0.5 s CPU\nend 3\n```" in text


# ---------------------------------------------------------------------------------------
# diagnostics reference

DIAGNOSTICS = ROOT / "docs" / "reference" / "diagnostics.md"


def test_every_diagnostic_code_is_documented_with_an_example():
    """Each code in phc's sources has a section `### PHC-Exxx: ... {#phc-exxx}` with an
    example block, and the page documents no code phc does not have."""
    text = DIAGNOSTICS.read_text(encoding="utf-8")
    sections = dict(re.findall(r"^### (PHC-[EW]\d{3}): [^\n]*\n(.*?)(?=^### |^## |\Z)", text, re.S | re.M))
    emitted = set(docgen.diagnostic_codes())
    missing = sorted(emitted - set(sections))
    assert not missing, (f"codes without a section in {DIAGNOSTICS.relative_to(ROOT)}: {missing}; add a section "
                         "with an example and the fix, then run `python tools/doc_examples.py --update "
                         "docs/reference/diagnostics.md`")
    stale = sorted(set(sections) - emitted)
    assert not stale, f"documented codes that phc no longer emits: {stale}"
    without_example = sorted(code for code, body in sections.items() if "```" not in body)
    assert not without_example, f"sections without an example: {without_example}"


def test_diagnostic_examples_show_their_code():
    """A section's console output (or message text) carries the section's own code."""
    text = DIAGNOSTICS.read_text(encoding="utf-8")
    for code, body in re.findall(r"^### (PHC-[EW]\d{3}): [^\n]*\n(.*?)(?=^### |^## |\Z)", text, re.S | re.M):
        shown = re.findall(r"```(?:console|text)\n(.*?)```", body, re.S)
        assert any(f"[{code}]" in block for block in shown), f"{code}: no example output shows [{code}]"


# ---------------------------------------------------------------------------------------
# README

README = ROOT / "README.md"
TEST_COMMAND = 'python -m pip install ".[test]" && python -m pytest'
MAIN_COMMAND = "python -m pip install . && phc simulate models/pendulum.yaml"


def test_readme_is_short_and_keeps_the_two_commands():
    text = README.read_text(encoding="utf-8")
    assert len(text.encode("utf-8")) < 6000, "the README must stay under 6 KB; move details into docs/"
    assert "## Two commands" in text
    assert MAIN_COMMAND in text and TEST_COMMAND in text


def test_ci_runs_the_readme_test_command_first():
    lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    commands = [line for line in lines if line and not line.startswith("#")]
    first_pip = next(i for i, line in enumerate(commands) if "pip install" in line)
    assert commands[first_pip] == TEST_COMMAND


# ---------------------------------------------------------------------------------------
# user-facing text

USER_FACING = [README, *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "phc").rglob("*.py")),
               *sorted((ROOT / "schemas").glob("*.json"))]
SEED_RE = re.compile(r"the seed|seed paper|seed.s |shared/", re.I)
RANDOM_SEED = re.compile(r"random|sampl|rng|hashseed|seed=|seed:|seed \+|seed\)", re.I)
LABELS = ("couplcond", "rigidDirac2", "mks2", "MKSresrel2", "LagrMech", "BH1gen", "flixBnd", "BNDTrace",
          "BNDtriplet", "Diracflex", "flexDirac", "flexLagr", "flexRes", "ex:expde", "vibstr", "beam_eq",
          "flexbeam-", "slider-crank-wheel", "slider-crank-guide", "slider-crank-dirac", "def-Dir", "prop:",
          "rem:", "Dirac_comp", "infdimlagr", "phinc")


@pytest.mark.parametrize("path", USER_FACING, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_latex_labels_or_seed_in_user_facing_text(path):
    """The paper is cited by section, proposition and equation as a reader finds them."""
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if SEED_RE.search(line) and not RANDOM_SEED.search(line):
            pytest.fail(f"{path.relative_to(ROOT)}:{number}: {line.strip()}", pytrace=False)
        for label in LABELS:
            if label in line:
                pytest.fail(f"{path.relative_to(ROOT)}:{number}: LaTeX label `{label}`: {line.strip()}",
                            pytrace=False)


def test_install_hints_name_the_distribution():
    name = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["name"]
    assert name != "phc"
    for path in USER_FACING:
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for target in re.findall(r"pip install ['\"]?([\w.-]+)\[", line):
                assert target in (".", name), f"{path.relative_to(ROOT)}:{number}: `pip install {target}[...]`"


# ---------------------------------------------------------------------------------------
# one version


def test_the_version_lives_in_one_place():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert "version" not in project and "version" in project.get("dynamic", [])
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    released = re.findall(r"^## \[(\d+\.\d+\.\d+)\]", changelog, re.M)
    assert released and released[0] == phc.__version__, "the newest release in CHANGELOG.md is phc.__version__"
    assert not re.search(r"^version:", (ROOT / "CITATION.cff").read_text(encoding="utf-8"), re.M)


def test_generated_reference_lists_every_component_type():
    text = docgen.components_reference()
    for key in docgen.component_types():
        assert f"### `{key}`" in text
