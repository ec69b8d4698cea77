"""Write the current benchmark figures into benchmarks/README.md, from the result files.

    python benchmarks/readme_results.py

GitHub shows benchmarks/README.md without the snippet includes the documentation site
uses (docs/benchmarks.md), so the README carries copies, between markers:

* ``<!-- results-index begin -->`` ... ``<!-- results-index end -->``: one row per result
  file of benchmarks/depends.toml — when, on which machine and at which commit it was
  measured, read from the header benchmarks/record.py wrote;
* ``<!-- results:NAME begin -->`` ... ``<!-- results:NAME end -->``: the whole of
  ``benchmarks/results/NAME.md`` (its headings three levels down, below the README's
  subsections; its relative links as seen from the README).

Run it after benchmarks/record.py; tests/test_benchmark_freshness.py fails while the
README differs from what this writes. Nothing between the markers is typed by hand.
"""

from __future__ import annotations

import os
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "benchmarks" / "README.md"
MANIFEST = ROOT / "benchmarks" / "depends.toml"
BLOCK = re.compile(r"(<!-- results:(?P<name>\w+) begin[^>]*-->\n)(?P<body>.*?)(<!-- results:(?P=name) end -->)", re.S)
INDEX = re.compile(r"(<!-- results-index begin[^>]*-->\n)(?P<body>.*?)(<!-- results-index end -->)", re.S)
MEASURED = re.compile(r"^\*Measured (?P<when>.+? UTC) on (?P<machine>[^;]+); load average (?P<load>[^;]+?) at the start;"
                      r"(?P<software>.*?)(?:; commit (?P<commit>[0-9a-f]+(?: \(with uncommitted changes\))?))?\.\*$",
                      re.M)
COMMAND = re.compile(r"^\*Command: `(?P<command>.+)` \((?P<wall>\d+) s wall\)\.\*$", re.M)


def _results() -> list[tuple[str, str]]:
    manifest = tomllib.loads(MANIFEST.read_text(encoding="utf-8"))
    return [(name, path) for name, spec in manifest["benchmarks"].items() for path in spec["results"]]


LINK = re.compile(r"(!?\[[^\]]*\]\()([^)\s]+)(\))")


def _outputs() -> dict[str, Path]:
    """The files benchmarks write besides their results, by name."""
    manifest = tomllib.loads(MANIFEST.read_text(encoding="utf-8"))
    return {Path(f).name: ROOT / f for spec in manifest["benchmarks"].values() for f in spec.get("outputs", [])}


def _rebase(target: str, source: Path, outputs: dict[str, Path]) -> str:
    """A relative link of a result file, as seen from benchmarks/README.md. A result
    recorded from a script's own file (``--file``) may link a picture beside that file:
    found among the benchmarks' outputs by its name."""
    if re.match(r"^[a-z]+:|^#|^/", target):
        return target
    where = (source.parent / target).resolve()
    if not where.exists() and Path(target).name in outputs:
        where = outputs[Path(target).name]
    return Path(os.path.relpath(where, README.parent.resolve())).as_posix()


def _body(path: Path) -> str:
    """A result file for the README: without record.py's comment line, headings three
    levels down (a result's `#` becomes `####`, below a README subsection), relative
    links as seen from the README."""
    outputs = _outputs()
    lines, fence = [], False
    for line in path.read_text(encoding="utf-8").rstrip("\n").split("\n"):
        if line.startswith("<!-- Written by benchmarks/record.py"):
            continue
        if line.startswith(("```", "~~~")):
            fence = not fence
        heading = re.match(r"(#{1,6}) ", line) if not fence else None
        if heading:
            line = "#" * min(6, len(heading.group(1)) + 3) + line[len(heading.group(1)):]
        if not fence:
            line = LINK.sub(lambda m: m.group(1) + _rebase(m.group(2), path, outputs) + m.group(3), line)
        lines.append(line)
    while lines and not lines[0].strip():
        lines.pop(0)
    return "\n".join(lines) + "\n"


def index() -> str:
    rows = ["| benchmark | result file | measured | machine | commit | command |", "|---|---|---|---|---|---|"]
    for name, path in _results():
        link = f"[{Path(path).name}]({Path(path).relative_to('benchmarks').as_posix()})"
        if not (ROOT / path).is_file():
            rows.append(f"| {name} | {link} | not measured yet | | | |")
            continue
        text = (ROOT / path).read_text(encoding="utf-8")
        m, c = MEASURED.search(text), COMMAND.search(text)
        if not m:
            rows.append(f"| {name} | {link} | not recorded by record.py | | | |")
            continue
        commit = m.group("commit") or "not recorded"
        rows.append(f"| {name} | {link} | {m.group('when')} | {m.group('machine')} | {commit} | "
                    f"`{c.group('command') if c else '?'}` |")
    return "\n".join(rows) + "\n"


def refresh_readme(text: str) -> str:
    """The README text with every generated block rewritten from the result files."""
    text = INDEX.sub(lambda m: m.group(1) + index() + m.group(3), text)

    def block(m: re.Match) -> str:
        path = ROOT / "benchmarks" / "results" / f"{m.group('name')}.md"
        link = f"**Current figures** — [`results/{path.name}`](results/{path.name}):\n\n"
        body = _body(path) if path.is_file() else "not measured yet\n"
        return m.group(1) + link + body + m.group(4)

    return BLOCK.sub(block, text)


def main() -> int:
    text = README.read_text(encoding="utf-8")
    new = refresh_readme(text)
    if new != text:
        README.write_text(new, encoding="utf-8")
        print(f"wrote {README.relative_to(ROOT)}")
    else:
        print(f"{README.relative_to(ROOT)} is up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
