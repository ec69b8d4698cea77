"""Run the examples of the documentation: every code block of README.md and docs/**/*.md.

``tests/test_docs.py`` collects one test per block; ``python tools/doc_examples.py
--update [FILE ...]`` reruns the commands of the ``console`` blocks and writes their
real output into the Markdown -- always, also where the output shown is still within the
block's tolerance -- so no output in the docs is typed by hand or left from an older phc.

What each block must do, by its language:

``yaml``
    A model (top-level ``components``) is validated by phc and must be free of errors; a
    scene (top-level ``model``) is validated with the model it names; any other YAML must
    parse, and its top-level keys that belong to a model file (``simulation``,
    ``parameters``, ...) are validated against the model language's pydantic types.
``python``
    Executed. The blocks of one page share one namespace, in order.
``console``
    Lines ``$ COMMAND`` are run; the lines after each, up to the next ``$``, are its
    expected output (stdout and stderr), compared line by line: the text exactly, the
    numbers as the block's ``numbers=`` declares (below; exactly by default), durations
    never. A line ``...`` matches any number of lines.
``sh``, ``bash``
    Command lines (no output shown), checked, not run: a ``phc`` line must parse with
    phc's own argument parser and the model and scene files it names must validate;
    ``pip install`` must name this project (``.``, its extras, or its distribution name);
    test paths of ``pytest`` and scripts of ``python`` must exist.
``toml``, ``json``
    Must parse.
``text``
    Pictures and formulas: not code, not run.

A block may be preceded (on the line right above its fence) by a directive
``<!-- test: KEY[=VALUE] ... -->``:

``file=PATH``
    Write the block to PATH in the page's working directory (models for later commands).
``expect=CODE[,CODE...]``
    The YAML must fail validation with exactly these codes (diagnostics pages).
``exit=N``
    Console: the expected exit status of the commands (default 0).
``numbers=SPEC``
    Console: how far the numbers shown may move from a fresh run (see *Numbers* below).
``slow``
    Run only with ``-m slow``.
``parse-only``
    YAML: only parse it.
``raw``
    YAML that is broken on purpose: only write it (with ``file=``).
``placeholders``
    sh: the block names files of the reader's own project (``models/my_model.yaml``);
    files that do not exist here are not checked.

Numbers
-------
``--update`` always rewrites a console block from a fresh run, so the figures shown are
what the current code prints. The test compares them with the tolerance the block
declares; it fails when a shown number differs from a fresh run by more.

*Durations are never compared*: a number of seconds (``s``, ``ms`` or ``µs``) followed by
`` CPU``, `` wall``, ``)`` or ``;`` -- phc's ``0.026 s CPU``, the certificate's ``; 0.08
s)``, a compilation's ``(10.44 s)``, a sweep's ``in 265.1 s;`` -- is masked before the
comparison, in every block.

*Every other number* is a figure: a decimal or e-notation number standing alone (not
part of a word: the ``406`` of ``PHC-E406``, the ``1`` of ``q1`` are text; an imaginary
unit ``i`` may follow it). Without ``numbers=`` a figure must be shown exactly as phc
prints it. ``numbers=SPEC`` loosens that; SPEC is a comma-separated list of items, later
ones overriding earlier ones:

``rel:R``
    a figure may differ from the fresh one by R relative to the larger of the two
    (``rel:0.5``: 600 matches 300 ... 1200);
``sci:F``
    a figure written in e-notation (``2.405e-09``: phc's error, balance, drift and
    residual figures) may be up to a factor F off, with the same sign (without ``sci:``,
    ``rel:`` or exactness applies to them too);
``floor:A``
    two figures both at most A in magnitude match (round-off: ``0.0e+00`` against
    ``4.4e-16``);
a preset name
    one of ``PRESETS``, each a tolerance with its reason:

    ``solver`` = ``rel:0.5,sci:20,floor:1e-13``
        The work and error figures of a simulation: an adaptive solver's steps and
        residual and Jacobian evaluations, a fixed-step solver's Newton iterations (they
        stop at a 1e-14 tolerance, i.e. on round-off), the energy balance, drift and error
        estimates -- counts within a factor 2, error figures within a factor 20. Round-off
        differs between x86-64 CPUs (the kernels OpenBLAS picks, NumPy's SIMD paths, the
        machine code numba emits), and IDA's step-size controller turns a last-bit
        difference into another step sequence. Measured by running every page with the
        CPU features switched down (``NPY_DISABLE_CPU_FEATURES``, ``OPENBLAS_CORETYPE``
        Haswell and Nehalem, ``NUMBA_CPU_NAME``): steps moved by up to 22 % (685 -> 882,
        docs/how-to/initial-values.md), Jacobian evaluations by 34 % (57 -> 86,
        docs/tutorials/electrical.md), error figures by up to a factor 5 (the pendulum's
        balance error). The window is about twice that and still catches a stale page
        (the counts that went stale here were off by 2-3x, the error figures by 10-300x).
    ``roundoff`` = ``sci:100,floor:1e-13``
        ``phc check``: the isotropy and power-balance figures are round-off (1e-16 ...
        1e-10; with the CPU features switched down they moved by up to a factor 2.4, and
        another CPU can give 0); the rest (dimensions, ranks, sampled values printed to
        three digits) exactly.
    ``digits`` = ``rel:1e-5,floor:1e-12``
        Results printed to six significant digits (eigenvalues): the last digit may flip
        on another CPU; a zero may come out as round-off.

Choose the tightest preset that covers what varies, and say why in a comment beside the
block when none fits. Structural numbers (states, equations, file positions) need no
``numbers=`` at all.

Every page runs in its own temporary working directory that holds a copy of the
repository's ``models`` and links to its ``schemas``, ``benchmarks``, ``tests`` and
``docs``, so commands read the shipped files under their usual names and write their
outputs there (``file=`` never writes through a link into the repository).
Snippet lines ``--8<-- "PATH"`` (pymdownx.snippets, as MkDocs renders them) are expanded
from the repository root before a block is used.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COPIED = ("models",)
"""Copied into each page's working directory: examples may add files next to the shipped ones."""
LINKED = ("schemas", "benchmarks", "tests", "docs")
"""Linked (read-only use) into each page's working directory."""
FENCE = re.compile(r"^(?P<indent> {0,4})(?P<fence>```+|~~~+)\s*(?P<lang>[\w+-]*)(?P<rest>[^\n]*)$")
DIRECTIVE = re.compile(r"^\s*<!--\s*test:\s*(?P<body>.*?)\s*-->\s*$")
SNIPPET = re.compile(r'^\s*--8<--\s+"(?P<path>[^"]+)"\s*$')
FIGURE = re.compile(r"(?<![\w.])((?>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?))(?!(?!i\b)\w)")
"""A number standing alone (not inside a word; an imaginary unit `i` may follow): compared
with the block's tolerance. Capturing, so that ``FIGURE.split`` alternates text and figures."""
DURATION = re.compile(r"(?<![\w.])\d+(?:\.\d+)?(?= ?(?:s|ms|µs)(?: CPU| wall|\)|;))")
"""A number of seconds followed by ` CPU`, ` wall`, `)` or `;`: a duration, never compared."""
PRESETS = {
    "solver": "rel:0.5,sci:20,floor:1e-13",
    "roundoff": "sci:100,floor:1e-13",
    "digits": "rel:1e-5,floor:1e-12",
}
"""Named tolerances of ``numbers=`` (their reasons: the module docstring)."""
PROGRESS = re.compile(r"^\S.* \[[# ]+\] +\d+(\.\d+)?%")
"""A progress-bar line (shown when a run takes more than a few seconds): not compared."""
NOT_CODE = {"text", "", "dot", "mermaid"}
DATA = {"csv"}
"""Data files for later blocks (with ``file=``): written, not checked."""
KNOWN = {"yaml", "python", "console", "sh", "bash", "toml", "json"} | NOT_CODE | DATA



