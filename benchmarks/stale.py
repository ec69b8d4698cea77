"""Which benchmark results are stale, and rerun only those.

    python benchmarks/stale.py            # list them, with the command and last wall time
    python benchmarks/stale.py --run      # rerun them one after another, then readme_results.py

A result is stale by the rule tests/test_benchmark_freshness.py applies: the commit its
header names is older than the last commit touching anything in its ``depends``
(benchmarks/depends.toml). The list is in the manifest's order; ``--run`` stops at the
first command that fails (its result file is then left as it was). Run it on a clean
checkout on a quiet machine: benchmarks/record.py writes the commit into each header and
marks a run made with uncommitted changes.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = ROOT / "benchmarks" / "depends.toml"
COMMIT = re.compile(r"; commit ([0-9a-f]{7,40})( \(with uncommitted changes\))?\.")
WALL = re.compile(r"\((\d+) s wall\)")


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, timeout=60)


def _depends(manifest: dict, name: str) -> list[str]:
    out = []
    for entry in manifest["benchmarks"][name]["depends"]:
        out += manifest["groups"][entry[1:]] if entry.startswith("@") else [entry]
    return out


def why_stale(manifest: dict, name: str) -> str | None:
    """Why the benchmark `name` must be rerun, or None when its results are current."""
    spec = manifest["benchmarks"][name]
    for rel in spec["results"]:
        path = ROOT / rel
        if not path.is_file():
            return f"{rel} is missing"
        m = COMMIT.search(path.read_text(encoding="utf-8"))
        if not m:
            return f"{rel} names no commit"
        if m.group(2):
            return f"{rel} was measured with uncommitted changes"
        if not _git("rev-parse", "--verify", "--quiet", f"{m.group(1)}^{{commit}}").stdout.strip():
            return f"{rel} names commit {m.group(1)}, which is not in this history"
        last = _git("log", "-1", "--format=%H", "--", *_depends(manifest, name)).stdout.strip()
        if last and _git("merge-base", "--is-ancestor", last, m.group(1)).returncode != 0:
            changed = _git("diff", "--name-only", m.group(1), "HEAD", "--", *_depends(manifest, name)).stdout.split()
            return f"{rel} measured at {m.group(1)}; changed since: {', '.join(changed[:4])}" + (
                " ..." if len(changed) > 4 else "")
    return None


def last_wall(manifest: dict, name: str) -> int | None:
    """Wall seconds of the benchmark's last recorded run (from its result header)."""
    for rel in manifest["benchmarks"][name]["results"]:
        path = ROOT / rel
        if path.is_file():
            m = WALL.search(path.read_text(encoding="utf-8"))
            if m:
                return int(m.group(1))
    return None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="store_true", help="rerun the stale benchmarks, then readme_results.py")
    args = parser.parse_args(argv)
    if _git("rev-parse", "--is-shallow-repository").stdout.strip() != "false":
        print("stale.py needs a full git checkout (the result files' commits are compared with the history)",
              file=sys.stderr)
        return 2
    manifest = tomllib.loads(MANIFEST.read_text(encoding="utf-8"))
    stale = [(name, why) for name in manifest["benchmarks"]
             if manifest["benchmarks"][name]["results"] and (why := why_stale(manifest, name))]
    total = sum(last_wall(manifest, name) or 0 for name, _ in stale)
    for name, why in stale:
        wall = last_wall(manifest, name)
        print(f"{name}: {why} (last run {wall if wall is not None else '?'} s wall)\n  "
              f"{manifest['benchmarks'][name]['command']}")
    print(f"{len(stale)} stale benchmark(s), about {total / 60:.0f} min by their last runs" if stale
          else "every benchmark result is current")
    if not args.run or not stale:
        return 0
    if _git("status", "--porcelain", "--untracked-files=no").stdout.strip():
        print("uncommitted changes: commit first, so that the results name the commit they measure",
              file=sys.stderr)
        return 2
    for name, _ in stale:
        command = manifest["benchmarks"][name]["command"]
        print(f"[{time.strftime('%H:%M:%S')}] {name}: {command}", flush=True)
        if subprocess.run(command, shell=True, cwd=ROOT).returncode != 0:
            print(f"{name} failed; the benchmarks after it were not run", file=sys.stderr)
            return 1
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "readme_results.py")], cwd=ROOT, check=True)
    print(f"[{time.strftime('%H:%M:%S')}] done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
