"""Faults without data loss, and bad command-line values.

* every numeric option is checked before any work (a one-line usage error, exit 2);
* every output path is checked before the run (a wrong ``--out`` costs nothing);
* result files are written atomically (a killed writer leaves the old file or none);
* a model expression leaving its domain during a run (sqrt/log/asin, exp overflow) stops
  the run cleanly, names the expression, its place in the model file and the time, and
  keeps the results so far (exit 1, never "internal error");
* Ctrl-C keeps the results computed so far (exit 130); SIGKILL leaves no truncated file.

The SIGINT/SIGKILL tests run ``phc simulate`` in a subprocess for a few seconds each.
"""

from __future__ import annotations

import csv
import inspect
import math
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.cli import main
from phc.errors import SimulationSetupError
from phc.io import TEMP_SUFFIX, atomic_write, check_output_dir, check_output_file, write_text, OutputPathError
from phc.simulation import ModelEvaluationError, N_OUT_LIMITS, SimulationInterrupted
from time_limits import SUBPROCESS_TIMEOUT

# Runs here skip the compile-time certificate where phc has one (it is not what is tested).
NO_CERT = {"certify": False} if "certify" in inspect.signature(phc.compile_model).parameters else {}
NO_CERTIFY = ["--no-certify"] if NO_CERT else []

REPO = Path(__file__).resolve().parents[1]
MODELS = REPO / "models"
MSD = str(MODELS / "mass_spring_damper.yaml")
CRANK = str(MODELS / "flexible_slider_crank.yaml")


def _rows(path):
    """The CSV's rows by column name without its unit (`t [s]` is `t`: docs/units.md)."""
    with open(path, newline="") as fh:
        return [{key.split(" [")[0]: value for key, value in row.items()} for row in csv.DictReader(fh)]


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "internal error" not in err and "Traceback" not in err
    return lines[0]


# -- numeric options ----------------------------------------------------------------------

def _model_reads(monkeypatch) -> list:
    """Every opening of the model file MSD from now on (os.open, which phc's file access and
    its front-end cache use, and open): a command refused before compiling anything has
    not even read its model (counted, not timed)."""
    import builtins
    import io

    model, reads = os.path.realpath(MSD), []

    def recording(real):
        def opening(path, *args, **kwargs):
            if isinstance(path, (str, bytes, os.PathLike)) and os.path.realpath(os.fsdecode(path)) == model:
                reads.append(real.__name__)
            return real(path, *args, **kwargs)
        return opening

    monkeypatch.setattr(os, "open", recording(os.open))
    monkeypatch.setattr(builtins, "open", recording(builtins.open))
    monkeypatch.setattr(io, "open", recording(io.open))
    return reads