def _pytest_markers() -> set[str]:
    """The markers pyproject.toml registers for pytest."""
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    block = re.search(r"^markers = \[(.*?)^\]", text, re.M | re.S)
    return set(re.findall(r'"(\w+):', block.group(1))) if block else set()

def doc_files() -> list[Path]:
    """README.md and every Markdown page of docs/."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


@dataclass
class Block:
    path: Path
    line: int  # 1-based line of the opening fence
    lang: str
    text: str  # the block's content with snippets expanded
    raw_lines: list[str]  # the content as written
    options: dict[str, str] = field(default_factory=dict)

    @property
    def where(self) -> str:
        path = self.path.relative_to(ROOT) if self.path.is_relative_to(ROOT) else self.path
        return f"{path}:{self.line}"

    @property
    def snippet_source(self) -> str | None:
        """The file a block includes when it is nothing but one snippet line."""
        lines = [line for line in self.raw_lines if line.strip()]
        m = SNIPPET.match(lines[0]) if len(lines) == 1 else None
        return m.group("path") if m else None

    @property
    def runs(self) -> bool:
        return self.lang not in NOT_CODE


def expand_snippets(lines: list[str]) -> str:
    out = []
    for line in lines:
        m = SNIPPET.match(line)
        if m:
            out.append((ROOT / m.group("path")).read_text(encoding="utf-8").rstrip("\n"))
        else:
            out.append(line)
    return "\n".join(out) + "\n"


def parse_blocks(path: Path) -> list[Block]:
    """The fenced code blocks of one Markdown file, with their directives."""
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, indent = m.group("fence"), m.group("indent")
        start, body = i, []
        i += 1
        while i < len(lines):
            stripped = lines[i].strip()
            if stripped and set(stripped) == {fence[0]} and len(stripped) >= len(fence):
                break  # the closing fence
            body.append(lines[i][len(indent):] if lines[i].startswith(indent) else lines[i])
            i += 1
        options = {}
        if start > 0:
            d = DIRECTIVE.match(lines[start - 1])
            if d:
                for item in shlex.split(d.group("body")):
                    key, _, value = item.partition("=")
                    options[key] = value
        blocks.append(Block(path, start + 1, m.group("lang").lower(), expand_snippets(body), body, options))
        i += 1
    return blocks


# ---------------------------------------------------------------------------------------
# the working directory of a page


class Page:
    """Working directory and Python namespace shared by the blocks of one page."""

    def __init__(self, path: Path):
        self.path = path
        self._tmp = tempfile.TemporaryDirectory(prefix="phc-docs-")
        self.dir = Path(self._tmp.name)
        for name in COPIED:
            shutil.copytree(ROOT / name, self.dir / name)
        for name in LINKED:
            (self.dir / name).symlink_to(ROOT / name, target_is_directory=True)
        self.namespace: dict = {"__name__": "__docs__"}
        self.done: set[int] = set()

    def target(self, relative: str, block: "Block") -> Path:
        """Where a block's `file=` goes: inside the page's directory, never through a link
        into the repository."""
        path = (self.dir / relative).resolve()
        if not path.is_relative_to(self.dir.resolve()):
            raise ExampleFailure(f"{block.where}: `file={relative}` would write outside the example's directory")
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def close(self) -> None:
        self._tmp.cleanup()


class ExampleFailure(AssertionError):
    pass


def _env() -> dict:
    env = dict(os.environ)
    env.update({"COLUMNS": "100", "PYTHONHASHSEED": "0", "NO_COLOR": "1"})
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def run_command(command: str, cwd: Path, timeout: float = 600) -> tuple[int, str]:
    """Run one command line of a docs block; (exit status, stdout and stderr).

    ``phc ...`` runs in this process (``phc.cli.main`` with the output captured): the
    same code as the command, without an interpreter start per example. ``python ...``
    runs in a subprocess."""
    argv = shlex.split(command)
    if argv[0] == "phc":
        return _run_phc(argv[1:], cwd)
    if argv[0] in ("python", "python3"):
        argv = [sys.executable, *argv[1:]]
    else:
        raise ExampleFailure(f"`{command}`: only `phc` and `python` commands are run in console blocks")
    proc = subprocess.run(argv, cwd=cwd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          timeout=timeout)
    return proc.returncode, _drop_progress(proc.stdout)


def _drop_progress(text: str) -> str:
    return "".join(line for line in text.splitlines(keepends=True) if not PROGRESS.match(line))


def _run_phc(args: list[str], cwd: Path) -> tuple[int, str]:
    import contextlib
    import io

    from phc.cli import main

    out = io.StringIO()
    old = Path.cwd()
    try:
        os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            try:
                status = main(args)
            except SystemExit as exc:  # argparse: usage errors, --help, --version
                status = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        os.chdir(old)
    return int(status or 0), _drop_progress(out.getvalue())


# ---------------------------------------------------------------------------------------
# checks by language


def _validate_yaml(block: Block, page: Page) -> None:
    import yaml

    if "raw" in block.options:  # a file that is broken on purpose (diagnostics examples)
        if "file" not in block.options:
            raise ExampleFailure(f"{block.where}: `raw` needs `file=`")
        page.target(block.options["file"], block).write_text(block.text, encoding="utf-8")
        return

    try:
        data = yaml.safe_load(block.text)
    except yaml.YAMLError as err:
        raise ExampleFailure(f"{block.where}: YAML does not parse: {err}") from None
    target = block.options.get("file")
    if target:
        page.target(target, block).write_text(block.text, encoding="utf-8")
    if "parse-only" in block.options:
        return
    expect = {c for c in block.options.get("expect", "").split(",") if c}
    if isinstance(data, dict) and ("components" in data or "model" in data):
        source = block.snippet_source
        if target:
            path = page.dir / target
        elif source:  # a shipped file shown as it is: validate it where it lies
            path = page.dir / source
        else:
            path = page.dir / ("scene.yaml" if "model" in data and "components" not in data else "model.yaml")
            path.write_text(block.text, encoding="utf-8")
        codes, text = _diagnostics(path, page.dir)
        if expect:
            if codes != expect:
                raise ExampleFailure(f"{block.where}: expected the diagnostics {sorted(expect)}, phc reports "
                                     f"{sorted(codes) or 'none'}:\n{text}")
        elif codes:
            raise ExampleFailure(f"{block.where}: the example does not validate:\n{text}")
        return
    if expect:
        raise ExampleFailure(f"{block.where}: `expect=` needs a model or scene")
    if isinstance(data, dict):
        _validate_fragment(block, data)


def _diagnostics(path: Path, cwd: Path) -> tuple[set[str], str]:
    """Error codes and text of `phc validate PATH` (run in-process; a scene with its model)."""
    import contextlib
    import io

    from phc.cli import main

    err = io.StringIO()
    old = Path.cwd()
    try:
        os.chdir(cwd)
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            main(["validate", str(path.relative_to(cwd))])
    finally:
        os.chdir(old)
    text = err.getvalue()
    codes = set(re.findall(r"\[(PHC-E\d{3})\]", text))
    return codes, text


def _validate_fragment(block: Block, data: dict) -> None:
    """Keys of a model file in a YAML fragment are checked against their pydantic types."""
    import pydantic

    from phc.spec.model import ModelSpec

    fields = ModelSpec.model_fields
    known = [key for key in data if key in fields]
    for key in known:
        try:
            pydantic.TypeAdapter(fields[key].annotation).validate_python(data[key])
        except pydantic.ValidationError as err:
            raise ExampleFailure(f"{block.where}: `{key}` is not valid in a model file:\n{err}") from None


def _run_python(block: Block, page: Page) -> None:
    target = block.options.get("file")
    if target:
        page.target(target, block).write_text(block.text, encoding="utf-8")
    old = Path.cwd()
    try:
        os.chdir(page.dir)
        code = compile(block.text, block.where, "exec")
        exec(code, page.namespace)  # noqa: S102 - the documentation's own examples, reviewed with it
    finally:
        os.chdir(old)


@dataclass(frozen=True)
class Tolerance:
    """How far a console block's figures may move (``numbers=``; the module docstring)."""

    rel: float | None = None  # relative, for every figure; None: exactly as shown
    sci: float | None = None  # a factor, for figures in e-notation; None: as `rel`
    floor: float = 0.0  # figures both at most this in magnitude match

    @classmethod
    def parse(cls, spec: str | None, where: str = "") -> "Tolerance":
        values: dict[str, float] = {}
        for item in (spec or "").split(","):
            item = item.strip()
            if not item:
                continue
            if item in PRESETS:
                values.update(cls.parse(PRESETS[item], where).__dict__)
                continue
            key, sep, value = item.partition(":")
            if key not in ("rel", "sci", "floor") or not sep:
                raise ExampleFailure(f"{where}: `numbers={spec}`: unknown item `{item}` (rel:R, sci:F, floor:A or "
                                     f"one of {sorted(PRESETS)})")
            try:
                values[key] = float(value)
            except ValueError:
                raise ExampleFailure(f"{where}: `numbers={spec}`: `{item}` needs a number") from None
            if values[key] < 0 or (key == "sci" and values[key] < 1):
                raise ExampleFailure(f"{where}: `numbers={spec}`: `{item}` out of range")
        return cls(**values)

    def close(self, shown: str, fresh: str) -> bool:
        """Whether the figure `shown` in the docs is close enough to the `fresh` one."""
        if shown == fresh:
            return True
        x, y = float(shown), float(fresh)
        if max(abs(x), abs(y)) <= self.floor:
            return True
        if self.sci is not None and ("e" in shown.lower() or "e" in fresh.lower()):
            return x * y > 0 and max(abs(x), abs(y)) <= self.sci * min(abs(x), abs(y))
        if self.rel is not None:
            return abs(x - y) <= self.rel * max(abs(x), abs(y))
        return False

    def __str__(self) -> str:
        items = [f"{k}:{v:g}" for k, v in (("rel", self.rel), ("sci", self.sci), ("floor", self.floor)) if v]
        return ",".join(items) or "exact"


