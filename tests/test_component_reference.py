"""The generated component reference (docs/reference/components.md, built by
``tools/docgen.py`` from the pydantic models; issue 36 item 5).

Every key of every component type has a description; the Markdown has no reST literal
left (``x``) and no unbalanced code span, so every inline code renders as code; every
``ratio`` says which way it goes; the key column does not break inside a key.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "tools") not in sys.path:
    sys.path.insert(0, str(ROOT / "tools"))

import docgen  # noqa: E402

HEADER = "| key | type | default | description |"


def _prose(text: str) -> list[str]:
    """The lines of `text` outside fenced code blocks."""
    out, fenced = [], False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if not fenced:
            out.append(line)
    assert not fenced, "a code block is not closed"
    return out


def _cells(row: str) -> list[str]:
    """The cells of a table row, split at pipes that are neither escaped nor in code."""
    cells, cell, code = [], "", False
    i = 0
    while i < len(row):
        ch = row[i]
        if ch == "\\" and i + 1 < len(row):
            cell += row[i:i + 2]
            i += 2
            continue
        if ch == "`":
            code = not code
        if ch == "|" and not code:
            cells.append(cell)
            cell = ""
        else:
            cell += ch
        i += 1
    cells.append(cell)
    return [c.strip() for c in cells[1:-1]]


def _key_rows(text: str):
    """(section heading, key, description) of every row of every key table."""
    heading, in_table = None, False
    for line in text.splitlines():
        if line.startswith("#"):
            heading, in_table = line.strip("# "), False
        elif line == HEADER:
            in_table = True
        elif in_table and line.startswith("|---"):
            continue
        elif in_table and line.startswith("|"):
            cells = _cells(line)
            yield heading, cells[0], cells[-1]
        else:
            in_table = False


def test_every_key_of_every_component_has_a_description():
    rows = list(_key_rows(docgen.components_reference()))
    assert len(rows) > 150  # every component type's table was found
    empty = [f"{heading}: {key}" for heading, key, description in rows if not description]
    assert not empty, f"keys without a description: {empty}"


def test_a_key_without_a_description_is_found():
    """The check above can fail: an empty cell is seen."""
    text = docgen.components_reference()
    broken = text.replace("| Free text shown in reports. |", "|  |", 1)
    assert [key for _, key, d in _key_rows(broken) if not d] == ["`description`"]


def _code_problems(text: str) -> list[str]:
    """Lines whose inline code does not render: a reST literal ``x`` (shown as a literal
    "``x"), or an odd number of backticks in a paragraph or table row (a code span that
    never closes and swallows the text after it)."""
    problems = []
    paragraph: list[str] = []

    def close() -> None:
        joined = "\n".join(paragraph)
        if joined.replace("\\`", "").count("`") % 2:
            problems.append(f"unbalanced code span: {joined[:120]}")
        paragraph.clear()

    for line in _prose(text):
        if "``" in line:
            problems.append(f"reST literal or broken code span: {line[:120]}")
        if line.startswith("|"):
            close()
            paragraph.append(line)
            close()
        elif not line.strip():
            close()
        else:
            paragraph.append(line)
    close()
    return problems


def test_inline_code_of_the_reference_renders():
    text = docgen.components_reference()
    assert _code_problems(text) == []
    # the two descriptions that rendered a literal "``text" and a broken run
    for key in ("linear-phs", "pde1d"):
        section = text.split(f"{{#{key}}}", 1)[1].split("\n### ", 1)[0]
        assert "```text\n" in section and "with `P_k = (−1)^{k+1} P_kᵀ`" in text


def test_the_lint_sees_a_rest_literal_and_an_open_code_span():
    assert _code_problems("with ``P_N`` invertible") != []
    assert _code_problems("a `ratio that never closes\n\nnext") != []
    assert _code_problems("```text\n``inside a block`` is code\n```\nfine `x`") == []


def test_every_ratio_says_which_way_it_goes():
    rows = {(heading, key): d for heading, key, d in _key_rows(docgen.components_reference())}
    ratios = {heading: d for (heading, key), d in rows.items() if key == "`ratio`"}
    assert set(ratios) >= {"`transformer` {#transformer}", "`gyrator` {#gyrator}"}
    assert "`f_b = N f_a`" in ratios["`transformer` {#transformer}"]
    assert "`e_b = G f_a`" in ratios["`gyrator` {#gyrator}"]
    for description in ratios.values():
        assert "from port `a` to port `b`" in description and "signs" in description


def test_the_key_column_does_not_break_inside_a_key():
    """Material lets inline code break anywhere; phc's stylesheet keeps a table's first
    column whole ("descriptio / n" before)."""
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    sheets = config.get("extra_css", [])
    css = "".join((ROOT / "docs" / s).read_text(encoding="utf-8") for s in sheets)
    rule = re.search(r"td:first-child code\s*\{([^}]*)\}", css)
    assert rule and "white-space: nowrap" in rule.group(1) and "word-break: normal" in rule.group(1)
