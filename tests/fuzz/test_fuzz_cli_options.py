"""Every option of every subcommand, given a hostile value, ends in a clean answer (issue
32, "Done when": the CLI fuzz over every subcommand's options finds no internal error or
traceback).

The options are read from :func:`phc.cli.build_parser` itself (argparse's subparsers and
their actions), so an option added later is fuzzed without editing this file. Each
subcommand has a cheap valid baseline command (a tiny model, a short run, outputs in a
temporary folder); one option at a time is then replaced by, or given, a hostile value —
empty, blank, non-finite, negative, zero, too large for a float, 400 nines, an escape
sequence, a line break, a GitHub workflow command, a non-ASCII digit, ``-``, 5 000
characters, a path climbing out of the folder, ``/dev/null`` — and a flag is switched
(added, or removed from the baseline). Positional arguments are fuzzed the same way. An
option read only together with another (:data:`COMPANIONS`: `schema --dir` with `--check`,
`sweep --scheduler` with `--executor dask`, ...) is fuzzed with that one too. Every
``PHC_...`` environment variable named in phc's sources gets the same values, under the
baselines of simulate (and, in the slow run, sweep, compile and cache).

Each run must end with an exit status of 0, 1 or 2 and no exception out of
:func:`phc.cli.main` (argparse's own ``SystemExit`` is its exit status), within
:data:`TIMEOUT` seconds; nothing it prints may hold a traceback, "internal error",
"please report" or a raw control character, and every line on stderr must be one of the
documented forms: argparse's usage block ending in ``phc SUB: error: ...``, a
``phc SUB: error: ...`` line, a ``phc: warning: ...`` line, a located diagnostic
ending in its code ``[PHC-E123]`` (or ``phc schema --check``'s ``FILE: stale ...``), or
a progress bar's line (with the flag `--quiet` switched off). An empty option value is
never accepted (exit status not 0): it is not read as a default or as the working folder.

The default run is derandomized and covers every option with a few values (chosen per
subcommand and option by a seeded generator); ``-m slow`` runs every value on every
option. ``export``'s baseline needs a C compiler (skipped without one; without one the
hostile runs end in its refusal, held to the same rules). ``bench`` runs a two-point study of a scene written here (one solver, one
step, a half-second run). The caches and the state folder are temporary
(``PHC_CACHE_DIR``, ``PHC_STATE_DIR``).
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import random
import re
import shutil
import signal
import warnings
from pathlib import Path

import pytest

from phc.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[2]
MODELS = ROOT / "models"

TIMEOUT = 60
"""Seconds a single run may take before it counts as a hang (the baselines take ~1 s)."""

PER_OPTION = 3
"""Hostile values per option in the default run."""

HOSTILE = (
    "", " ", "nan", "inf", "-inf", "-1", "0", "1e400", "9" * 400, "x", "\x1b[2J", "a\nb", "::error file=x::y",
    "\u00b2", "-", "y" * 5000, "../../etc/passwd", "../../../x.csv", "/dev/null",
)
"""Values given to every option taking one (and to every positional argument)."""

FLAG = "<flag>"
"""The one variant of an option taking no value: switched (added, or removed if in the baseline)."""

PLOT = importlib.util.find_spec("matplotlib") is not None
"""The sweep's baseline draws its plot when it can (so `--plot-output` and `--plot-against` are read)."""

SCENE = """\
format_version: 1
model: msd.yaml
name: tiny_bench
t_end: 0.5
n_out: 6
solver: midpoint
accuracy: {step: 0.05}
outputs:
  x: spring.x
bench: {solvers: [midpoint], steps: [0.05]}
"""

# -- the options, read from the parser ----------------------------------------------------


def _subparsers(parser: argparse.ArgumentParser) -> dict:
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


def _name(action: argparse.Action) -> str:
    """The option's longest spelling (`--output` rather than `-o`), or a positional's dest."""
    return max(action.option_strings, key=len) if action.option_strings else action.dest


def _fuzzed_actions(sub: argparse.ArgumentParser) -> list:
    return [a for a in sub._actions if not isinstance(a, (argparse._HelpAction, argparse._VersionAction))]


