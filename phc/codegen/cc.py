"""Running the system C compiler: the one place phc starts it to build a shared library.

The compiler is the one :func:`find_compiler` finds (``$CC``, else ``cc``, ``gcc`` or
``clang``); this module imports no sympy, so a cached front end can ask for it. Its callers: the C back end's model libraries and the C step
loop's library (:mod:`phc.codegen.c_backend`) and the FMU's binary (:mod:`phc.export.fmu`).

The command is ``argv flags... -o output sources... libs...``, run in a working directory,
without input, with its output captured and a time limit. Every failure becomes one line in a
:class:`~phc.errors.CodegenError` naming the compiler: it could not be started, it ran past its
time, or it exited non-zero (with the exit status and the first line it printed that says
``error``, else its first line).
"""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
from pathlib import Path
from typing import Iterable, Optional, Sequence

from phc.errors import CodegenError

__all__ = ["available", "compile_library", "find_compiler", "first_error"]

_COMPILERS: dict = {}
"""($CC, $PATH) -> (argv, identity) of the compiler found, or (None, why none)."""


def find_compiler() -> tuple[Optional[list[str]], str]:
    """(the compiler's argv, its identity: the first line of ``--version``) or (None, why
    there is none). ``$CC`` when set (split like a shell word list), else the first of
    ``cc``, ``gcc``, ``clang`` on the PATH that answers ``--version``."""
    env = os.environ.get("CC", "").strip()
    key = (env, os.environ.get("PATH", ""))
    found = _COMPILERS.get(key)
    if found is None:
        found = _COMPILERS[key] = _find(env)
    return found


def _find(env: str) -> tuple[Optional[list[str]], str]:
    try:
        candidates = [shlex.split(env)] if env else [["cc"], ["gcc"], ["clang"]]
    except ValueError:
        candidates = []
    for argv in candidates:
        exe = shutil.which(argv[0]) if argv else None
        if exe is None:
            continue
        try:
            done = subprocess.run([exe, *argv[1:], "--version"], capture_output=True, text=True, timeout=60,
                                  stdin=subprocess.DEVNULL)
        except (OSError, subprocess.SubprocessError):
            continue
        if done.returncode == 0:
            return [exe, *argv[1:]], (done.stdout.strip().splitlines() or [exe])[0].strip()
    where = f"$CC is `{env}`, which does not run" if env else "no `cc`, `gcc` or `clang` on the PATH"
    return None, (f"no C compiler found ({where}); install one (e.g. `apt install gcc`) or set $CC, "
                  "or run with --backend numpy")


def available() -> tuple[bool, str]:
    """(True, the compiler's identity) when a C compiler was found, else (False, why not)."""
    argv, text = find_compiler()
    return argv is not None, text



def compile_library(argv: Sequence[str], flags: Iterable[str], sources: Iterable, output, *, cwd, timeout: float,
                    libs: Iterable[str] = ("-lm",), what: str = "the generated code", hint: str = "") -> Path:
    """Run ``argv flags... -o output sources... libs...`` in `cwd` and return `output` as a Path.

    Parameters
    ----------
    argv : sequence of str
        The compiler's command (:func:`find_compiler`).
    flags, sources, libs
        Put on the command line in this order around ``-o output`` (sources as given: relative
        to `cwd` or absolute).
    timeout : float
        Seconds the compiler may take before it is abandoned.
    what : str
        What is compiled, for the message (``"the generated code"``).
    hint : str
        Said after the exit status when the compiler fails (``"a phc bug: please report it"``).

    Raises
    ------
    CodegenError
        One line: the compiler could not be run, took more than `timeout` seconds, or failed
        (its exit status and first error line).
    """
    name = argv[0] if argv else "?"
    command = [*argv, *flags, "-o", str(output), *map(str, sources), *libs]
    try:
        # its own process group: at the time limit the driver and what it started (cc1, as, ld),
        # which hold the output pipes open, are stopped together
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                                text=True, errors="replace", cwd=cwd, start_new_session=True)
    except (OSError, subprocess.SubprocessError) as err:
        why = getattr(err, "strerror", None) or str(err)
        raise CodegenError(f"the C compiler ({name}) could not be run: {_line(why)}") from None
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        _stop_group(proc)
        raise CodegenError(f"the C compiler ({name}) took more than {timeout:.0f} s on {what}") from None
    except BaseException:  # Ctrl-C: no compiler left running behind phc
        _stop_group(proc)
        raise
    if proc.returncode != 0:
        status = f"exit {proc.returncode}" + (f"; {hint}" if hint else "")
        raise CodegenError(f"the C compiler ({name}) failed on {what} ({status}): {first_error(stderr or stdout)}")
    return Path(output)


def _stop_group(proc: subprocess.Popen) -> None:
    """Kill `proc`'s process group and collect it."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except OSError:  # already gone
        pass
    proc.communicate()


def first_error(text: str) -> str:
    """The first non-blank line of a compiler's output that says ``error`` (else its first
    non-blank line), stripped and cut to 300 characters."""
    lines = [line for line in (text or "").splitlines() if line.strip()]
    first = next((line for line in lines if "error" in line), lines[0] if lines else "")
    return first.strip()[:300]


def _line(text: str) -> str:
    return " ".join(str(text).split())[:300]
