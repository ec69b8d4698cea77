"""The `phc` argument parser and the checks of the arguments before any work.

:func:`build_parser` (every subcommand and option; docs/reference/cli.md is generated from
it), the limits of the numeric options and the accepted output paths
(:data:`NUMERIC_OPTIONS`, :data:`OUTPUT_OPTIONS`, checked by :func:`_check_arguments`),
and what wraps every command: its `--max-memory` budget, its `--allow-path` folders and
phc's warnings as one line. Part of :mod:`phc.cli`.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from phc import __version__
from phc.cli.commands import (cmd_animate, cmd_bench, cmd_cache, cmd_check, cmd_compile, cmd_export, cmd_graph,
                              cmd_linearize, cmd_schema, cmd_simulate, cmd_sweep, cmd_validate)
from phc.errors import UsageError
from phc.names import RUN_LIMITS, option_problem

_python_showwarning = warnings.showwarning


# Numeric options, checked in one place before any work: (command, dest) -> (option, kind,
# low, high). Kinds: "positive" (finite, > 0, <= high), "fraction" (0 < x < 1), "count"
# (a whole number in [low, high]) (phc.names.option_problem). The run options' ranges are
# the model language's (phc.names.RUN_LIMITS, which phc.options.RunOptions checks too).
NUMERIC_OPTIONS = {
    ("simulate", "t_end"): ("--t-end", *RUN_LIMITS["t_end"]),
    ("simulate", "n_out"): ("--n-out", *RUN_LIMITS["n_out"]),
    ("simulate", "step"): ("--step", *RUN_LIMITS["step"]),
    ("simulate", "rtol"): ("--rtol", *RUN_LIMITS["rtol"]),
    ("simulate", "atol"): ("--atol", *RUN_LIMITS["atol"]),
    ("animate", "t_end"): ("--t-end", *RUN_LIMITS["t_end"]),
    ("animate", "magnify"): ("--magnify", "positive", 0, 1e6),
    ("animate", "frames"): ("--frames", "count", 1, 10_000),
    ("animate", "fps"): ("--fps", "count", 1, 100),
    ("bench", "tolerances"): ("--tol", *RUN_LIMITS["rtol"]),
    ("bench", "steps"): ("--step", *RUN_LIMITS["step"]),
    ("bench", "repeats"): ("--repeats", "count", 1, 1000),
    ("bench", "reference_rtol"): ("--reference-rtol", *RUN_LIMITS["rtol"]),
    ("bench", "target_error"): ("--target-error", *RUN_LIMITS["rtol"]),
    ("check", "samples"): ("--samples", "count", 0, 1000),
    ("sweep", "samples"): ("--samples", "count", 1, 100_000),
    ("sweep", "workers"): ("--workers", "count", 1, 4096),
    ("sweep", "seed"): ("--seed", "count", 0, 2**32 - 1),  # phc.sweep.design.MAX_SEED
    ("sweep", "t_end"): ("--t-end", *RUN_LIMITS["t_end"]),
    ("sweep", "n_out"): ("--n-out", *RUN_LIMITS["n_out"]),
    ("linearize", "modes"): ("--modes", "count", 1, 1_000_000),
    ("export", "step"): ("--step", *RUN_LIMITS["step"]),
}

# Output paths, checked before any work: (command, dest) -> accepted extensions, or None
# for a folder (created if missing). "-" (stdout) is always accepted where it makes sense.
OUTPUT_OPTIONS = {
    ("simulate", "out"): ("--out", (".csv", ".npz")),
    ("simulate", "plot"): ("--plot", (".png", ".pdf", ".svg")),
    ("animate", "output"): ("-o", (".gif",)),
    ("graph", "output"): ("-o", (".dot", ".png")),
    ("compile", "output"): ("-o", None),
    ("bench", "out_dir"): ("--out-dir", None),
    ("sweep", "out"): ("--out", (".csv", ".parquet")),
    ("sweep", "series"): ("--series", (".csv",)),
    ("sweep", "plot"): ("--plot", (".png", ".pdf", ".svg")),
    ("linearize", "output"): ("-o", (".txt", ".json", ".npz")),
    ("export", "fmu"): ("--fmu", (".fmu",)),
}


def _check_number(option: str, kind: str, low: float, high: float, value) -> None:
    problem = option_problem(kind, low, high, value)
    if problem:
        raise UsageError(f"{option} {problem}")


def _check_arguments(args) -> None:
    """Numeric options, memory sizes, output paths and the environment variables read as
    numbers, before any work (usage errors)."""
    from phc.io import OutputPathError, check_output_dir, check_output_file

    if getattr(args, "max_memory", None) is not None and not isinstance(args.max_memory, int):
        args.max_memory = _memory_size(args.max_memory)  # bytes from here on (phc.codegen.fastpath, _with_budget)
    _check_environment(budget=hasattr(args, "max_memory"))
    for (command, dest), (option, kind, low, high) in NUMERIC_OPTIONS.items():
        value = getattr(args, dest, None) if args.command == command else None
        for item in (value if isinstance(value, list) else [value] if value is not None else []):
            _check_number(option, kind, low, high, item)
    for (command, dest), (option, suffixes) in OUTPUT_OPTIONS.items():
        path = getattr(args, dest, None) if args.command == command else None
        if path == "":
            raise UsageError(f"{option} is empty; give a {'folder' if suffixes is None else 'file name'}")
        if not path or path == "-" and command == "graph":
            continue
        try:
            if suffixes is None:
                check_output_dir(path, option)
            else:
                check_output_file(path, option, suffixes)
        except OutputPathError as err:
            raise UsageError(str(err)) from None


def _solver_names() -> tuple[str, ...]:
    from phc.names import SOLVER_NAMES

    return SOLVER_NAMES


def _peer_solver_names() -> tuple[str, ...]:
    from phc.names import PEER_SOLVER_NAMES

    return PEER_SOLVER_NAMES


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """phc's own warnings as one line `phc: warning: ...`; others as Python prints them."""
    from phc import PhcWarning
    from phc.inert import printable

    if issubclass(category, PhcWarning):
        print(f"phc: warning: {printable(str(message), quoted=False)}", file=sys.stderr)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


