"""The package stays readable (issue 31 item 8): no module of phc is over ~800 lines without
saying why in its docstring, and the README's module map ("How it works") names only paths
that exist and every subpackage of phc, so that a newcomer finds their room."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PHC = ROOT / "phc"
LONG = 800
"""Lines above which a module says in its docstring why it is that long."""
REASON = re.compile(r"over 800 lines because")


def test_every_long_module_says_why_in_its_docstring():
    silent = []
    for path in sorted(PHC.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        if text.count("\n") <= LONG:
            continue
        doc = ast.get_docstring(ast.parse(text)) or ""
        if not REASON.search(" ".join(doc.split())):
            silent.append(f"{path.relative_to(ROOT)} ({text.count(chr(10))} lines)")
    assert not silent, f"over {LONG} lines without a reason in the docstring ('... over 800 lines because ...'): {silent}"


def _module_map() -> tuple[str, list[str]]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## How it works", 1)[1].split("\n## ", 1)[0]
    assert "Module map, in `phc/`:" in section
    return section, re.findall(r"`([a-z_]+(?:\.py|/))`", section.split("Module map, in `phc/`:", 1)[1])


def test_the_readme_module_map_names_existing_paths_and_every_subpackage():
    _, named = _module_map()
    assert named
    missing = [name for name in named if not (PHC / name).exists()]
    assert not missing, f"the README's module map names paths phc/ does not have: {missing}"
    subpackages = {f"{p.parent.name}/" for p in PHC.glob("*/__init__.py")}
    left_out = sorted(subpackages - set(named))
    assert not left_out, f"the README's module map leaves out: {left_out}"


TOP_LEVEL = {"__init__", "__main__", "_entry", "pipeline", "errors", "diagnostics", "inert", "io", "names",
             "options", "progress"}
"""The modules at the top of phc/: the entry points, the pipeline and what every room shares
(docs/theory/pipeline.md, "Where the code lives"). A new module goes into its room."""


def test_the_top_level_holds_only_what_every_room_shares():
    top = sorted(p.stem for p in PHC.glob("*.py"))
    stray = sorted(set(top) - TOP_LEVEL)
    assert not stray, (f"modules at the top of phc/ that belong in a room (phc/frontend/, phc/ir/, phc/codegen/, "
                       f"phc/study/, ...; README's module map): {stray}")
    rooms = sorted(p.parent.name for p in PHC.glob("*/__init__.py"))
    silent = [room for room in rooms if not ast.get_docstring(ast.parse((PHC / room / "__init__.py").read_text()))]
    assert not silent, f"rooms whose __init__.py does not say what they hold: {silent}"
