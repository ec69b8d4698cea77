"""Start-up of the `phc` command (issue 16 items 4 and 5): wall and CPU time of fresh processes.

    python benchmarks/record.py startup -- python benchmarks/bench_startup.py [--repeat N]

writes ``benchmarks/results/startup.md``. Each command runs `--repeat` times (default 5)
after one warm-up run, as a child process from this script (as from the shell); the table
gives the best and the median wall time and the CPU time (user + system) of the best
run. On a shared machine the wall clock includes waiting for a core: the CPU column is
the figure to compare between runs.

Measured:

* `phc --version`, `phc --help`;
* `phc validate models/pendulum.yaml` with its result cached (a second run of the
  unchanged file) and without (``PHC_FRONT_END_CACHE=0``);
* `phc simulate models/pendulum.yaml` with the cached front end (:mod:`phc.codegen.fastpath`, a
  second run of the unchanged model) and with it off (``PHC_FRONT_END_CACHE=0``: reading,
  elaboration, symbolic passes and certificate every time; the generated module and
  compiled code still come from their caches);
* the same with ``--t-end 0.01``: start-up and set-up without the 20 s of simulated time
  (35 000 IDA steps at rtol 1e-12);
* the floor of the interpreter: ``python -c pass``, and the imports any IDA run needs
  (numpy, scipy.sparse, SUNDIALS' Python binding), as scikit-SUNDAE imports itself (with
  scipy.optimize) and as phc imports it (without);
* the libraries every run of a model calls, numpy and scipy's sparse matrices, dense LAPACK
  and graph matching (consistent initialization, the singularity monitor), with one BLAS
  thread as the command runs: the last line gives the warm ``--t-end 0.01`` run's CPU time
  above it, the part of the run that is phc's own (reading the cached front end, loading the
  compiled model, initialization, 0.01 s of integration, writing the output).

The caches live in a temporary directory of this run (``PHC_CACHE_DIR``, ``PHC_STATE_DIR``).
Python's bytecode cache is on for the children (``PYTHONDONTWRITEBYTECODE`` removed from
their environment), as in a user's installation; the warm-up run writes it.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from phc._entry import THREAD_VARIABLES

ROOT = Path(__file__).resolve().parents[1]
PENDULUM = "models/pendulum.yaml"


def run(cmd: list[str], env: dict, repeat: int) -> tuple[float, float, float]:
    """(best wall, median wall, CPU of the best run) of `cmd`, after one warm-up run."""
    subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, check=True)
    walls = []
    best = None
    for _ in range(repeat):
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu0 = usage.ru_utime + usage.ru_stime
        t = time.perf_counter()
        subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, check=True)
        wall = time.perf_counter() - t
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = usage.ru_utime + usage.ru_stime - cpu0
        walls.append(wall)
        if best is None or wall < best[0]:
            best = (wall, cpu)
    return best[0], statistics.median(walls), best[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    py = sys.executable
    phc = [py, "-m", "phc"]
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, PHC_CACHE_DIR=str(Path(tmp) / "cache"), PHC_STATE_DIR=str(Path(tmp) / "state"))
        # as installed for a user: Python's bytecode cache on (pip writes it at install time,
        # an editable install on first import); a machine with PYTHONDONTWRITEBYTECODE set
        # would otherwise compile phc's sources in every run
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env.pop("PHC_FRONT_END_CACHE", None)
        off = dict(env, PHC_FRONT_END_CACHE="0")
        one_thread = dict(env, **{var: "1" for var in THREAD_VARIABLES})  # as the `phc` command asks
        out = str(Path(tmp) / "p.csv")
        rows = [
            ("`python -c pass` (the interpreter)", [py, "-c", "pass"], env, None),
            ("`python -c 'import numpy, scipy.sparse, sksundae.ida'` (scikit-SUNDAE's own import)",
             [py, "-c", "import numpy, scipy.sparse, scipy.sparse.linalg, scipy.linalg, sksundae.ida"], env, None),
            ("`python -c 'import numpy, scipy.sparse, scipy.linalg, scipy.sparse.csgraph'`, one BLAS thread "
             "(the libraries a run's consistent initialization and singularity monitor call)",
             [py, "-c", "import numpy, scipy.sparse, scipy.linalg, scipy.sparse.csgraph"], one_thread, None),
            ("`phc --version`", [*phc, "--version"], env, 0.2),
            ("`phc --help`", [*phc, "--help"], env, 0.2),
            (f"`phc validate {PENDULUM}`, cached", [*phc, "validate", PENDULUM], env, 0.5),
            (f"`phc validate {PENDULUM}`, PHC_FRONT_END_CACHE=0", [*phc, "validate", PENDULUM], off, 0.5),
            (f"`phc simulate {PENDULUM} --t-end 0.01`, front end cached",
             [*phc, "simulate", PENDULUM, "--t-end", "0.01", "--out", out], env, None),
            (f"`phc simulate {PENDULUM} --t-end 0.01`, PHC_FRONT_END_CACHE=0",
             [*phc, "simulate", PENDULUM, "--t-end", "0.01", "--out", out], off, None),
            (f"`phc simulate {PENDULUM}`, front end cached", [*phc, "simulate", PENDULUM, "--out", out], env, 0.8),
            (f"`phc simulate {PENDULUM}`, PHC_FRONT_END_CACHE=0", [*phc, "simulate", PENDULUM, "--out", out], off,
             None),
        ]
        print(f"# Start-up of the `phc` command ({args.repeat} runs each after a warm-up run; caches warm)\n")
        print(f"Command: `python benchmarks/bench_startup.py --repeat {args.repeat}`\n")
        print("| command | best wall [s] | median wall [s] | CPU of the best run [s] | goal |")
        print("|---|---:|---:|---:|---|")
        cpus = []
        for label, cmd, e, goal in rows:
            best, median, cpu = run(cmd, e, args.repeat)
            cpus.append(cpu)
            verdict = "" if goal is None else f"≤ {goal} s wall: {'met' if best <= goal else 'not met'}"
            print(f"| {label} | {best:.2f} | {median:.2f} | {cpu:.2f} | {verdict} |", flush=True)
        floor = cpus[next(i for i, row in enumerate(rows) if row[2] is one_thread)]
        warm = cpus[next(i for i, row in enumerate(rows) if "0.01" in row[1] and row[2] is env)]
        print(f"\nWarm `phc simulate {PENDULUM} --t-end 0.01`: {warm:.2f} s CPU, of which {floor:.2f} s is the "
              f"interpreter importing numpy and scipy (third row) and {warm - floor:.2f} s the rest.")
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
        print(f"\nLoad average at the end: {load:.1f} on {os.cpu_count()} logical CPUs.")


if __name__ == "__main__":
    main()
