"""The one runner of the system C compiler (:mod:`phc.codegen.cc`), used by the C back end and
the FMU export: a library it builds works, and every failure — a compile error, a compiler that
cannot be started or runs past its time, no compiler at all — is one line naming the compiler.

The compile-error cases need a C compiler (skipped without one); the others need none.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import stat
import time
import sys

from pathlib import Path

import pytest

from phc import __version__
from phc.codegen import c_backend
from phc.codegen.c_printer import ABI
from phc.codegen.cc import compile_library, first_error
from phc.errors import CodegenError

_OK, _WHY = c_backend.available()
needs_cc = pytest.mark.skipif(not _OK, reason=f"no C compiler: {_WHY}")

BROKEN = "double twice(double x)\n{\n    return 2.0 * x +;\n}\n"
"""A syntax error on line 3 (every C compiler reports it as ``bad.c:3:...: error: ...``)."""


@needs_cc
def test_a_library_it_builds_is_loadable_and_computes(tmp_path):
    argv, _ = c_backend.find_compiler()
    (tmp_path / "ok.c").write_text("double twice(double x) { return 2.0 * x; }\n")
    out = compile_library(argv, c_backend.FLAGS, ["ok.c"], tmp_path / "ok.so", cwd=tmp_path, timeout=300)
    lib = ctypes.CDLL(str(out))
    lib.twice.argtypes, lib.twice.restype = [ctypes.c_double], ctypes.c_double
    assert lib.twice(1.25) == 2.5


@needs_cc
def test_a_compile_error_is_one_line_with_the_compilers_first_error(tmp_path):
    argv, _ = c_backend.find_compiler()
    (tmp_path / "bad.c").write_text(BROKEN)
    with pytest.raises(CodegenError) as err:
        compile_library(argv, c_backend.FLAGS, ["bad.c"], tmp_path / "bad.so", cwd=tmp_path, timeout=300,
                        what="the test's file", hint="a test")
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"the C compiler ({argv[0]}) failed on the test's file (exit ")
    assert "; a test): bad.c:3:" in message and "error" in message.split("bad.c:3:", 1)[1]
    assert not (tmp_path / "bad.so").exists()


@needs_cc
def test_the_c_backend_reports_a_compile_error_through_the_runner():
    argv, _ = c_backend.find_compiler()
    with pytest.raises(CodegenError) as err:
        c_backend._compile(BROKEN, argv, "0" * 24, None)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"the C compiler ({argv[0]}) failed on the generated code (exit ")
    assert f"phc_c_{'0' * 24}.c:3:" in message


def test_a_compiler_that_cannot_be_started_is_one_line(tmp_path):
    missing = str(tmp_path / "no-such-cc")
    with pytest.raises(CodegenError) as err:
        compile_library([missing], ("-O2",), ["x.c"], tmp_path / "x.so", cwd=tmp_path, timeout=60)
    message = str(err.value)
    assert "\n" not in message
    assert message == f"the C compiler ({missing}) could not be run: {os.strerror(2)}"


def _running(pid: int) -> bool:
    """Whether process `pid` exists and is not a zombie waiting to be collected."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def test_a_compiler_past_its_time_is_abandoned_with_one_line(tmp_path):
    slow = tmp_path / "slow-cc"
    # the shell's child holds the output pipes as cc1 does under the compiler driver: killing
    # only the driver would leave it running and the call waiting for its 60 s
    slow.write_text(f"#!/bin/sh\nsleep 60 &\necho $! > {tmp_path / 'child.pid'}\nwait\n")
    slow.chmod(slow.stat().st_mode | stat.S_IXUSR)
    with pytest.raises(CodegenError) as err:
        compile_library([str(slow)], (), ["x.c"], tmp_path / "x.so", cwd=tmp_path, timeout=1, what="x.c")
    assert str(err.value) == f"the C compiler ({slow}) took more than 1 s on x.c"
    child = int((tmp_path / "child.pid").read_text())
    for _ in range(100):  # SIGKILL is delivered at once; the re-parented child is collected soon after
        if not _running(child):
            break
        time.sleep(0.05)
    assert not _running(child), "the compiler's child process was left running"


def test_without_a_compiler_discovery_says_so_in_one_line(tmp_path, monkeypatch):
    missing = str(tmp_path / "no-such-cc")
    monkeypatch.setenv("CC", missing)
    argv, why = c_backend.find_compiler()
    assert argv is None and "\n" not in why
    assert why.startswith(f"no C compiler found ($CC is `{missing}`, which does not run)")


def test_the_first_error_line_is_preferred_to_warnings():
    text = "\n  \nx.c:1:1: warning: something\nx.c:2:5: error: expected ';'\nx.c:9:1: error: later\n"
    assert first_error(text) == "x.c:2:5: error: expected ';'"
    assert first_error("ld: cannot find -lfoo\n") == "ld: cannot find -lfoo"
    assert first_error("") == ""
    assert len(first_error("error " + "x" * 1000)) == 300


def test_the_library_cache_key_is_unchanged_by_the_runner():
    """The digest of a library (its name in the cache) is what it was before the runner existed:
    the same inputs give the same SHA-256 prefix, so cached libraries stay valid."""
    argv, identity, text = ["/usr/bin/cc"], "cc (GCC) 12.2.0", "int x;\n"
    material = "\0".join((text, "/usr/bin/cc", identity, " ".join((*c_backend.FLAGS, "-lm")),
                          __version__, str(ABI), platform.machine(), sys.platform))
    assert c_backend.library_digest(text, argv, identity) == hashlib.sha256(material.encode()).hexdigest()[:24]
