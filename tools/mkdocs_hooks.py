"""MkDocs hooks of phc's documentation (``hooks:`` in ``mkdocs.yml``).

A page may hold a line ``<!-- generate: NAME -->``; it is replaced, at build time, by the
Markdown that :data:`docgen.GENERATORS` produces from the code (component types and
options from the pydantic models, the command line from argparse). Nothing generated is
stored in the repository, so the reference cannot go stale.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

TOOLS = Path(__file__).resolve().parent
ROOT = TOOLS.parent
for path in (str(ROOT), str(TOOLS)):
    if path not in sys.path:
        sys.path.insert(0, path)

import docgen  # noqa: E402

MARKER = re.compile(r"^<!-- generate: ([a-z-]+) -->$", re.MULTILINE)


def on_page_markdown(markdown: str, page, config, files) -> str:
    def replace(match: re.Match) -> str:
        name = match.group(1)
        if name not in docgen.GENERATORS:
            raise KeyError(f"{page.file.src_path}: unknown generator `{name}` (known: {sorted(docgen.GENERATORS)})")
        return docgen.GENERATORS[name]()

    return MARKER.sub(replace, markdown)


OPTIONAL_PAGES = {
    # page (relative to docs/) -> (nav section, title, the page it follows); added once it exists
    "backends.md": ("How-to guides", "Choose a backend (NumPy or compiled)", "how-to/solvers.md"),
    "parameter-studies.md": ("How-to guides", "Run parameter studies", "how-to/accuracy.md"),
    "constraints.md": ("How-to guides", "Constraints", "how-to/initial-values.md"),
    "events.md": ("How-to guides", "Events and switching", "constraints.md"),
}
"""Pages that other work adds to docs/: placed in the navigation once they exist, so the
site builds (with `--strict`) before and after they land."""


def on_config(config):
    docs = Path(config["docs_dir"])
    nav = config["nav"]
    listed = set(_nav_pages(nav))
    for page, (section, title, after) in OPTIONAL_PAGES.items():
        if not (docs / page).is_file() or page in listed:
            continue
        entries = next((item[section] for item in nav if isinstance(item, dict) and section in item), None)
        if entries is None:
            entries = []
            nav.append({section: entries})
        pages = [next(iter(e.values())) if isinstance(e, dict) else e for e in entries]
        position = pages.index(after) + 1 if after in pages else len(entries)
        entries.insert(position, {title: page})
        listed.add(page)
    extra = sorted(str(p.relative_to(docs)) for p in docs.rglob("*.md") if str(p.relative_to(docs)) not in listed)
    if extra:
        nav.append({"More": extra})
    return config


def _nav_pages(nav):
    for item in nav:
        if isinstance(item, str):
            yield item
        elif isinstance(item, dict):
            for value in item.values():
                if isinstance(value, str):
                    yield value
                else:
                    yield from _nav_pages(value)
