"""`phc sweep` robustness: swept names that are result columns, a time-series file that is
a results file, a dead worker charged only to its own point, resuming (failed points again
on request; only results of the same model, values and phc version), workers that run
anywhere (they never read the model's files), and no worker left behind by SIGTERM or
SIGINT.

Physics is checked against the closed form of the damped oscillator (tests/test_sweep.py).
"""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import phc
from phc.cli import main
from phc.sweep import DaskExecutor, LocalExecutor, SweepSetupError, read_results, run_sweep
from phc.sweep import executors
from closed_forms import msd_x  # the free damped oscillator of models/mass_spring_damper.yaml
from time_limits import SUBPROCESS_TIMEOUT

REPO = Path(__file__).resolve().parents[1]
MSD = REPO / "models" / "mass_spring_damper.yaml"



def interruptible():
    """SIGINT and SIGTERM at their defaults and unblocked in the child (see
    tests/test_cli_faults.py)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


@pytest.fixture(scope="module")
def msd():
    return phc.compile_model(MSD)


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, lines
    assert "Traceback" not in err
    return lines[0]


# -- swept names and result files --------------------------------------------------------

STEPS_MODEL = MSD.read_text(encoding="utf-8").replace(
    "  k: {value: 4.0, unit: N/m, description: spring stiffness}",
    "  steps: {value: 4.0, unit: N/m, description: spring stiffness (named like a result column)}").replace(
    "spring: {type: spring, k: k}", "spring: {type: spring, k: steps}")


def test_a_swept_parameter_named_like_a_result_column_is_refused_where_it_is_written(tmp_path, capsys):
    """A parameter `steps` would be a second `steps` column (the solver's step count): on
    the command line it is refused at the parameter's line in the model file, in a scene at
    the sweep entry; nothing is written."""
    model = tmp_path / "steps.yaml"
    model.write_text(STEPS_MODEL, encoding="utf-8")
    line = next(i for i, text in enumerate(STEPS_MODEL.splitlines(), 1) if text.startswith("  steps:"))
    out = tmp_path / "r.csv"
    assert main(["sweep", str(model), "--param", "steps=1,2", "--out", str(out), "--quiet"]) == 1
    err = one_line(capsys.readouterr().err)
    assert re.match(rf"{re.escape(str(model))}:{line}:\d+: ", err), err
    assert "swept parameter `steps` has the name of a result column (the solver's step count)" in err
    assert "rename the parameter in the model file" in err and err.endswith("[PHC-E606]")
    assert not out.exists()
    scene = tmp_path / "study.yaml"
    scene.write_text(f"model: {model}\nsweep:\n  parameters:\n    c: [0.2, 0.4]\n    steps: [1, 2]\n")
    assert main(["sweep", str(scene), "--out", str(out), "--quiet"]) == 1
    err = one_line(capsys.readouterr().err)
    assert err.startswith(f"{scene}:5:5: sweep.parameters.steps: swept parameter `steps` has the name"), err
    assert not out.exists()


def test_a_parameter_with_a_name_of_its_own_still_sweeps_and_parquet_columns_are_unique(tmp_path, msd):
    pq = pytest.importorskip("pyarrow.parquet")
    report = run_sweep(MSD, tmp_path / "r.parquet", params=[("k", "1,4")], t_end=0.5, executor=LocalExecutor(1),
                       progress=False, compiled=msd)
    names = pq.read_table(report.paths["parquet"]).column_names
    assert len(names) == len(set(names)) and names[:2] == ["point", "k"]


@pytest.mark.parametrize("out, series", [("r.csv", "r.csv"), ("r.parquet", "r.csv"), ("r.csv", "sub/../r.csv"),
                                         ("sub/r.parquet", "sub/./r.csv")])
def test_the_time_series_cannot_be_a_results_file(out, series, tmp_path, monkeypatch, capsys):
    """`--out r.parquet` writes `r.csv` too (its append log): `--series r.csv` would be
    written into it. Refused in one line before the model is compiled."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    assert main(["sweep", str(MSD), "--param", "k=1,2", "--out", out, "--series", series, "--quiet"]) == 2
    err = one_line(capsys.readouterr().err)
    assert err.startswith(f"phc sweep: error: --series `{series}` is "), err
    assert "give the time series a file of its own" in err
    assert not (tmp_path / "r.csv").exists() and not (tmp_path / "sub" / "r.csv").exists()
    with pytest.raises(SweepSetupError, match="--series"):
        run_sweep(MSD, out, params=[("k", "1,2")], series=series, progress=False)


# -- a dead worker, resume ---------------------------------------------------------------


def test_a_worker_that_dies_is_charged_to_its_own_point_only(tmp_path, msd, monkeypatch):
    """The point k = 3 kills its worker process every time it runs; the other points, run
    meanwhile on the other worker or queued, are not charged: they succeed at their first
    attempt and match the closed form, and only k = 3 fails, after its own 3 attempts."""
    monkeypatch.setenv("PHC_SWEEP_START_METHOD", "fork")  # the workers inherit the patched run_point
    real = executors.run_point

    def run_point(compiled, task):
        if task["params"]["k"] == 3.0:
            os.kill(os.getpid(), signal.SIGKILL)
        time.sleep(0.2)  # the other points overlap the deaths (nothing asserts on time)
        return real(compiled, task)

    monkeypatch.setattr(executors, "run_point", run_point)
    report = run_sweep(MSD, tmp_path / "r.csv", params=[("k", "3,1,2,4,5,6")], t_end=1.0,
                       executor=LocalExecutor(2), progress=False, compiled=msd)
    rows = read_results(tmp_path / "r.csv")
    assert report.complete and [r["point"] for r in rows] == list(range(6))
    for r in rows[1:]:
        assert r["success"] and r["attempts"] == 1, r
        assert r["x.final"] == pytest.approx(msd_x(r["k"], 1.0), abs=1e-7)
    assert not rows[0]["success"] and rows[0]["attempts"] == executors.MAX_ATTEMPTS
    assert "killed by SIGKILL" in rows[0]["message"]


def test_resume_runs_missing_points_and_failed_ones_on_request(tmp_path, msd):
    out = tmp_path / "r.csv"
    common = dict(params=[("k", "1,2,3")], t_end=0.5, executor=LocalExecutor(1), progress=False, compiled=msd)
    run_sweep(MSD, out, **common)
    with open(out, newline="") as fh:
        header, *rows = list(csv.reader(fh))
    rows[0][header.index("success")] = "false"  # point 0 failed (say, its node went down)
    with open(out, "w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows([header, rows[0], rows[1]])  # point 2 never ran
    report = run_sweep(MSD, out, resume=True, **common)
    rows = read_results(out)
    assert report.resumed == 2 and report.retried == 0 and not report.success
    assert [r["success"] for r in rows] == [False, True, True]  # the failed row is kept, point 2 ran
    report = run_sweep(MSD, out, resume=True, retry_failed=True, **common)
    rows = read_results(out)
    assert report.resumed == 2 and report.retried == 1 and report.success
    assert rows[0]["x.final"] == pytest.approx(msd_x(1.0, 0.5), abs=1e-7)
    with pytest.raises(SweepSetupError, match="--retry-failed needs --resume"):
        run_sweep(MSD, out, retry_failed=True, overwrite=True, **common)


def test_retry_failed_on_the_command_line(tmp_path, capsys):
    out = str(tmp_path / "r.csv")
    argv = ["sweep", str(MSD), "--param", "k=1,2", "--t-end", "0.2", "--workers", "1", "--quiet", "--out", out]
    assert main([*argv, "--retry-failed"]) == 2
    assert one_line(capsys.readouterr().err) == ("phc sweep: error: --retry-failed needs --resume (it runs the "
                                                 "failed points of existing results again)")
    assert main(argv) == 0
    capsys.readouterr()
    assert main([*argv, "--resume", "--retry-failed", "--format", "json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["resumed"], summary["retried"], summary["succeeded"]) == (2, 0, 2)


def test_resume_needs_results_of_the_same_model_values_and_phc_version(tmp_path, msd):
    out = tmp_path / "r.csv"
    common = dict(t_end=0.5, executor=LocalExecutor(1), progress=False)
    run_sweep(MSD, out, params=[("k", "1,2")], compiled=msd, **common)
    meta_path = tmp_path / "r.sweep.json"
    meta = json.loads(meta_path.read_text())
    meta_path.write_text(json.dumps(dict(meta, phc_version="0.0.1")))
    with pytest.raises(SweepSetupError, match=r"computed by phc 0\.0\.1, this is phc "):
        run_sweep(MSD, out, params=[("k", "1,2")], resume=True, compiled=msd, **common)
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(SweepSetupError, match=r"different sweep \(over k = `1,2`; this one: k = `1,3`\)"):
        run_sweep(MSD, out, params=[("k", "1,3")], resume=True, compiled=msd, **common)
    other = tmp_path / "other.yaml"  # the same parameters and outputs, another model
    other.write_text(MSD.read_text().replace("name: mass_spring_damper", "name: other_oscillator"))
    with pytest.raises(SweepSetupError, match="it holds a sweep of model `mass_spring_damper`, not `other_oscillator`"):
        run_sweep(other, out, params=[("k", "1,2")], resume=True, **common)
    stiffer = tmp_path / "stiffer.yaml"  # the same name, other generated code
    stiffer.write_text(MSD.read_text().replace("c: {value: 0.4,", "c: {value: 0.5,"))
    with pytest.raises(SweepSetupError, match="the model changed since its rows were computed"):
        run_sweep(stiffer, out, params=[("k", "1,2")], resume=True, **common)
    report = run_sweep(MSD, out, params=[("k", "1,2")], resume=True, compiled=msd, **common)
    assert report.resumed == 2 and report.success


# -- workers anywhere --------------------------------------------------------------------


def test_dask_workers_started_in_another_directory_run_a_relative_model_path(tmp_path, monkeypatch):
    """The model is named relative to the client's directory; the Dask worker runs in
    another one. Parameter values are checked against the model file by the client and the
    compiled model travels whole: the worker never reads a file of the model."""
    distributed = pytest.importorskip("distributed")
    import logging

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the worker process starts here
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                                       silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    try:
        monkeypatch.chdir(REPO)
        assert [os.path.realpath(d) for d in client.run(os.getcwd).values()] == [os.path.realpath(elsewhere)]
        relative = "models/mass_spring_damper.yaml"
        report = run_sweep(relative, tmp_path / "r.csv", params=[("k", "1,4"), ("c", "0.3,-1")], t_end=1.0,
                           executor=DaskExecutor(client=client), progress=False, compiled=phc.compile_model(relative))
    finally:
        client.close()
        cluster.close()
    rows = read_results(tmp_path / "r.csv")
    assert report.complete and [r["success"] for r in rows] == [True, False, True, False]
    for r in rows:
        if r["c"] > 0:
            assert r["worker"].startswith("tcp://")
            assert r["x.final"] == pytest.approx(msd_x(r["k"], 1.0, c=r["c"]), abs=1e-7)
        else:  # refused as the model file would refuse it, by the client (which has the file)
            assert "parameter `c` = -1" in r["message"] and "[PHC-E405]" in r["message"], r["message"]


# -- no worker left behind ---------------------------------------------------------------


def _descendants(pid: int) -> set[int]:
    """The processes started by `pid`, and theirs (a fork server's workers), from /proc."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parents[int(entry.name)] = int((entry / "stat").read_text().rpartition(")")[2].split()[1])
            except (OSError, ValueError, IndexError):
                continue
    out, todo = set(), [pid]
    while todo:
        parent = todo.pop()
        kids = {p for p, pp in parents.items() if pp == parent and p not in out}
        out |= kids
        todo.extend(kids)
    return out


def _running(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rpartition(")")[2].split()[0] != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
@pytest.mark.parametrize("signum, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_stopping_a_sweep_leaves_no_worker_behind(signum, code, tmp_path):
    """SIGTERM (a batch system's stop) or SIGINT to `phc sweep` while its two workers run
    long points: it exits with 128 + the signal, says how to resume, and its worker
    processes are gone."""
    out = tmp_path / "r.csv"
    argv = [sys.executable, "-m", "phc", "sweep", str(MSD), "--param", "k=1:8:8", "--t-end", "1e7", "--workers", "2",
            "--out", str(out), "--quiet", "--no-certify", "--backend", "numpy"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                            preexec_fn=interruptible)
    # waits for the two workers (or the child's exit); the deadline is a hang guard, not a speed limit
    deadline = time.monotonic() + SUBPROCESS_TIMEOUT
    kids: set[int] = set()
    while time.monotonic() < deadline and proc.poll() is None:
        kids = _descendants(proc.pid)
        if len(kids) >= 2:
            break
        time.sleep(0.05)
    assert len(kids) >= 2, proc.communicate(timeout=SUBPROCESS_TIMEOUT)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=SUBPROCESS_TIMEOUT)
    assert proc.returncode == code, err
    assert "--resume" in err and "Traceback" not in err
    # a process the sweep did not wait for (a fork server) may end a moment after it; a worker
    # left running a point of 1e7 s would still be there at the deadline (a hang guard again)
    deadline = time.monotonic() + SUBPROCESS_TIMEOUT
    while time.monotonic() < deadline and any(_running(pid) for pid in kids):
        time.sleep(0.05)
    assert not [pid for pid in kids if _running(pid)]


def _stopped_before_its_handlers(blob: bytes, parent: int) -> None:
    """A worker stopped at its first instruction, before it set its own handlers: the
    SIGTERM stays pending until `_init_pool_worker` has set the default action."""
    os.kill(os.getpid(), signal.SIGTERM)
    executors._init_pool_worker(blob, parent)
    os._exit(0)  # not reached when the pending SIGTERM ends the process


def _raise_interrupt(signum, frame):  # the sweep command's SIGTERM handler does this
    raise KeyboardInterrupt


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask") or "fork" not in
                    __import__("multiprocessing").get_all_start_methods(), reason="POSIX fork and signal masks")
def test_a_worker_stopped_before_it_set_its_handlers_ends_quietly():
    """A forked worker inherits the sweep command's SIGTERM handler (it raises
    KeyboardInterrupt). Stopped before it installed its own, it must end by SIGTERM, not
    print a traceback from the inherited handler: the parent holds the signals while it
    starts the worker, and the worker releases them once its handlers are set."""
    import multiprocessing
    import pickle

    ctx = multiprocessing.get_context("fork")
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        with executors._signals_held("fork"):
            process = ctx.Process(target=_stopped_before_its_handlers, args=(pickle.dumps({}), os.getpid()))
            process.start()
        process.join(timeout=SUBPROCESS_TIMEOUT)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert process.exitcode == -signal.SIGTERM  # 1 (KeyboardInterrupt in the child) without the hold