@pytest.mark.parametrize("argv, option, value", [
    (["simulate", MSD, "--step", "nan", "--solver", "midpoint"], "--step", "nan"),
    (["simulate", MSD, "--step=-1e-3"], "--step", "-0.001"),
    (["simulate", MSD, "--step", "inf"], "--step", "inf"),
    (["simulate", MSD, "--n-out", "-5"], "--n-out", "-5"),
    (["simulate", MSD, "--n-out", "1"], "--n-out", "1"),
    (["simulate", MSD, "--n-out", "1000000000000"], "--n-out", "1000000000000"),
    (["simulate", MSD, "--t-end", "nan"], "--t-end", "nan"),
    (["simulate", MSD, "--t-end", "inf"], "--t-end", "inf"),
    (["simulate", MSD, "--t-end", "0"], "--t-end", "0"),
    (["simulate", MSD, "--rtol", "nan"], "--rtol", "nan"),
    (["simulate", MSD, "--rtol", "1"], "--rtol", "1"),
    (["simulate", MSD, "--atol", "nan"], "--atol", "nan"),
    (["simulate", MSD, "--atol", "inf"], "--atol", "inf"),
    (["simulate", MSD, "--param", "k=nan"], "--param k", "nan"),
    (["simulate", MSD, "--param", "k=-inf"], "--param k", "-inf"),
    (["animate", MSD, "-o", "x.gif", "--fps", "0"], "--fps", "0"),
    (["animate", MSD, "-o", "x.gif", "--frames", "-3"], "--frames", "-3"),
    (["animate", MSD, "-o", "x.gif", "--magnify", "nan"], "--magnify", "nan"),
    (["bench", MSD, "--tol", "nan"], "--tol", "nan"),
    (["bench", MSD, "--step", "0"], "--step", "0"),
    (["bench", MSD, "--repeats", "0"], "--repeats", "0"),
    (["bench", MSD, "--reference-rtol", "2"], "--reference-rtol", "2"),
    (["check", MSD, "--samples", "-1"], "--samples", "-1"),
])
def test_bad_numeric_option_is_a_one_line_usage_error(argv, option, value, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    reads = _model_reads(monkeypatch)
    assert main(argv) == 2
    captured = capsys.readouterr()
    line = one_error_line(captured.err)
    assert line.startswith(f"phc {argv[0]}: error: {option}"), line
    assert line.endswith(f"got {value}"), line
    assert captured.out == ""
    assert reads == []  # refused before compiling anything: the model was not even read
    assert not list(tmp_path.iterdir())


def test_n_out_limits_are_the_model_languages():
    from phc.spec.model import SimulationSpec

    field = SimulationSpec.model_fields["n_out"]
    bounds = {type(m).__name__: m for m in field.metadata}
    assert (bounds["Ge"].ge, bounds["Le"].le) == N_OUT_LIMITS
    from phc.cli import NUMERIC_OPTIONS

    assert NUMERIC_OPTIONS[("simulate", "n_out")][2:] == N_OUT_LIMITS


def test_parameter_that_makes_the_model_singular_is_named_without_warnings(capsys):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["simulate", MSD, *NO_CERTIFY, "--quiet", "--param", "m=0"]) == 2
    captured = capsys.readouterr()
    line = one_error_line(captured.err)
    # refused as the model file refuses `m: 0` (before, the run failed on `1/m`)
    assert "--param m=0: `m` of `mass` is 0; it must be positive" in line and "[PHC-E405]" in line, line
    assert "RuntimeWarning" not in captured.err
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]


def test_api_refuses_non_finite_and_oversized_options():
    compiled = phc.compile_model(MSD, **NO_CERT)
    for kwargs, word in [(dict(max_steps=10 ** 20), "max_steps"), (dict(max_steps=0), "max_steps"),
                         (dict(n_out=10 ** 12), "n_out"), (dict(step=float("nan"), solver="midpoint"), "step"),
                         (dict(t_end=float("inf")), "t_end"), (dict(atol=float("nan")), "atol"),
                         (dict(params={"k": float("nan")}), "k"), (dict(t_eval=[0.0, float("nan")]), "t_eval"),
                         (dict(initial={"spring.x": float("inf")}), "spring.x")]:
        with pytest.raises(SimulationSetupError, match=re.escape(word)):
            phc.simulate(compiled, **kwargs)


# -- output paths -------------------------------------------------------------------------

