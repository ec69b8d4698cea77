"""Every input the fuzzer (``test_fuzz_loaders.py``) ever broke, kept as a regression case.

``found/NAME.yaml`` is a model or scene file as the fuzzer wrote it (its first comment says
what broke and how it was fixed); a folder ``found/NAME/`` holds a scene (``scene.yaml``)
with the model it uses. Each must pass the fuzzer's oracle (:func:`fuzzlib.check_input`:
success or located one-line diagnostics, no other exception, within the time limit), also
when compiled. ``NAME.expected``, when present, holds the exact stderr lines of
``phc validate NAME.yaml`` run inside ``found/``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import fuzzlib
from phc.cli import main

FOUND = Path(__file__).parent / "found"
ENTRIES = sorted(FOUND.glob("*.yaml")) + sorted(p / "scene.yaml" for p in FOUND.iterdir() if (p / "scene.yaml").is_file())


def _id(path: Path) -> str:
    return path.stem if path.parent == FOUND else path.parent.name


@pytest.mark.parametrize("entry", ENTRIES, ids=[_id(p) for p in ENTRIES])
def test_found_input(entry, capsys, monkeypatch):
    monkeypatch.chdir(entry.parent)
    fuzzlib.check_input(Path(entry.name), {p.name for p in entry.parent.iterdir()}, compile=True)
    expected = entry.with_suffix(".expected") if entry.parent == FOUND else entry.parent / "expected"
    if expected.is_file():
        code = main(["validate", entry.name])
        err = capsys.readouterr().err
        assert code == 1
        assert err.splitlines() == expected.read_text(encoding="utf-8").splitlines()


def test_found_corpus_is_not_empty():
    assert len(ENTRIES) >= 2
    for entry in ENTRIES:
        assert entry.read_text(encoding="utf-8").startswith("# Found by the fuzzer"), \
            f"{entry}: the first comment says what the fuzzer found"