def _takes_value(action: argparse.Action) -> bool:
    return action.nargs != 0


def _cases() -> list:
    """(subcommand, option, value) of every run of the full product."""
    cases = []
    for command, sub in _subparsers(build_parser()).items():
        for action in _fuzzed_actions(sub):
            values = HOSTILE if _takes_value(action) else (FLAG,)
            cases += [(command, _name(action), value) for value in values]
    return cases


def _default_cases() -> list:
    """At most PER_OPTION values per option, drawn by a generator seeded by subcommand and
    option (the same draw on every machine and Python: string seeds are hashed by SHA-512)."""
    by_option: dict = {}
    for command, option, value in _cases():
        by_option.setdefault((command, option), []).append(value)
    cases = []
    for (command, option), values in by_option.items():
        rng = random.Random(f"{command} {option}")
        chosen = values if len(values) <= PER_OPTION else rng.sample(values, PER_OPTION)
        cases += [(command, option, value) for value in chosen]
    return cases


def _id(case) -> str:
    command, option, value = case
    shown = value if len(value) <= 12 else f"{value[:6]}..{len(value)}"
    return f"{command} {option} {shown!r}"


# -- the baselines ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Model copies, the bench scene and the cache and state folders, shared by the runs
    (the caches warm once)."""
    base = tmp_path_factory.mktemp("cli-fuzz")
    models = base / "models"
    models.mkdir()
    for name in ("mass_spring_damper.yaml", "pendulum.yaml"):
        shutil.copy(MODELS / name, models / name)
    shutil.copy(MODELS / "mass_spring_damper.yaml", models / "msd.yaml")
    (models / "scene.yaml").write_text(SCENE, encoding="utf-8")
    return base


def _baseline(command: str, world: Path) -> tuple[list, dict]:
    """(positional arguments, {option: value or FLAG}) of a cheap run that succeeds.
    Outputs are relative: the runs start in a folder of their own."""
    msd = str(world / "models" / "mass_spring_damper.yaml")
    pendulum = str(world / "models" / "pendulum.yaml")
    quick = {"--t-end": "0.1", "--n-out": "5"}
    return {
        "validate": ([msd], {}),
        "compile": ([msd], {"--output": "gen"}),
        "simulate": ([msd], {**quick, "--out": "r.csv", "--quiet": FLAG}),
        "animate": ([pendulum], {"--output": "a.gif", "--frames": "2", "--t-end": "0.1", "--quiet": FLAG}),
        "bench": ([str(world / "models" / "scene.yaml")],
                  {"--out-dir": "bench", "--repeats": "1", "--no-plot": FLAG, "--quiet": FLAG}),
        "sweep": ([msd], {**quick, "--param": "k=3,4", "--out": "s.csv", "--workers": "1", "--quiet": FLAG,
                          **({"--plot": "s.png"} if PLOT else {})}),  # --plot: --plot-output/-against are used
        "check": ([msd], {"--samples": "1"}),
        "linearize": ([msd], {"--output": "l.json"}),
        "export": ([msd], {"--fmu": "m.fmu"}),
        "graph": ([msd], {"--output": "g.dot"}),
        "schema": ([], {"--write": FLAG, "--dir": "schemas"}),
        "cache": (["info"], {}),
    }[command]


def _argv(command: str, positionals: list, options: dict) -> list:
    argv = [command]
    for option, value in options.items():
        if value is FLAG:
            argv.append(option)
        elif option.startswith("--"):
            argv.append(f"{option}={value}")
        else:
            argv += [option, value]
    # positionals after `--`, so a value starting with `-` is one, as a user would write it
    return argv + (["--", *positionals] if positionals else [])


COMPANIONS = {
    ("schema", "--dir"): [{"--write": None, "--check": FLAG}],
    ("sweep", "--scheduler"): [{"--executor": "dask"}],
    ("sweep", "--out"): [{"--resume": FLAG}, {"--overwrite": FLAG}],
    ("sweep", "--series"): [{"--resume": FLAG}],
    ("sweep", "--retry-failed"): [{"--resume": FLAG}],
    ("sweep", "--samples"): [{"--param": "k=uniform:3:4"}],
    ("sweep", "--seed"): [{"--param": "k=uniform:3:4", "--samples": "2"}],
    ("simulate", "--step"): [{"--solver": "midpoint"}],
    ("linearize", "--output"): [{"--format": "npz"}],
    ("linearize", "--modes"): [{"--output": None}],
}
"""Options that are read only together with another: each hostile value is also tried with
these changes to the baseline (an option set, or removed for None)."""


def _variant(command: str, option: str, value: str, world: Path, companion=None) -> list:
    sub = _subparsers(build_parser())[command]
    (action,) = [a for a in _fuzzed_actions(sub) if _name(a) == option]
    positionals, options = _baseline(command, world)
    positionals, options = list(positionals), dict(options)
    for name, setting in (companion or {}).items():
        if setting is None:
            options.pop(name, None)
        else:
            options[name] = setting
    if not action.option_strings:  # a positional: the baseline's in that place is replaced
        index = [a.dest for a in sub._actions if not a.option_strings].index(action.dest)
        positionals[index:index + 1] = [value]
    elif value is FLAG or value == FLAG:
        if option in options:
            del options[option]
        else:
            options[option] = FLAG
    else:
        options[option] = value
    return _argv(command, positionals, options)


# -- one run and what it may print --------------------------------------------------------

CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")
"""Raw control characters (all of C0 but tab and newline, DEL, C1): ESC, BEL and CR among them."""
USAGE_ERROR = re.compile(r"phc( [a-z]+)?: error: \S")
WARNING = re.compile(r"phc: warning: \S")
STALE = re.compile(r".+\.schema\.json: stale or missing; regenerate with `phc schema --write --dir .+`$")
"""`phc schema --check`'s line per stale file (a whole file is the place)."""
PROGRESS = re.compile(r"\S.* \[[# ]{30}\] .*elapsed \d")
"""A progress bar's line on a stream that is not a terminal (phc.progress), without `--quiet`."""
LOCATED = re.compile(r".+: .+ \[PHC-[EWI]\d{3}\]$")