def _allowed_paths(args):
    """Files under each `--allow-path DIR` may be referenced too (see phc.frontend.files)."""
    from phc.frontend.files import allow_paths

    dirs = getattr(args, "allow_path", None) or []
    for d in dirs:
        if not d:  # Path("") is the working folder: not what an empty value means
            raise UsageError("--allow-path is empty; give a folder")
        try:
            is_dir = Path(d).is_dir()
        except OSError as err:  # a name too long, a loop of symbolic links
            raise UsageError(f"--allow-path `{d}` cannot be used ({(err.strerror or type(err).__name__).lower()})"
                             ) from None
        if not is_dir:
            raise UsageError(f"--allow-path `{d}` is not a directory")
    return allow_paths(dirs)


def _memory_size(text: str) -> int:
    """Bytes of `--max-memory SIZE`, parsed here (not by argparse) with its bounds: a one-line
    usage error, also for a number too large for a float."""
    from phc.frontend.budget import parse_size

    try:
        return parse_size(text)
    except ValueError as err:
        raise UsageError(f"--max-memory {err}") from None


def _check_environment(budget: bool = True) -> None:
    """The environment variables phc reads as numbers: PHC_MAX_MEMORY (for the commands
    with a memory budget) and PHC_CACHE_MAX_MB."""
    from phc.frontend.budget import max_memory
    from phc.codegen.load import cap_problem

    try:
        if budget:
            max_memory()
    except ValueError as err:
        raise UsageError(str(err)) from None
    problem = cap_problem()
    if problem:
        raise UsageError(problem)


def _with_budget(func):
    """Run a command under its `--max-memory` budget (see phc.frontend.budget)."""

    def run(args) -> int:
        from phc.frontend import budget

        with budget.override(args.max_memory):
            try:
                budget.max_memory()
            except ValueError as err:  # a malformed PHC_MAX_MEMORY
                raise UsageError(str(err)) from None
            return func(args)

    return run


_FORMATS = {"text": "one located line per problem", "json": "one JSON document on stdout",
            "github": "GitHub Actions annotations (::error file=...,line=...,col=...::message)",
            "sarif": "one SARIF 2.1.0 log on stdout for code scanning (github/codeql-action/upload-sarif)"}


