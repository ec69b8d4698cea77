"""Run one benchmark and record its tables with the date, the machine and the command.

    python benchmarks/record.py NAME [--file PATH] -- COMMAND [ARG ...]

runs COMMAND from the repository root (with one BLAS thread unless the environment says
otherwise, as the `phc` command does), and writes ``benchmarks/results/NAME.md``: a header
saying when, where and how the figures were measured, followed by what COMMAND printed
on its standard output (or, with ``--file``, the Markdown file COMMAND wrote). The
documentation's Benchmarks page includes these files as they are: no figure there is
typed by hand. A failing COMMAND writes nothing and exits with its status.

Example::

    python benchmarks/record.py linear_scale -- python benchmarks/bench_linear_scale.py
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import platform
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return " ".join(line.split(":", 1)[1].split())
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _versions() -> str:
    parts = [f"Python {platform.python_version()}"]
    for name in ("numpy", "scipy", "sympy"):
        try:
            module = __import__(name)
            parts.append(f"{name} {module.__version__}")
        except ImportError:
            pass
    sys.path.insert(0, str(ROOT))
    try:
        import phc

        parts.append(f"phc {phc.__version__}")
    except ImportError:
        pass
    return ", ".join(parts)


def _recorded_files() -> set[str]:
    """The files benchmarks write (`results` and `outputs` in benchmarks/depends.toml): a
    change to one is an earlier benchmark's result, not a change to the code measured."""
    import tomllib

    try:
        table = tomllib.loads((ROOT / "benchmarks" / "depends.toml").read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return set()
    return {path for entry in table.get("benchmarks", {}).values()
            for path in [*entry.get("results", ()), *entry.get("outputs", ())]}


def _git_commit() -> str:
    """The commit checked out, with "(with uncommitted changes)" when a tracked file other
    than a benchmark's result or output differs from it."""
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, timeout=10)
        status = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
                                capture_output=True, text=True, timeout=30)
        recorded = _recorded_files()
        changed = [line[3:].split(" -> ")[-1].strip('"') for line in status.stdout.splitlines() if line.strip()]
        dirty = [path for path in changed if path not in recorded]
        commit = out.stdout.strip()
        return f"{commit} (with uncommitted changes)" if commit and dirty else commit
    except (OSError, subprocess.SubprocessError):
        return ""


def header(command: list[str], started: _dt.datetime, wall_s: float, load: str, commit: str) -> str:
    """The lines above a recorded table: date, machine, software, the commit (and whether the
    tree had uncommitted changes) when the command started, command, wall time."""
    cores = os.cpu_count() or 0
    lines = [
        f"<!-- Written by benchmarks/record.py; rerun the command below to update. Do not edit by hand. -->",
        "",
        f"*Measured {started:%Y-%m-%d %H:%M} UTC on {platform.machine()}, {cores} logical CPUs ({_cpu_model()}), "
        f"{platform.system()} {platform.release()}; load average {load} at the start; "
        f"{_versions()}{'; commit ' + commit if commit else ''}.*",
        "",
        f"*Command: `{shlex.join(command)}` ({wall_s:.0f} s wall).*",
        "",
    ]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("name", help="results/NAME.md is written")
    parser.add_argument("--file", help="record this Markdown file (written by COMMAND) instead of its stdout")
    parser.usage = "%(prog)s NAME [--file PATH] -- COMMAND [ARG ...]"
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" not in argv or argv.index("--") == len(argv) - 1:
        parser.error("give the command after --")
    split = argv.index("--")
    args = parser.parse_args(argv[:split])
    command = argv[split + 1:]
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    started = _dt.datetime.now(_dt.timezone.utc)
    commit = _git_commit()  # before the command: the files it writes itself are not uncommitted changes
    try:
        load = "{:.1f}, {:.1f}, {:.1f}".format(*os.getloadavg())
    except OSError:
        load = "unknown"
    t0 = time.perf_counter()
    proc = subprocess.run(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.stdout.write(proc.stdout)
        print(f"record.py: `{shlex.join(command)}` failed (exit {proc.returncode}); nothing written",
              file=sys.stderr)
        return proc.returncode
    if args.file:
        body = Path(ROOT / args.file).read_text(encoding="utf-8")
    else:  # the scripts' own "wrote FILE" notes are not results
        body = "\n".join(line for line in proc.stdout.splitlines() if not line.startswith("wrote "))
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / f"{args.name}.md"
    out.write_text(header(command, started, wall, load, commit) + body.rstrip() + "\n", encoding="utf-8")
    print(f"wrote {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