class _Hang(BaseException):
    """Raised by the alarm; not an Exception, so `main` cannot report it as its own."""


def _on_alarm(signum, frame):
    raise _Hang


def _run(argv: list, capsys) -> tuple[int, str, str]:
    shown = repr(["phc", *argv])[:400]
    old_handler = signal.signal(signal.SIGALRM, _on_alarm)
    old_showwarning = warnings.showwarning
    signal.alarm(TIMEOUT)
    try:
        code = main(argv)
    except SystemExit as done:  # argparse's usage errors
        code = 0 if done.code is None else done.code
    except _Hang:
        pytest.fail(f"{shown} did not finish in {TIMEOUT} s")
    except BaseException as err:  # noqa: BLE001 (any escape is the finding)
        pytest.fail(f"{shown} raised {type(err).__name__}: {str(err)[:300]}")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old_handler)
        warnings.showwarning = old_showwarning
    out, err = capsys.readouterr()
    return code, out, err


def _check(argv: list, code, out: str, err: str) -> None:
    shown = repr(["phc", *argv])[:400]
    text = out + err
    assert code in (0, 1, 2), f"{shown}: exit status {code!r}\n{err[-2000:]}"
    for bad in ("Traceback", "internal error", "please report"):
        assert bad not in text, f"{shown}: {bad!r} printed\n{text[-2000:]}"
    match = CONTROL.search(text)
    assert not match, f"{shown}: raw control character {match.group()!r} printed\n{text[-2000:]!r}"
    lines = err.splitlines()
    if lines and lines[0].startswith("usage: phc"):  # argparse: the usage (wrapped) and one error line
        lines = lines[1:]
        while lines and lines[0].startswith(" "):
            lines = lines[1:]
        assert len(lines) == 1 and USAGE_ERROR.match(lines[0]), f"{shown}: usage without one error line\n{err}"
    for line in lines:
        if line.strip():
            assert (USAGE_ERROR.match(line) or WARNING.match(line) or LOCATED.match(line) or PROGRESS.match(line)
                    or STALE.match(line)), \
                f"{shown}: stderr line of no documented form: {line[:500]!r}\n{err[-2000:]}"


