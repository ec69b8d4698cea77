"""Where the native IDA driver finds SUNDIALS (:func:`phc.codegen.c_ida.find_sundials`): pkg-config's
answer is kept in phc's signed cache (:func:`phc.codegen.c_ida.pkg_config_prefix`), and a SUNDIALS
installed, changed or removed where pkg-config looks is found anew.

A stand-in ``pkg-config`` (a shell script first on ``$PATH``) answers from a ``sundials_ida.pc`` in a
directory of the test's and writes down each time it is asked; a stand-in SUNDIALS is the headers and
libraries' file names (empty files) under a prefix of the test's.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from phc.codegen import c_ida

pytestmark = pytest.mark.skipif(os.name != "posix", reason="the stand-in pkg-config is a shell script")

SCRIPT = """#!/bin/sh
echo "$*" >> "{log}"
case "$*" in
  "--variable=pc_path pkg-config") echo "{pc_dir}" ;;
  "--variable=prefix sundials_ida")
    [ -f "{pc_dir}/sundials_ida.pc" ] || exit 1
    sed -n 's/^prefix=//p' "{pc_dir}/sundials_ida.pc" ;;
  *) exit 1 ;;
esac
"""


@pytest.fixture
def world(tmp_path, monkeypatch):
    """(the .pc directory, the log of pkg-config's calls) with phc's cache in `tmp_path`."""
    bin_dir, pc_dir, log = tmp_path / "bin", tmp_path / "pc", tmp_path / "calls.log"
    bin_dir.mkdir()
    pc_dir.mkdir()
    script = bin_dir / "pkg-config"
    script.write_text(SCRIPT.format(log=log, pc_dir=pc_dir))
    script.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}")
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_COMPILED_CACHE", "1")
    for var in ("SUNDIALS_DIR", "CONDA_PREFIX", "PKG_CONFIG_PATH", "PKG_CONFIG_LIBDIR"):
        monkeypatch.delenv(var, raising=False)
    return pc_dir, log


def _calls(log: Path) -> int:
    return len(log.read_text().splitlines()) if log.exists() else 0


def _install(prefix: Path) -> Path:
    """A stand-in SUNDIALS under `prefix`: ida.h and the libraries the driver links (empty files)."""
    (prefix / "include" / "ida").mkdir(parents=True)
    (prefix / "include" / "ida" / "ida.h").write_text("")
    (prefix / "lib").mkdir()
    suffix = ".dylib" if os.uname().sysname == "Darwin" else ".so"
    for name in c_ida.LIBRARIES:
        (prefix / "lib" / f"lib{name}{suffix}").write_text("")
    return prefix


def _write_pc(pc_dir: Path, prefix: Path) -> None:
    file = pc_dir / "sundials_ida.pc"
    before = os.stat(file).st_mtime_ns if file.exists() else 0
    file.write_text(f"prefix={prefix}\nName: IDA\n")
    # an edit within the file system's time resolution of the last one: its time moved on a second
    st = os.stat(file)
    os.utime(file, ns=(st.st_atime_ns, max(st.st_mtime_ns, before + 1_000_000_000)))


def test_the_answer_is_kept_and_a_changed_install_is_found_anew(world, tmp_path):
    pc_dir, log = world
    assert c_ida.pkg_config_prefix() is None  # pkg-config knows no SUNDIALS
    asked = _calls(log)
    assert asked >= 1
    assert c_ida.pkg_config_prefix() is None
    assert _calls(log) == asked  # kept: pkg-config is not run again

    first = _install(tmp_path / "sundials_a")
    _write_pc(pc_dir, first)  # installed where pkg-config looks
    assert c_ida.pkg_config_prefix() == first
    found, why = c_ida.find_sundials()
    assert why == "" and found[0] == first / "include" and found[1] == first / "lib"
    asked = _calls(log)
    assert c_ida.find_sundials()[0][1] == first / "lib"
    assert _calls(log) == asked

    second = _install(tmp_path / "sundials_b")
    _write_pc(pc_dir, second)  # the same file, now naming another prefix
    assert c_ida.pkg_config_prefix() == second
    assert c_ida.find_sundials()[0][1] == second / "lib"

    for library in (second / "lib").iterdir():  # the libraries removed, the .pc file left
        library.unlink()
    found = c_ida.find_sundials()[0]
    assert found is None or found[1] != second / "lib"

    (pc_dir / "sundials_ida.pc").unlink()  # uninstalled
    assert c_ida.pkg_config_prefix() is None


def test_a_damaged_record_is_asked_again(world, tmp_path):
    pc_dir, log = world
    first = _install(tmp_path / "sundials_a")
    _write_pc(pc_dir, first)
    assert c_ida.pkg_config_prefix() == first
    records = list((tmp_path / "cache" / "c").glob("phc_sundials_pc_*.json"))
    assert len(records) == 1
    data = records[0].read_bytes()
    records[0].write_bytes(data.replace(str(first).encode(), str(tmp_path / "elsewhere").encode()))
    asked = _calls(log)
    assert c_ida.pkg_config_prefix() == first  # the signature does not verify: pkg-config is asked
    assert _calls(log) > asked


def test_without_the_cache_pkg_config_is_asked_each_time(world, tmp_path, monkeypatch):
    pc_dir, log = world
    monkeypatch.setenv("PHC_COMPILED_CACHE", "0")
    first = _install(tmp_path / "sundials_a")
    _write_pc(pc_dir, first)
    assert c_ida.pkg_config_prefix() == first
    asked = _calls(log)
    assert c_ida.pkg_config_prefix() == first
    assert _calls(log) > asked