def block_tolerance(block: "Block") -> Tolerance:
    if "numbers-vary" in block.options:
        raise ExampleFailure(f"{block.where}: `numbers-vary` masked every number and is gone: declare how far "
                             f"the numbers may move, `numbers=SPEC` (tools/doc_examples.py)")
    return Tolerance.parse(block.options.get("numbers"), block.where)


def _split(line: str) -> list[str]:
    """Text and figures of a line, alternating (text first), durations masked."""
    return FIGURE.split(DURATION.sub("#", line))


def same_line(shown: str, fresh: str, tolerance: Tolerance) -> bool:
    """One line of the docs against one line of a fresh run: the same text, the figures
    within the tolerance, durations not compared."""
    if shown == fresh:
        return True
    a, b = _split(shown), _split(fresh)
    if len(a) != len(b) or a[0::2] != b[0::2]:
        return False
    return all(tolerance.close(x, y) for x, y in zip(a[1::2], b[1::2]))


def moved_figures(shown: str, fresh: str, tolerance: Tolerance) -> list[tuple[str, str]]:
    """The figures of a line that moved beyond the tolerance (the text being the same)."""
    a, b = _split(shown), _split(fresh)
    if len(a) != len(b) or a[0::2] != b[0::2]:
        return []
    return [(x, y) for x, y in zip(a[1::2], b[1::2]) if not tolerance.close(x, y)]


