"""The cache of generated modules (:mod:`phc.codegen.load`): what is executed is the text
phc printed, never the file on disk; the directory is private; the size is capped.

A cache directory may be shared or restored from an untrusted place (a CI cache restored
from pull-request builds). The attacks tried here: a planted file at the module's hash
path, a file swapped right after phc writes (and would check) it, and a planted
unchecked-hash ``.pyc`` (PEP 552) that an importer would prefer to the source.
"""

from __future__ import annotations

import importlib.util
import os
import py_compile
import stat
import sys
import warnings
from pathlib import Path

import pytest

from phc.cli import main
from phc.codegen import load

SOURCE = "VALUE = 42\n"


def _payload(canary: Path) -> str:
    return f"open({str(canary)!r}, 'w').close()\nVALUE = -1\n"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("PHC_CACHE_DIR", str(folder))
    monkeypatch.setattr(load, "_PRIVATE_FALLBACK", None)
    return folder


def _target(folder: Path, source: str = SOURCE) -> Path:
    return folder / f"phc_{load.source_hash(source)}.py"


def test_the_cache_directory_is_created_private(cache):
    load.load_generated(SOURCE)
    assert stat.S_IMODE(cache.stat().st_mode) == 0o700


def test_a_planted_file_at_the_hash_path_is_not_executed(cache, tmp_path):
    canary = tmp_path / "OWNED"
    cache.mkdir(mode=0o700)
    _target(cache).write_text(_payload(canary))
    module, path = load.load_generated(SOURCE)
    assert module.VALUE == 42 and not canary.exists()
    assert path.read_text() == SOURCE  # the readable copy is repaired too


def test_a_file_swapped_after_writing_is_not_executed(cache, tmp_path, monkeypatch):
    """The race of the old loader: compare or write the file, then import it by path."""
    canary = tmp_path / "OWNED"
    write = load.write_atomic

    def write_then_swap(path, data):
        write(path, data)
        path.write_text(_payload(canary))  # the attacker wins the race

    monkeypatch.setattr(load, "write_atomic", write_then_swap)
    module, _ = load.load_generated(SOURCE)
    assert module.VALUE == 42 and not canary.exists()
    module, _ = load.load_generated(SOURCE)  # second load: the file differs and is rewritten
    assert module.VALUE == 42 and not canary.exists()


def test_a_planted_unchecked_pyc_is_not_executed(cache, tmp_path):
    canary = tmp_path / "OWNED"
    cache.mkdir(mode=0o700)
    target = _target(cache)
    target.write_text(SOURCE)
    evil = tmp_path / "evil.py"
    evil.write_text(_payload(canary))
    pyc = Path(importlib.util.cache_from_source(str(target)))
    pyc.parent.mkdir()
    py_compile.compile(str(evil), cfile=str(pyc), invalidation_mode=py_compile.PycInvalidationMode.UNCHECKED_HASH)
    # Sanity: an ordinary import of the cached file would run the planted bytecode.
    spec = importlib.util.spec_from_file_location("probe", target)
    spec.loader.exec_module(importlib.util.module_from_spec(spec))
    assert canary.exists()
    canary.unlink()
    module, _ = load.load_generated(SOURCE)
    assert module.VALUE == 42 and not canary.exists()


def test_no_bytecode_is_written_for_generated_modules(cache):
    load.load_generated(SOURCE)
    assert not (cache / "__pycache__").exists()


def test_a_directory_others_can_write_is_refused(cache):
    cache.mkdir()
    cache.chmod(0o777)
    with pytest.warns(load.CacheWarning, match="writable by other users"):
        module, path = load.load_generated(SOURCE)
    assert module.VALUE == 42
    assert path.parent != cache and not _target(cache).exists()
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="needs root to chown")
def test_a_directory_another_user_owns_is_refused(cache):
    cache.mkdir(mode=0o700)
    os.chown(cache, 65534, 65534)
    with pytest.warns(load.CacheWarning, match="owned by another user"):
        _, path = load.load_generated(SOURCE)
    assert path.parent != cache


def test_a_symlinked_cache_directory_is_refused(cache, tmp_path):
    real = tmp_path / "elsewhere"
    real.mkdir(mode=0o700)
    cache.symlink_to(real)
    with pytest.warns(load.CacheWarning, match="symbolic link"):
        _, path = load.load_generated(SOURCE)
    assert path.parent != cache and not list(real.iterdir())


def test_least_recently_used_modules_are_evicted_above_the_cap(cache, monkeypatch):
    sources = [f"VALUE = {k}\n" + "# padding\n" * 2000 for k in range(5)]  # ~20 kB each
    for k, source in enumerate(sources):
        load.load_generated(source)
        os.utime(_target(cache, source), (1000 + k, 1000 + k))
    load.load_generated(sources[0])  # used again: now the most recent
    monkeypatch.setenv("PHC_CACHE_MAX_MB", str(3 * len(sources[0]) / 2**20))
    load.enforce_cap()
    kept = {s for s in sources if _target(cache, s).exists()}
    assert kept == {sources[0], sources[3], sources[4]}


def test_cache_info_and_clean(cache, capsys):
    load.load_generated(SOURCE)
    assert main(["cache", "info"]) == 0
    assert f"{cache}: 1 files" in capsys.readouterr().out
    assert main(["cache", "clean"]) == 0
    assert "removed 1 files" in capsys.readouterr().out
    assert not _target(cache).exists()


def test_the_parents_checked_are_pathlibs(tmp_path):
    """The directories above a cache directory that _unsafe_parent checks, as strings: those of
    ``Path.parents`` (the root has none; repeated and trailing separators are normalized away first)."""
    for path in ("/", "/a", "/a//b/", str(tmp_path / "x" / "y"), os.path.realpath(tmp_path)):
        path = os.path.abspath(path)
        assert load._parents(path) == [str(parent) for parent in Path(path).parents]
