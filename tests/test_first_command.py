"""The first command of the README, `phc simulate models/pendulum.yaml` after `pip install
.`, prints no warning (issue 36 item 4): pint, which checks the units every shipped model
declares, is a core dependency, so a plain install has it (before, it was an extra and the
first run warned PHC-W172)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from phc.cli import main

tomllib = pytest.importorskip("tomllib")  # Python 3.11+

REPO = Path(__file__).resolve().parents[1]


def _requirement_names(items) -> set[str]:
    return {re.match(r"[A-Za-z0-9_.-]+", item).group(0).lower() for item in items}


def test_pint_is_installed_with_phc():
    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert "pint" in _requirement_names(project["dependencies"])
    assert "units" in project["optional-dependencies"]  # `pip install ".[units]"` keeps working


def test_the_first_readme_command_prints_no_warning(capsys, monkeypatch):
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    command = re.search(r"python -m pip install \. && (phc simulate \S+)", readme).group(1)
    assert command == "phc simulate models/pendulum.yaml"
    monkeypatch.chdir(REPO)
    assert main(command.split()[1:]) == 0
    out = capsys.readouterr()
    assert "warning" not in (out.out + out.err).lower(), out.err
    assert "PHC-W" not in out.out + out.err