def _matches(expected: list[str], actual: list[str], tolerance: Tolerance | None = None) -> bool:
    """Line match where a line `...` stands for any number of lines."""
    tolerance = tolerance or Tolerance()
    if not expected:
        return not actual
    if expected[0] == "...":
        return any(_matches(expected[1:], actual[k:], tolerance) for k in range(len(actual) + 1))
    return bool(actual) and same_line(expected[0], actual[0], tolerance) and _matches(expected[1:], actual[1:],
                                                                                      tolerance)


def _moved(expected: list[str], actual: list[str], tolerance: Tolerance) -> list[str]:
    """Notes on figures beyond the tolerance, line by line (where the lines line up)."""
    notes = []
    for shown, fresh in zip(expected, actual):
        if shown == "...":
            break
        for x, y in moved_figures(shown, fresh, tolerance):
            notes.append(f"{x} -> {y}")
    return notes


def console_commands(block: Block) -> list[tuple[str, list[str], int]]:
    """(command, expected output lines, index of the command line in the block)."""
    out = []
    for k, line in enumerate(block.text.rstrip("\n").split("\n")):
        if line.startswith("$ "):
            out.append((line[2:], [], k))
        elif out:
            out[-1][1].append(line.rstrip())
        elif line.strip():
            raise ExampleFailure(f"{block.where}: a console block starts with `$ COMMAND`")
    for _, expected, _ in out:
        while expected and not expected[-1]:
            expected.pop()
    return out