def _fuzz(command: str, option: str, value: str, world: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    # (export without a C compiler: its refusal is held to the same rules)
    # a deep working folder: `../../etc/passwd` and `../../../x.csv` stay inside tmp_path
    cwd = tmp_path / "a" / "b" / "c" / "d"
    cwd.mkdir(parents=True)
    monkeypatch.chdir(cwd)
    cache = world / ("cache-of-cache" if command == "cache" else "cache")  # `cache clean` empties its own
    monkeypatch.setenv("PHC_CACHE_DIR", str(cache))
    monkeypatch.setenv("PHC_STATE_DIR", str(cache / "state"))
    for companion in [None, *COMPANIONS.get((command, option), [])]:
        argv = _variant(command, option, value, world, companion)
        code, out, err = _run(argv, capsys)
        _check(argv, code, out, err)
        if value == "":  # an empty value is refused, never read as a default or as the working folder
            assert code != 0, f"{argv!r}: an empty value was accepted\n{out[-1000:]}"


FOUND = [
    ("animate", "--fps", "9" * 400),  # OverflowError converting the int to a float: "internal error"
    ("sweep", "--seed", "9" * 400),
    ("schema", "--dir", "y" * 5000),  # --write: "internal error: OSError: File name too long"
    ("schema", "--dir", ""),  # --write into the working folder
    ("simulate", "--allow-path", ""),  # accepted as the working folder
    ("sweep", "--scheduler", ""),  # silently ignored (`--scheduler x` is refused without dask)
    ("sweep", "--plot-output", ""),  # silently the default column
    ("sweep", "--plot-against", ""),
]
"""Cases the fuzz found (each failed before its fix); they run whatever the draw."""


# -- the environment ----------------------------------------------------------------------

NOT_READ = {"PHC_ABI", "PHC_DEBUG"}
"""`PHC_` names in phc's sources that are not fuzzed: a C macro, and the switch that shows
tracebacks of internal errors on purpose."""


@functools.lru_cache(maxsize=None)
def _environment_variables() -> tuple:
    """Every `PHC_...` environment variable named in phc's Python sources (a new one is
    fuzzed without editing this file)."""
    names = set()
    for path in (ROOT / "phc").rglob("*.py"):
        names |= set(re.findall(r"\bPHC_[A-Z][A-Z_]*[A-Z]\b", path.read_text(encoding="utf-8")))
    return tuple(sorted(names - NOT_READ))


ENV_COMMANDS = ("simulate", "sweep", "compile", "cache")
"""The baselines run under each hostile environment variable (all of them in the slow run;
the default run: simulate)."""


def _env_cases(commands=ENV_COMMANDS) -> list:
    return [(command, name, value) for command in commands for name in _environment_variables() for value in HOSTILE]


def _default_env_cases() -> list:
    cases = []
    for name in _environment_variables():
        rng = random.Random(f"env {name}")
        cases += [("simulate", name, value) for value in rng.sample(HOSTILE, PER_OPTION)]
    return cases


def _fuzz_environment(command: str, name: str, value: str, world: Path, tmp_path: Path, monkeypatch,
                      capsys) -> None:
    cwd = tmp_path / "a" / "b" / "c" / "d"
    cwd.mkdir(parents=True)
    monkeypatch.chdir(cwd)
    # the caches of these runs are their own: a hostile value must not leave a record the others read
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    monkeypatch.setenv(name, value)
    argv = _argv(command, *_baseline(command, world))
    code, out, err = _run(argv, capsys)
    _check(argv, code, out, err)


# -- the tests ----------------------------------------------------------------------------


@pytest.mark.parametrize("command", sorted(_subparsers(build_parser())))
def test_baseline_succeeds(command, world, tmp_path, monkeypatch, capsys):
    """Every baseline runs (exit 0, nothing wrong printed): the hostile variants start
    from a command that works, so a refusal is the value's doing."""
    if command == "export" and shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("phc export builds the FMU with the system C compiler; none is installed")
    cwd = tmp_path / "a" / "b" / "c" / "d"
    cwd.mkdir(parents=True)
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("PHC_CACHE_DIR", str(world / ("cache-of-cache" if command == "cache" else "cache")))
    monkeypatch.setenv("PHC_STATE_DIR", str(world / "cache" / "state"))
    argv = _argv(command, *_baseline(command, world))
    code, out, err = _run(argv, capsys)
    _check(argv, code, out, err)
    assert code == 0, f"{argv}: exit {code}\n{err}"
    written = {"compile": "gen", "simulate": "r.csv", "animate": "a.gif", "bench": "bench/bench.csv",
               "sweep": "s.csv", "linearize": "l.json", "export": "m.fmu", "graph": "g.dot",
               "schema": "schemas/model.schema.json"}
    if command in written:
        assert (cwd / written[command]).exists(), f"{argv}: wrote no {written[command]}"


def test_companions_name_options_of_the_parser():
    parsers = _subparsers(build_parser())
    for (command, option), companions in COMPANIONS.items():
        names = {_name(a) for a in _fuzzed_actions(parsers[command])}
        assert option in names and all(set(c) <= names for c in companions), (command, option)


def test_every_option_is_fuzzed():
    """The default run covers every option of every subcommand (and every value of the
    flags), and the full run every hostile value."""
    default = {(c, o) for c, o, _ in _default_cases()}
    full = _cases()
    assert default == {(c, o) for c, o, _ in full}
    assert {c for c, _ in default} == set(_subparsers(build_parser()))
    sub = _subparsers(build_parser())["simulate"]
    assert {"--t-end", "--out", "--quiet", "file"} <= {_name(a) for a in _fuzzed_actions(sub)}


@pytest.mark.parametrize("case", FOUND, ids=_id)
def test_found_case(case, world, tmp_path, monkeypatch, capsys):
    _fuzz(*case, world, tmp_path, monkeypatch, capsys)


def test_schema_check_of_an_unreadable_folder_is_a_usage_error(tmp_path, monkeypatch, capsys):
    """`phc schema --check --dir` of a name too long to open: one usage line, exit 2 (it
    was an internal error)."""
    monkeypatch.chdir(tmp_path)
    argv = ["schema", "--check", "--dir", "y" * 5000]
    code, out, err = _run(argv, capsys)
    _check(argv, code, out, err)
    assert code == 2 and err.startswith("phc schema: error: --dir `yyy"), err


def test_sweep_plot_options_need_plot(world, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    argv = ["sweep", str(world / "models" / "msd.yaml"), "--param", "k=3,4", "--out", "s.csv", "--plot-output", "x.max"]
    code, out, err = _run(argv, capsys)
    _check(argv, code, out, err)
    assert code == 2 and "--plot-output needs --plot" in err, err
    assert not (tmp_path / "s.csv").exists()  # refused before the work


@pytest.mark.parametrize("case", _default_cases(), ids=_id)
def test_hostile_option_value(case, world, tmp_path, monkeypatch, capsys):
    _fuzz(*case, world, tmp_path, monkeypatch, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(set(_cases()) - set(_default_cases())), ids=_id)
def test_hostile_option_value_everywhere(case, world, tmp_path, monkeypatch, capsys):
    _fuzz(*case, world, tmp_path, monkeypatch, capsys)


def test_every_environment_variable_is_fuzzed():
    names = _environment_variables()
    assert {"PHC_MAX_MEMORY", "PHC_CACHE_MAX_MB", "PHC_CACHE_DIR", "PHC_STATE_DIR", "PHC_ALLOW_PATH",
            "PHC_BACKEND", "PHC_FRONT_END_CACHE"} <= set(names)
    assert {n for _, n, _ in _default_env_cases()} == set(names)


@pytest.mark.parametrize("case", _default_env_cases(), ids=lambda c: "env " + _id(c))
def test_hostile_environment_variable(case, world, tmp_path, monkeypatch, capsys):
    _fuzz_environment(*case, world, tmp_path, monkeypatch, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(set(_env_cases()) - set(_default_env_cases())),
                         ids=lambda c: "env " + _id(c))
def test_hostile_environment_variable_everywhere(case, world, tmp_path, monkeypatch, capsys):
    _fuzz_environment(*case, world, tmp_path, monkeypatch, capsys)