def format_help(*choices: str) -> str:
    """The --format help of a command that offers `choices` (only those)."""
    return "; ".join(f"{c}: {_FORMATS[c]}" for c in choices)


FORMAT_HELP = format_help("text", "json", "github", "sarif")


class _Parser(argparse.ArgumentParser):
    """argparse's parser whose error line quotes the user's arguments inert (phc.inert): an
    unrecognized argument may hold ESC or a line break and `::error ...`."""

    def error(self, message):
        from phc.inert import inert

        super().error(inert(message))


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="phc", description="Compiler for port-Hamiltonian models.")
    parser.add_argument("--version", action="version", version=f"phc {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("validate", help="check model files (schema, names, expressions, structure); a part "
                       "(`kind: part`) without closing its exposed ports")
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("--format", choices=("text", "json", "github", "sarif"), default="text", help=FORMAT_HELP)
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("compile", help="generate the residual module of each model")
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("--format", choices=("text", "github", "sarif"), default="text",
                   help=format_help("text", "github", "sarif"))
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.add_argument("-o", "--output", default=".", metavar="DIR", help="directory for the generated module")
    p.add_argument("--backend", choices=("auto", "numpy", "numba", "c"),
                   help="what runs the generated functions: numba (machine code, cached; pip install "
                   "'port-hamiltonian-compiler[fast]'), c (C compiled by the system C compiler, cached), numpy, "
                   "or auto (C where a compiler is found, else numba for models of 16 unknowns or more when installed; "
                   "the default, or $PHC_BACKEND)")
    p.set_defaults(func=cmd_compile)

    p = sub.add_parser("simulate", help="compile and simulate a model or a scene")
    p.add_argument("file", metavar="FILE", help="a model file, or a scene file (models/scenes/*.yaml)")
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.add_argument("--t-end", type=float, help="end time (default: the model's simulation.t_end)")
    p.add_argument("--n-out", type=int, help="number of output points")
    p.add_argument("--solver", choices=_solver_names(), help="integrator (default: the model's)")
    p.add_argument("--step", type=float, help="step size of the midpoint solver")
    p.add_argument("--backend", choices=("auto", "numpy", "numba", "c"),
                   help="what runs the generated functions: numba (machine code, cached; pip install "
                   "'port-hamiltonian-compiler[fast]'), c (C compiled by the system C compiler, cached), numpy, "
                   "or auto (C where a compiler is found, else numba for models of 16 unknowns or more when installed; "
                   "the default, or $PHC_BACKEND)")
    p.add_argument("--rtol", type=float)
    p.add_argument("--atol", type=float)
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="override a parameter (repeatable)")
    p.add_argument("-o", "--out", metavar="FILE", help="write results to FILE (.csv or .npz)")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--plot", metavar="OUT.png", help="draw the requested outputs over time (needs the `plot` extra: pip install 'port-hamiltonian-compiler[plot]')")
    p.add_argument("--estimate-error", action="store_true",
                   help="estimate the temporal (finer step/tolerance) and spatial (refined meshes) errors of the "
                   "outputs by Richardson extrapolation from reruns")
    p.add_argument("--profile", action="store_true",
                   help="break the CPU time into compile stages, residual and Jacobian evaluations and solver work")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("animate", help="simulate and draw the planar mechanism frame by frame (GIF)")
    p.add_argument("file", metavar="FILE", help="a scene or model file")
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.add_argument("-o", "--output", metavar="OUT.gif", required=True)
    p.add_argument("--magnify", type=float, default=1.0, help="magnify the beam deflection in the picture")
    p.add_argument("--frames", type=int, default=100, help="at most this many frames")
    p.add_argument("--fps", type=int, default=20)
    p.add_argument("--t-end", type=float)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_animate)

    p = sub.add_parser("bench", help="work-precision study of a scene: error vs CPU time across solvers, "
                       "tolerances and meshes (CSV, Markdown, PNG)")
    p.add_argument("scene", metavar="SCENE")
    p.add_argument("--solver", action="append", dest="solvers", choices=_solver_names() + _peer_solver_names(),
                   help="solver to sweep (repeatable; default: the scene's bench.solvers, else all of phc's); "
                   "scipy_Radau, scipy_BDF, scipy_DOP853: scipy's methods given the same residual")
    p.add_argument("--tol", action="append", type=float, dest="tolerances", help="rtol of IDA (repeatable)")
    p.add_argument("--step", action="append", type=float, dest="steps", help="step of fixed-step solvers (repeatable)")
    p.add_argument("--mesh", action="append", metavar="COMP=N1,N2,...", help="element counts to sweep (repeatable)")
    p.add_argument("--repeats", type=int, help="runs per point; the minimum CPU time is reported")
    p.add_argument("--output", action="append", dest="outputs", help="outputs whose error is measured (repeatable)")
    p.add_argument("--reference", metavar="FILE.csv",
                   help="reference values (a `t` column and one column per output, e.g. a published reference "
                   "solution): errors of those outputs at those times; replaces the scene's reference_values")
    p.add_argument("--reference-rtol", type=float, help="rtol of the reference run (no closed form)")
    p.add_argument("--target-error", type=float,
                   help="relative error to reach: each fixed-step solver goes on to finer steps (from its "
                   "measured convergence) until its error is at most this")
    p.add_argument("--out-dir", default=".", help="where bench.csv, bench.md and bench.png go")
    p.add_argument("--no-cache", action="store_true", help="recompute the reference run")
    p.add_argument("--no-plot", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("sweep", help="parameter study: grids, Latin-hypercube or random samples, on a local "
                       "process pool or a Dask cluster (one compilation per sweep)")
    p.add_argument("file", metavar="FILE", help="a model file, or a scene file (its `sweep:` section is used)")
    p.add_argument("--param", action="append", metavar="NAME=SPEC",
                   help="swept values (repeatable): a number, a list 1,2,5, a grid A:B:N or log:A:B:N, or a "
                   "distribution uniform:A:B, normal:MEAN:STD, loguniform:A:B; NAME is a parameter, "
                   "accuracy.rtol/atol/step or accuracy.mesh.COMPONENT")
    p.add_argument("--samples", type=int, help="number of samples of the distributions")
    p.add_argument("--seed", type=int, help="seed of the sampler (default 0)")
    p.add_argument("--sampling", choices=("lhs", "random"), help="Latin hypercube (default) or random")
    p.add_argument("--executor", choices=("local", "dask"), default="local",
                   help="local process pool (default) or Dask distributed (needs the `cluster` extra: pip install 'port-hamiltonian-compiler[cluster]')")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler address (tcp://host:8786) or scheduler file; default: a LocalCluster")
    p.add_argument("--workers", type=int, help="worker processes of the local pool or LocalCluster (default: "
                   "the CPUs available)")
    p.add_argument("-o", "--out", required=True, metavar="RESULTS",
                   help="results, one row per run: -o RESULTS.csv (or RESULTS.parquet) writes RESULTS.csv, "
                   "RESULTS.parquet (with pyarrow) and RESULTS.sweep.json (what was swept, for --resume); "
                   "each file written is listed")
    p.add_argument("--series", metavar="FILE.csv", help="also write every run's output time series (long format)")
    p.add_argument("--resume", action="store_true",
                   help="continue the results in --out (same model, values, run options and phc version): its rows "
                   "are kept, points without a row run")
    p.add_argument("--retry-failed", action="store_true",
                   help="with --resume: run the points of failed rows again too")
    p.add_argument("--overwrite", action="store_true", help="replace existing results in --out")
    p.add_argument("--t-end", type=float, help="end time of every run (default: the model's)")
    p.add_argument("--n-out", type=int, help="output points of every run")
    p.add_argument("--solver", choices=_solver_names(), help="integrator (default: the model's)")
    p.add_argument("--backend", choices=("auto", "numpy", "numba", "c"),
                   help="what runs the generated functions on every worker (and in every recompiled group): "
                   "numba, c, numpy, or auto (the default, or $PHC_BACKEND)")
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.add_argument("--plot", metavar="OUT.png", help="draw an output against one or two parameters (needs the `plot` extra: pip install 'port-hamiltonian-compiler[plot]')")
    p.add_argument("--plot-output", metavar="COLUMN", help="column to draw (default: the first output's max)")
    p.add_argument("--plot-against", metavar="P1[,P2]", help="swept parameter(s) on the axes (default: the first "
                   "one or two that vary)")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("check", help="certify Dirac structures and couplings and the compiled equations (Berger, Hochdahl, Reis, Seifried, \"Port-Hamiltonian modelling of coupled rigid/flexible multibody systems\", Section 2)")
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("--format", choices=("text", "json", "github", "sarif"), default="text", help=FORMAT_HELP)
    p.add_argument("--samples", type=int, default=2, help="random states sampled besides the initial one")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("linearize", help="linearize about a consistent point: the descriptor system (E, A, B, C, "
                       "D), finite eigenvalues with natural frequencies and damping ratios, mode shapes")
    p.add_argument("file", metavar="FILE", help="a model file, or a scene file")
    p.add_argument("--at", type=float, metavar="T", help="linearize at time T of the simulated motion (default: at "
                   "the start, about the initial state)")
    p.add_argument("--state", action="append", metavar="NAME=VALUE",
                   help="initial value of a state (repeatable); the rest by consistent initialization")
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="override a parameter (repeatable)")
    p.add_argument("--mesh", action="append", metavar="COMPONENT=N", help="elements of a distributed component "
                   "(repeatable)")
    p.add_argument("--format", choices=("text", "json", "npz"),
                   help="report format (default: from the -o suffix, else text)")
    p.add_argument("-o", "--output", metavar="OUT", help="write the report to OUT (.txt, .json or .npz)")
    p.add_argument("--modes", type=int, default=20, help="modes listed in the text report (default 20)")
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.set_defaults(func=cmd_linearize)

    p = sub.add_parser("export", help="write the model as an FMI 2.0 co-simulation FMU (the implicit midpoint rule "
                       "in C, a linux64 binary built with the system C compiler) for other simulation tools")
    p.add_argument("file", metavar="FILE", help="a model file, or a scene file")
    p.add_argument("--fmu", required=True, metavar="OUT.fmu", help="the FMU to write")
    p.add_argument("--fmi", choices=("2", "3"), default="2", help="FMI version (2: FMI 2.0; 3 is not offered yet)")
    p.add_argument("--solver", choices=_solver_names(), help="the integrator the FMU embeds: midpoint (the only one "
                   "it offers, and the default)")
    p.add_argument("--step", type=float, help="longest step (default: the model's simulation.step, else one step per "
                   "communication interval)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="export with this parameter value (the "
                   "FMU's default; repeatable)")
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("graph", help="draw the interconnection graph (DOT, or PNG with matplotlib)")
    p.add_argument("file", metavar="FILE")
    p.add_argument("-o", "--output", metavar="OUT", help="out.dot or out.png (default: DOT on stdout)")
    p.set_defaults(func=cmd_graph)

    for name in ("validate", "compile", "simulate", "animate", "bench", "check", "graph", "sweep", "linearize",
                 "export"):
        p = sub.choices[name]
        p.add_argument("--max-memory", metavar="SIZE",
                       help="memory budget, e.g. 8G or 512M: a model whose estimated compile and output memory is "
                       "larger is refused before the work (default 2G; env PHC_MAX_MEMORY)")
        p.set_defaults(func=_with_budget(p.get_default("func")))

    p = sub.add_parser("schema", help="print, write or check the JSON Schemas of the model language")
    p.add_argument("--name", default="model", choices=("model", "scene", "model.schema.json", "scene.schema.json"),
                   help="which schema to print: the model language or scenes (default: model)")
    p.add_argument("--write", action="store_true", help="write the schemas into --dir")
    p.add_argument("--check", action="store_true", help="fail if the schemas in --dir are stale")
    p.add_argument("--dir", default="schemas")
    p.set_defaults(func=cmd_schema)

    p = sub.add_parser("cache", help="show or empty the cache of generated modules and bench references")
    p.add_argument("action", choices=("info", "clean"), nargs="?", default="info")
    p.set_defaults(func=cmd_cache)
    for name in ("validate", "compile", "simulate", "animate", "bench", "check", "graph", "sweep", "linearize",
                 "export"):
        sub.choices[name].add_argument(
            "--allow-path", action="append", default=[], metavar="DIR",
            help="also allow files under DIR to be referenced (nested models, tables, matrices); by default "
            "they must lie in the directory of the model or scene file (repeatable; env PHC_ALLOW_PATH)")
    return parser