def _run_console(block: Block, page: Page) -> None:
    want_exit = int(block.options.get("exit", "0"))
    tolerance = block_tolerance(block)
    for command, expected, _ in console_commands(block):
        status, output = run_command(command, page.dir)
        actual = [line.rstrip() for line in output.rstrip("\n").split("\n")] if output.strip() else []
        if status != want_exit:
            raise ExampleFailure(f"{block.where}: `{command}` exited with {status}, expected {want_exit}:\n{output}")
        if not _matches(expected, actual, tolerance):
            moved = _moved(expected, actual, tolerance)
            note = (f"; figures beyond the block's tolerance ({tolerance}): {', '.join(moved)}" if moved else "")
            raise ExampleFailure(f"{block.where}: the output of `{command}` differs from the docs{note} "
                                 f"(rerun `python tools/doc_examples.py --update {block.where.rsplit(':', 1)[0]}`):\n"
                                 + "\n".join(["--- docs", *expected, "--- phc", *actual]))


def _extras() -> set[str]:
    data = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    return set(data["project"].get("optional-dependencies", {}))


def _distribution() -> str:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["name"]


def _check_pip(block: Block, words: list[str]) -> None:
    if "install" not in words:
        raise ExampleFailure(f"{block.where}: unexpected pip command `{' '.join(words)}`")
    targets = [w for w in words[words.index("install") + 1:] if not w.startswith("-")]
    for target in targets:
        if target.startswith(("./", "/", "../")):
            continue  # a checkout of this project, by path
        m = re.fullmatch(r"(?P<name>[.\w-]+)(?:\[(?P<extras>[\w,]+)\])?", target)
        if not m:
            raise ExampleFailure(f"{block.where}: cannot read the pip target `{target}`")
        name, extras = m.group("name"), (m.group("extras") or "").split(",")
        if name not in (".", _distribution()):
            raise ExampleFailure(f"{block.where}: `pip install {target}` does not install this project "
                                 f"(its distribution is `{_distribution()}`)")
        unknown = [e for e in extras if e and e not in _extras()]
        if unknown:
            raise ExampleFailure(f"{block.where}: unknown extra {unknown} (pyproject.toml has {sorted(_extras())})")