@pytest.mark.parametrize("argv, expected", [
    (["simulate", MSD, "--out", "nofolder/x.csv"], "the folder `nofolder` does not exist"),
    (["simulate", MSD, "--out", "adir.csv"], "is a folder"),
    (["simulate", MSD, "--out", "x.txt"], "must end in .csv or .npz"),
    (["simulate", MSD, "--plot", "nofolder/x.png"], "the folder `nofolder` does not exist"),
    (["simulate", MSD, "--plot", "x.gif"], "must end in .png or .pdf or .svg"),
    (["compile", MSD, "-o", "afile"], "is a file, not a folder"),
    (["compile", MSD, "-o", "afile/sub"], "`afile` is a file"),
    (["graph", MSD, "-o", "nofolder/g.dot"], "the folder `nofolder` does not exist"),
    (["graph", MSD, "-o", "adir.csv"], "must end in .dot or .png"),
    (["animate", MSD, "-o", "nofolder/a.gif"], "the folder `nofolder` does not exist"),
    (["animate", MSD, "-o", "a.png"], "must end in .gif"),
    (["bench", MSD, "--out-dir", "afile"], "is a file, not a folder"),
])
def test_output_path_is_checked_before_the_run(argv, expected, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "adir.csv").mkdir()
    (tmp_path / "afile").write_text("")
    reads = _model_reads(monkeypatch)
    assert main(argv) == 2
    captured = capsys.readouterr()
    line = one_error_line(captured.err)
    assert expected in line, line
    assert captured.out == ""  # nothing ran
    assert reads == []  # the model was not even read
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir.csv", "afile"]


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc (a folder nobody can create files in)")
def test_unwritable_folder_is_refused(capsys):
    assert main(["simulate", MSD, "--out", "/proc/phc-results.csv"]) == 2
    assert "cannot write into the folder `/proc`" in one_error_line(capsys.readouterr().err)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder_is_refused(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(OutputPathError, match="cannot write into the folder"):
            check_output_file(folder / "x.csv", "--out", (".csv",))
        with pytest.raises(OutputPathError, match="cannot write into the folder"):
            check_output_dir(folder / "new" / "deeper", "--out-dir")
    finally:
        folder.chmod(0o700)


def test_output_checks_create_nothing(tmp_path):
    assert check_output_dir(tmp_path / "a" / "b", "-o") == tmp_path / "a" / "b"
    assert check_output_file(tmp_path / "x.CSV", "--out", (".csv",)) == tmp_path / "x.CSV"
    assert list(tmp_path.iterdir()) == []


# -- atomic writing -----------------------------------------------------------------------

def test_atomic_write_replaces_only_on_success(tmp_path):
    target = tmp_path / "r.csv"
    target.write_text("old\n")
    target.chmod(0o640)
    with pytest.raises(RuntimeError):
        with atomic_write(target, "w") as fh:
            fh.write("half")
            raise RuntimeError("writer failed")
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["r.csv"]  # the temporary file is gone
    write_text(target, "new\n")
    assert target.read_text() == "new\n"
    assert target.stat().st_mode & 0o777 == 0o640  # the replaced file's permissions are kept
    fresh = write_text(tmp_path / "fresh.txt", "x")
    mask = os.umask(0)
    os.umask(mask)
    assert fresh.stat().st_mode & 0o777 == 0o666 & ~mask  # not mkstemp's 0600


KILLED_WRITER = textwrap.dedent("""
    import sys, time
    from phc.io import atomic_write
    with atomic_write(sys.argv[1], "w") as fh:
        fh.write("partial,row\\n" * 1000)
        fh.flush()
        print("writing", flush=True)
        time.sleep(60)
        fh.write("the rest\\n")
""")


def test_writer_killed_mid_file_leaves_the_old_file(tmp_path):
    target = tmp_path / "results.csv"
    target.write_text("t,x\n0,1\n")
    proc = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(target)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
        proc.stdout.close()
    assert target.read_text() == "t,x\n0,1\n"  # untouched
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "results.csv"]
    assert len(leftovers) == 1 and leftovers[0].startswith(".results.csv.") and leftovers[0].endswith(TEMP_SUFFIX)
    assert "partial,row" in (tmp_path / leftovers[0]).read_text()  # the killed write went there


# -- run-time domain errors ---------------------------------------------------------------

OSCILLATOR = """\
format_version: 1
name: oscillator
parameters:
  m: 1.0
  k: 4.0
components:
  mass: {type: mass, m: m}
  spring: {type: spring, k: k}
connections:
  - [mass.port, spring.port]
simulation:
  t_end: 2.0
  n_out: 101
  initial:
    spring.x: 0.5
    mass.p: 0.0
  outputs:
    x: spring.x
    r: EXPR
"""
# x(t) = 0.5 cos(2t): negative from t = π/4 on