def _check_phc_command(block: Block, page: Page, args: list[str]) -> None:
    """A `phc` line of a sh block: its options must parse, and the model and scene files it
    names must exist and validate (it is not run: sh blocks show no output)."""
    import argparse
    import contextlib
    import io

    from phc.cli import build_parser

    parser = build_parser()
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            parsed = parser.parse_args(args)
    except SystemExit:
        raise ExampleFailure(f"{block.where}: `phc {shlex.join(args)}`: {err.getvalue().strip()}") from None
    files = []
    for value in vars(parsed).values():
        for item in value if isinstance(value, list) else [value]:
            if isinstance(item, str) and item.endswith((".yaml", ".yml")) and "*" not in item:
                files.append(item)
    for name in files:
        path = page.dir / name
        if not path.is_file():
            if name in args[args.index(name) - 1:args.index(name)]:
                continue
            raise ExampleFailure(f"{block.where}: `phc {shlex.join(args)}`: no such file `{name}`")
        codes, text = _diagnostics(path, page.dir)
        if codes and "exit" not in block.options:
            raise ExampleFailure(f"{block.where}: `phc {shlex.join(args)}`: `{name}` does not validate:\n{text}")
    del argparse


def _run_shell(block: Block, page: Page) -> None:
    text = block.text.replace("\\\n", " ")
    for line in text.splitlines():
        line = line.split(" #", 1)[0].strip() if not line.lstrip().startswith("#") else ""
        if not line:
            continue
        for command in (c.strip() for c in line.split("&&")):
            words = shlex.split(command)
            while words and re.fullmatch(r"[A-Z_][A-Z0-9_]*=\S*", words[0]):
                words = words[1:]  # VAR=value before a command
            program = words[0]
            if program in ("python", "python3") and words[1:3] == ["-m", "pip"]:
                _check_pip(block, words[3:])
            elif program == "pip":
                _check_pip(block, words[1:])
            elif program in ("python", "python3") and words[1:3] == ["-m", "pytest"] or program == "pytest":
                args = words[3 if program != "pytest" else 1:]
                for before, arg in zip([None] + args, args):
                    if before == "-m":  # a marker expression: its markers must be registered
                        unknown = set(re.findall(r"\w+", arg)) - {"not", "and", "or"} - _pytest_markers()
                        if unknown:
                            raise ExampleFailure(f"{block.where}: `{command}`: no marker `{sorted(unknown)[0]}` "
                                                 "in pyproject.toml")
                    elif not arg.startswith("-") and not (ROOT / arg.split("::")[0]).exists() and "=" not in arg:
                        raise ExampleFailure(f"{block.where}: `{command}`: no such test path `{arg}`")
            elif program == "mkdocs":
                if not (ROOT / "mkdocs.yml").is_file():
                    raise ExampleFailure(f"{block.where}: `{command}` needs mkdocs.yml")
            elif program in ("pre-commit", "git", "cd", "export", "timeout"):
                continue
            elif program == "phc" or (program in ("python", "python3") and words[1:3] == ["-m", "phc"]):
                _check_phc_command(block, page, words[1:] if program == "phc" else words[3:])
            elif program in ("python", "python3") and len(words) > 1 and words[1].endswith(".py"):
                if not (ROOT / words[1]).is_file():
                    raise ExampleFailure(f"{block.where}: `{command}`: no such script `{words[1]}`")
            else:
                raise ExampleFailure(f"{block.where}: `{command}`: the docs test does not know `{program}`")


def run_block(block: Block, page: Page) -> None:
    if block.lang not in KNOWN:
        raise ExampleFailure(f"{block.where}: code block in `{block.lang}`, which the docs test cannot check; "
                             f"use one of {sorted(KNOWN - {''})}")
    if block.lang == "yaml":
        _validate_yaml(block, page)
    elif block.lang == "python":
        _run_python(block, page)
    elif block.lang == "console":
        _run_console(block, page)
    elif block.lang in ("sh", "bash"):
        _run_shell(block, page)
    elif block.lang == "toml":
        tomllib.loads(block.text)
    elif block.lang == "json":
        json.loads(block.text)
    elif block.lang in DATA:
        if "file" not in block.options:
            raise ExampleFailure(f"{block.where}: a `{block.lang}` block needs `file=` (it is data for later blocks)")
        page.target(block.options["file"], block).write_text(block.text, encoding="utf-8")


# ---------------------------------------------------------------------------------------
# --update: write the real outputs into the console blocks


def _skeleton(line: str) -> list[str]:
    """The text of a line without its figures and durations."""
    return _split(line)[0::2]


def _elide(expected: list[str], actual: list[str], where: str = "") -> list[str]:
    """The fresh output `actual` with the elisions (`...`) of the block kept: the lines
    shown before the first `...` and after the last are the first and last lines of the
    output, a run of lines between two `...` is found again by its text (its figures may
    have changed)."""
    if "..." not in expected:
        return actual
    segments, current = [], []
    for line in expected:
        if line == "...":
            segments.append(current)
            current = []
        else:
            current.append(line)
    segments.append(current)
    head, *middle, tail = segments
    out, pos = list(actual[:len(head)]), len(head)
    end = max(pos, len(actual) - len(tail))
    for segment in middle:
        if out[-1:] != ["..."]:
            out.append("...")
        found = next((k for k in range(pos, end - len(segment) + 1)
                      if all(_skeleton(a) == _skeleton(b) for a, b in zip(segment, actual[k:k + len(segment)]))),
                     None)
        if found is None:
            if segment:
                print(f"warning: {where}: the lines {segment[:1]}... shown between two `...` are no longer in "
                      f"the output; left out", file=sys.stderr)
            continue
        out += actual[found:found + len(segment)]
        pos = found + len(segment)
    if out[-1:] != ["..."]:
        out.append("...")
    return out + actual[max(pos, len(actual) - len(tail)):]