def _write(tmp_path, text, name="model.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("solver", ["ida", "midpoint"])
@pytest.mark.parametrize("expr", ["sqrt(spring.x)", "log(spring.x)"])
def test_output_outside_its_domain_stops_with_its_name_line_and_time(tmp_path, solver, expr):
    text = OSCILLATOR.replace("EXPR", expr)
    path = _write(tmp_path, text)
    line = text.splitlines().index(f"    r: {expr}") + 1
    result = phc.simulate(phc.compile_model(path, **NO_CERT), solver=solver)
    assert not result.success
    assert f"output `r` ({path}:{line})" in result.message, result.message
    assert f"`{expr}`" in result.message and "outside its domain" in result.message
    failed_at = float(re.search(r"cannot be evaluated at t = ([0-9.e+-]+)", result.message).group(1))
    # kept: every output time before x turns negative, none after
    assert result.t[-1] <= math.pi / 4 < failed_at == pytest.approx(result.t[-1] + 0.02)
    assert np.all(result["r"] == result["r"])  # the kept values are numbers
    assert f"results up to t = {result.t[-1]:.6g} are kept" in result.message
    # and how many output times that is: a coarse output grid may keep only the start
    assert f"({len(result.t)} output time(s) kept, the last at t = {result.t[-1]:.6g})" in result.message


def test_output_failing_at_the_start_is_a_model_error(tmp_path, capsys):
    path = _write(tmp_path, OSCILLATOR.replace("EXPR", "acos(4*spring.x)"))
    assert main(["simulate", str(path), *NO_CERTIFY, "--quiet"]) == 1
    captured = capsys.readouterr()
    line = one_error_line(captured.err)
    assert "output `r`" in line and "t = 0:" in line and "`acos(4*spring.x)`" in line and "spring.x = 0.5" in line


STATE_MODEL = """\
format_version: 1
name: state_model
parameters:
  a: 1.0
components:
  s:
    type: phs
    states: [q]
    hamiltonian: HAMILTONIAN
    J: [[0]]
    R: [[0]]
    ports:
      u:
        domain: electrical
        causality: effort_in
        B: [[1]]
  src: {type: effort_source, domain: electrical, value: RATE}
connections:
  - [s.u, src.port]
simulation:
  t_end: 2.0
  n_out: 201
  initial:
    s.q: 0.0
"""
# q' = RATE: q(t) = RATE·t


@pytest.mark.parametrize("solver", ["ida", "midpoint", "discrete_gradient"])
@pytest.mark.parametrize("hamiltonian, rate, t_star, reason", [
    ("exp(a*q)", 1000, math.log(sys.float_info.max) / 1000, "overflow"),  # exp(q) overflows at q = 709.78
    ("q**2/2 + asin(q)", 1, 1.0, ""),  # d/dq asin(q) = 1/sqrt(1 − q²): not defined from q = 1 on
])
def test_state_expression_outside_its_domain_keeps_the_results_so_far(tmp_path, capsys, solver, hamiltonian, rate,
                                                                       t_star, reason):
    path = _write(tmp_path, STATE_MODEL.replace("HAMILTONIAN", hamiltonian).replace("RATE", str(rate)))
    out = tmp_path / "r.csv"
    code = main(["simulate", str(path), *NO_CERTIFY, "--quiet", "--solver", solver, "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 1, captured.err
    assert "internal error" not in captured.err and "Traceback" not in captured.err
    first = captured.out.splitlines()[0]
    assert first.startswith("state_model: FAILED — ") and "cannot be evaluated at t = " in first, first
    assert reason in first and "s.q = " in first
    rows = _rows(out)
    reached = float(rows[-1]["t"])
    assert len(rows) > 1 and reached <= t_star + 1e-12  # up to the time the model leaves its domain
    failed_at = float(re.search(r"cannot be evaluated at t = ([0-9.eE+-]+)", first).group(1))
    assert reached <= failed_at <= t_star + 1e-9  # the failure is where the model leaves its domain
    assert reached >= t_star - 0.03  # ... and not far before it (output interval 0.01)
    # IDA's steps may be long (q' = 1000 is integrated exactly by BDF of any order): a trial
    # step that overflows is a recoverable failure, retried shorter (it ended the run at
    # t = 0.35 when it was not), and the run stops where its steps creep up to the edge


def test_failing_row_is_found_through_common_subexpressions():
    """The failing operation is a shared `_c` line: the row that uses it is named."""
    compiled = phc.compile_model(MSD, **NO_CERT)
    from phc.simulation.guard import guard, quiet_floating_point

    assert re.search(r"^    (_c\d+) = 1/p_m$", compiled.source, re.M)  # 1/m is shared by two rows
    mod = guard(compiled.module, compiled.source)
    p = mod.full_parameters(np.array([0.0, 4.0, 0.4]))
    with pytest.raises(ModelEvaluationError) as info, quiet_floating_point():
        mod.residual(0.0, np.ones(mod.N), np.zeros(mod.N), p, np.zeros(mod.N))
    err = info.value
    assert err.function == "residual" and err.label in mod.EQUATIONS and err.parameters == {"m": 0.0}
    assert "1/m" in err.expression


# -- solver failures keep their results ----------------------------------------------------

@pytest.mark.parametrize("solver", ["ida", "midpoint"])
def test_failed_solver_writes_what_it_computed(tmp_path, capsys, solver):
    text = (MODELS / "mass_spring_damper.yaml").read_text().replace("  n_out: 501\n", "  n_out: 501\n  max_steps: 300\n")
    path = _write(tmp_path, text, "msd.yaml")
    out = tmp_path / "r.csv"
    assert main(["simulate", str(path), *NO_CERTIFY, "--quiet", "--solver", solver, "--out", str(out)]) == 1
    first = capsys.readouterr().out.splitlines()[0]
    reached = float(re.search(r"at t = ([0-9.e+-]+)", first).group(1))
    assert "FAILED" in first and "max_steps" in first and "raise `max_steps`" in first, first
    rows = _rows(out)
    assert 1 < len(rows) < 501 and float(rows[-1]["t"]) <= reached + 1e-12
    assert all(math.isfinite(float(v)) for v in rows[-1].values())


# -- Ctrl-C and SIGKILL ----------------------------------------------------------------------

def interruptible():
    """In the child before it starts: SIGINT at its default disposition and not blocked, as a
    terminal delivers Ctrl-C. A child inherits both from the test process, where other
    tests' libraries (thread pools, process pools) may have left SIGINT ignored or blocked;
    Python then never turns it into KeyboardInterrupt."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _phc(*args):
    return [sys.executable, "-m", "phc", *args]


@pytest.fixture(scope="module")
def warm_crank():
    """Compile the flexible slider–crank once (cached), so that a run starts integrating at once."""
    subprocess.run(_phc("simulate", CRANK, *NO_CERTIFY, "--quiet", "--t-end", "1e-4", "--n-out", "2"),
                   check=True, capture_output=True, timeout=300)


def _start_and_signal(out: Path, sig, solver: str, n_out: int = 2001):
    """Start a long run and send `sig` once it is integrating past its second output time:
    the progress line (printed on a non-terminal 2 s into the integration, then every 10 s)
    says how far it got. On a loaded machine the first line can come before the first
    output time is reached: then the next one is awaited."""
    proc = subprocess.Popen(_phc("simulate", CRANK, *NO_CERTIFY, "--solver", solver, "--t-end", "1",
                                 "--n-out", str(n_out), "--out", str(out)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=interruptible)
    before = []
    try:
        while True:
            line = proc.stderr.readline()
            before.append(line)
            reached = re.search(r" t = ([0-9.e+-]+) ", line)
            if not line or ("elapsed" in line and reached and float(reached.group(1)) >= 2.0 / (n_out - 1)):
                break
        assert line, f"the run ended before integrating: {''.join(before)}"
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=SUBPROCESS_TIMEOUT)
    finally:
        proc.kill()
    return proc.returncode, stdout, "".join(before) + stderr


@pytest.mark.parametrize("solver", ["midpoint", "ida"])
def test_ctrl_c_writes_the_partial_results_and_exits_130(tmp_path, warm_crank, solver):
    out = tmp_path / "x.csv"
    code, stdout, stderr = _start_and_signal(out, signal.SIGINT, solver)
    assert code == 130, stderr
    assert "Traceback" not in stderr and "internal error" not in stderr
    message = [line for line in stderr.splitlines() if line.startswith("phc simulate: interrupted at t = ")]
    assert message and str(out) in message[0], stderr
    reached = float(re.search(r"at t = ([0-9.e+-]+)", message[0]).group(1))
    assert "INTERRUPTED" in stdout.splitlines()[0]
    rows = _rows(out)
    times = [float(r["t"]) for r in rows]
    assert 0 < reached < 1 and len(rows) >= 2
    assert times[0] == 0.0 and times[-1] == pytest.approx(reached, rel=1e-5)
    assert np.all(np.diff(times) > 0) and all(math.isfinite(float(v)) for r in rows for v in r.values())
    assert [p.name for p in tmp_path.iterdir()] == ["x.csv"]


def test_sigkill_leaves_no_partial_file_at_the_target(tmp_path, warm_crank):
    out = tmp_path / "x.csv"
    out.write_text("t,x\n0,1\n")  # a previous result
    code, _, _ = _start_and_signal(out, signal.SIGKILL, "midpoint")
    assert code == -signal.SIGKILL
    assert out.read_text() == "t,x\n0,1\n"
    for leftover in tmp_path.iterdir():
        assert leftover.name == "x.csv" or (leftover.name.startswith(".x.csv.") and leftover.name.endswith(".part"))


def test_simulation_interrupted_carries_the_partial_result(monkeypatch):
    compiled = phc.compile_model(MSD, **NO_CERT)
    calls = {"n": 0}
    residual = compiled.module.residual

    def interrupting(*args):
        calls["n"] += 1
        if calls["n"] == 200:
            raise KeyboardInterrupt
        return residual(*args)

    monkeypatch.setattr(compiled.module, "residual", interrupting)
    with pytest.raises(SimulationInterrupted) as info:
        phc.simulate(compiled, solver="midpoint")
    result = info.value.result
    assert isinstance(info.value, KeyboardInterrupt)
    assert result.interrupted and not result.success and result.message.startswith("interrupted at t = ")
    assert 0 < result.t[-1] < 10 and len(result.t) == len(result.H) == len(result["x"])


def test_a_bug_in_generated_code_is_an_internal_error_not_a_domain_error():
    """The guard reports a model leaving an expression's domain as a located error; a
    TypeError of anything else (here: a generated function called with a wrong argument, as
    a code-generation bug would) is phc's own failure and must not be dressed up as the
    model's (issue 31: "a code-generation bug is reported as 'this expression leaves its
    domain'")."""
    from phc.simulation.guard import GuardedModule, ModelEvaluationError, is_domain_error

    import types

    compiled = phc.compile_model(MSD, **NO_CERT)
    mod = compiled.module

    def buggy_residual(t, y, yp, p, out):  # what a printer bug could generate
        out[:] = None + y[0]

    fake = types.SimpleNamespace(**{k: getattr(mod, k) for k in dir(mod) if not k.startswith("__")})
    fake.residual = buggy_residual
    guarded = GuardedModule(fake, compiled.source)
    y, p = np.zeros(mod.N), np.asarray(mod.PARAMETER_DEFAULTS, dtype=float)
    with pytest.raises(TypeError, match="NoneType") as info:
        guarded.residual(0.0, y, y, p, np.zeros(len(mod.EQUATIONS)))
    assert not isinstance(info.value, ModelEvaluationError)
    assert is_domain_error(OverflowError("math range error")) and is_domain_error(ValueError("math domain error"))
    assert is_domain_error(TypeError("can't convert complex to float"))
    assert not is_domain_error(TypeError("residual() missing 1 required positional argument: 'out'"))
    assert not is_domain_error(ValueError("operands could not be broadcast together with shapes (3,) (4,)"))


def test_ctrl_c_while_the_results_are_written_finishes_the_file(tmp_path, monkeypatch, capsys):
    """SIGINT arrives in the middle of writing `--out` (issue 32 item 3): the file is
    finished and complete, the message says where it is, and the exit code is 130."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    original = np.savetxt

    def interrupted_savetxt(fh, data, **kwargs):
        half = len(data) // 2
        original(fh, data[:half], **kwargs)
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C half way through the file
        original(fh, data[half:], **{k: v for k, v in kwargs.items() if k != "header"})

    monkeypatch.setattr(np, "savetxt", interrupted_savetxt)
    out = tmp_path / "r.csv"
    code = main(["simulate", str(MSD), "--n-out", "41", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 130
    assert "interrupted while writing the results" in err and str(out) in err
    rows = list(csv.reader(out.read_text().splitlines()))
    assert len(rows) == 1 + 41 and all(len(r) == len(rows[0]) for r in rows)
    assert float(rows[-1][0]) == pytest.approx(10.0)  # the run's end, MSD's t_end


def test_finish_before_interrupt_holds_the_signal_until_the_block_ends():
    from phc.io import finish_before_interrupt

    signal.signal(signal.SIGINT, signal.default_int_handler)
    done = []
    with pytest.raises(KeyboardInterrupt):
        with finish_before_interrupt() as held:
            os.kill(os.getpid(), signal.SIGINT)
            done.append("after the signal")
    assert done == ["after the signal"] and held == [signal.SIGINT]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