def update_file(path: Path, slow: bool = True) -> int:
    """Rerun the console blocks of one file and write their outputs; returns the count
    of blocks changed."""
    blocks = parse_blocks(path)
    lines = path.read_text(encoding="utf-8").split("\n")
    page = Page(path)
    changed = 0
    try:
        edits = []
        for block in blocks:
            if not block.runs or ("slow" in block.options and not slow):
                continue
            if block.lang != "console":
                try:
                    run_block(block, page)
                except ExampleFailure as err:
                    print(f"warning: {err}", file=sys.stderr)
                continue
            new_body = []
            tolerance = block_tolerance(block)
            want_exit = int(block.options.get("exit", "0"))
            for command, expected, _ in console_commands(block):
                status, output = run_command(command, page.dir)
                actual = [line.rstrip() for line in output.rstrip("\n").split("\n")] if output.strip() else []
                if status != want_exit:
                    print(f"warning: {block.where}: `{command}` exited with {status}, expected {want_exit}",
                          file=sys.stderr)
                if not _matches(expected, actual, tolerance):
                    moved = _moved(expected, actual, tolerance)
                    print(f"note: {block.where}: `{command}`: the output changed"
                          + (f"; beyond the block's tolerance ({tolerance}): {', '.join(moved)}" if moved else ""),
                          file=sys.stderr)
                # always the fresh output: the figures shown are what the current code prints
                new_body += [f"$ {command}", *_elide(expected, actual, block.where), ""]
            while new_body and not new_body[-1]:
                new_body.pop()
            if new_body != [line.rstrip() for line in block.raw_lines]:
                edits.append((block.line, len(block.raw_lines), new_body))
        for start, count, body in reversed(edits):
            lines[start:start + count] = body
            changed += 1
    finally:
        page.close()
    if changed:
        path.write_text("\n".join(lines), encoding="utf-8")
    return changed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--update", action="store_true", help="write the real outputs into the console blocks")
    parser.add_argument("--no-slow", action="store_true", help="leave the blocks marked slow alone")
    parser.add_argument("files", nargs="*", help="Markdown files (default: README.md and docs/)")
    args = parser.parse_args(argv)
    files = [Path(f).resolve() for f in args.files] or doc_files()
    failures = 0
    for path in files:
        if args.update:
            n = update_file(path, slow=not args.no_slow)
            print(f"{path.relative_to(ROOT)}: {n} block(s) updated")
            continue
        page = Page(path)
        try:
            for block in parse_blocks(path):
                if not block.runs or ("slow" in block.options and args.no_slow):
                    continue
                try:
                    run_block(block, page)
                except ExampleFailure as err:
                    failures += 1
                    print(err, file=sys.stderr)
        finally:
            page.close()
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
