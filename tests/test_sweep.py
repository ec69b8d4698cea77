"""Parameter studies (:mod:`phc.sweep`, ``phc sweep``): the SPEC syntax, the samplers, a
compiled model pickled by value, the local pool and a Dask LocalCluster giving identical
rows, failing points as rows, interrupt and resume, compile-time parameters, the scene's
``sweep:`` section, and the result files.

Physics is checked against closed forms (the damped oscillator's x(t); the slider's
initial position r + L) and against runs of :func:`phc.simulate` in this process.
"""

from __future__ import annotations

import json
import math
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.cli import main
from phc.spec.sweep import SpecError, parse_spec
from phc.sweep import (MACHINE_COLUMNS, AppendLog, DaskExecutor, LocalExecutor, SweepSetupError, make_design,
                       read_results, run_sweep, sample_unit)
from closed_forms import msd_x  # the free damped oscillator of models/mass_spring_damper.yaml
from time_limits import SUBPROCESS_TIMEOUT

REPO = Path(__file__).resolve().parents[1]
MODELS = REPO / "models"
MSD = MODELS / "mass_spring_damper.yaml"
CRANK = MODELS / "flexible_slider_crank.yaml"


@pytest.fixture(scope="module")
def msd():
    return phc.compile_model(MSD)


@pytest.fixture(scope="module")
def crank():
    return phc.compile_model(CRANK)


def same(a: dict, b: dict) -> bool:
    """Rows equal in every column but timing and place (NaN equals NaN)."""
    keys = set(a) - set(MACHINE_COLUMNS)
    if keys != set(b) - set(MACHINE_COLUMNS):
        return False
    return all(a[k] == b[k] or (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])) for k in keys)



# -- the SPEC syntax -------------------------------------------------------------------


@pytest.mark.parametrize("text, values", [
    ("68.27", (68.27,)),
    ("1,2,5", (1.0, 2.0, 5.0)),
    ("10:100:4", (10.0, 40.0, 70.0, 100.0)),
    ("log:1e-3:1e-1:3", (1e-3, 1e-2, 1e-1)),
    ("2:2:1", (2.0,)),
])
def test_grid_specs(text, values):
    axis = parse_spec("k", text)
    assert not axis.sampled
    assert np.allclose(axis.values, values, rtol=1e-14, atol=0)
    assert axis.values[-1] == values[-1]  # the end is exact, not accumulated


def test_yaml_numbers_and_lists_are_specs():
    assert parse_spec("k", 3).values == (3.0,)
    assert parse_spec("k", [1, 2.5]).values == (1.0, 2.5)


@pytest.mark.parametrize("text, distribution, a, b", [
    ("uniform:1:2", "uniform", 1, 2), ("normal:0.5:0.1", "normal", 0.5, 0.1),
    ("loguniform:1e-3:1", "loguniform", 1e-3, 1), ("log-uniform:1:10", "loguniform", 1, 10)])
def test_distribution_specs(text, distribution, a, b):
    axis = parse_spec("k", text)
    assert (axis.distribution, axis.a, axis.b) == (distribution, a, b)


@pytest.mark.parametrize("text, words", [
    ("1:2", "A:B:N"), ("a,b", "not a number"), ("1:2:0", "whole number"), ("1:2:2.5", "whole number"),
    ("log:0:1:3", "positive"), ("uniform:2:1", "below"), ("normal:0:0", "standard deviation"),
    ("loguniform:0:1", "positive"), ("1,,2", "empty"), ("nan", "finite"), ("", "empty"), ("uniform:1", "two numbers"),
])
def test_bad_specs_say_what_is_wrong(text, words):
    with pytest.raises(SpecError, match=words):
        parse_spec("k", text)


# -- samplers --------------------------------------------------------------------------


def test_latin_hypercube_hits_every_stratum_once_and_is_reproducible():
    n = 50
    u = sample_unit(n, 3, seed=7, sampling="lhs")
    for j in range(3):
        assert sorted(np.floor(u[:, j] * n).astype(int)) == list(range(n))
    assert np.array_equal(u, sample_unit(n, 3, seed=7, sampling="lhs"))
    assert not np.array_equal(u, sample_unit(n, 3, seed=8, sampling="lhs"))


def test_sampled_distributions_follow_their_laws(msd):
    axes = [parse_spec("m", "normal:2:0.1"), parse_spec("k", "loguniform:1:100"), parse_spec("c", "uniform:0.1:0.2")]
    design = make_design(msd, axes, samples=2000, seed=1)
    m = np.array([p.params["m"] for p in design.points])
    k = np.array([p.params["k"] for p in design.points])
    c = np.array([p.params["c"] for p in design.points])
    assert abs(m.mean() - 2) < 0.005 and abs(m.std() - 0.1) < 0.005
    assert k.min() >= 1 and k.max() <= 100 and abs(np.median(np.log10(k)) - 1) < 0.02  # uniform in log k
    assert c.min() >= 0.1 and c.max() <= 0.2


def test_grid_times_samples(msd):
    design = make_design(msd, [parse_spec("k", "1,2,3"), parse_spec("c", "uniform:0.1:0.2")], samples=4)
    assert len(design.points) == 12
    assert [p.values["k"] for p in design.points[:5]] == [1, 1, 1, 1, 2]
    assert [p.values["c"] for p in design.points[:4]] == [p.values["c"] for p in design.points[4:8]]


@pytest.mark.parametrize("axes, samples, words", [
    ([("kk", "1")], None, "unknown parameter `kk`.*did you mean `k`"),
    ([("k", "uniform:1:2")], None, "no number of samples"),
    ([("k", "1,2")], 5, "no parameter is a distribution"),
    ([("accuracy.mesh.rod", "4")], None, "not a distributed component"),
    ([("accuracy.rtol", "-1,1e-6")], None, "must be positive"),
])
def test_design_mistakes_are_one_message(msd, axes, samples, words):
    with pytest.raises(SweepSetupError, match=words):
        make_design(msd, [parse_spec(n, s) for n, s in axes], samples=samples)


# -- a compiled model pickles by value --------------------------------------------------


def test_compiled_model_pickles_as_source_and_metadata(crank):
    state = crank.__getstate__()
    assert "module" not in state and state["source"] == crank.source  # the module is rebuilt from the source
    a = phc.simulate(crank, t_end=0.001, params={"EI": 20.0})  # checks EI = 20 against the model file
    twin = pickle.loads(pickle.dumps(crank))
    assert twin.module is not crank.module and twin.module.VARIABLES == crank.module.VARIABLES
    assert twin.module.__file__ == str(twin.module_path)
    # outputs are located without reading the model file on the worker
    line = next(i for i, text in enumerate(CRANK.read_text(encoding="utf-8").splitlines(), 1)
                if text.strip().startswith("slider_x:"))
    assert twin.description.output_spans["slider_x"].line == line
    b = phc.simulate(twin, t_end=0.001, params={"EI": 20.0})
    assert np.array_equal(a.y, b.y)
    # the twin never reads the model's files: a value not checked where it was compiled is refused
    with pytest.raises(phc.SimulationSetupError, match="rebuilt from its pickle"):
        phc.simulate(twin, t_end=0.001, params={"EI": 21.0})


def test_a_pickle_from_another_phc_version_is_refused(msd, monkeypatch):
    blob = pickle.dumps(msd)
    monkeypatch.setattr(phc, "__version__", "0.0.0-other")
    with pytest.raises(RuntimeError, match="install the same phc version on every worker"):
        pickle.loads(blob)


# -- sweeps -----------------------------------------------------------------------------


def test_stiffness_sweep_matches_the_closed_form(tmp_path, msd):
    ks = [1.0, 4.0, 9.0]
    report = run_sweep(MSD, tmp_path / "msd.csv", params=[("k", "1,4,9")], t_end=2.0,
                       series=tmp_path / "series.csv", executor=LocalExecutor(2), progress=False, compiled=msd)
    assert report.success and report.n_compilations == 1
    rows = read_results(tmp_path / "msd.csv")
    assert [r["k"] for r in rows] == ks
    for r in rows:
        assert r["x.final"] == pytest.approx(msd_x(r["k"], 2.0), abs=1e-7)
        assert r["energy_balance_relative"] < 1e-6
    series = np.loadtxt(tmp_path / "series.csv", delimiter=",", skiprows=1)
    for i, k in enumerate(ks):
        block = series[series[:, 0] == i]
        assert len(block) == msd.dae.options["n_out"]
        exact = [msd_x(k, t) for t in block[:, 1]]
        assert np.max(np.abs(block[:, 2] - exact)) < 1e-7


def test_local_pool_and_dask_localcluster_give_identical_rows_and_a_failing_point_is_a_row(tmp_path, crank):
    """The flexible slider–crank over rod stiffness, EI = -68.27 is refused as the model
    file would refuse it (PHC-E141): that point fails, is recorded, and the sweep completes
    on both executors."""
    pytest.importorskip("distributed")
    common = dict(params=[("EI", "6.827,68.27,-68.27,682.7")], t_end=0.001, workers=2, progress=False, compiled=crank)
    for executor in ("local", "dask"):
        report = run_sweep(CRANK, tmp_path / f"{executor}.csv", executor=executor, **common)
        assert report.complete and len(report.failed) == 1
    local, dask = read_results(tmp_path / "local.csv"), read_results(tmp_path / "dask.csv")
    assert [r["point"] for r in local] == [0, 1, 2, 3] == [r["point"] for r in dask]
    assert [r["success"] for r in local] == [True, True, False, True]
    assert "parameter `EI` = -68.27: `EI` of `rod` must be positive" in local[2]["message"]
    assert "[PHC-E141]" in local[2]["message"]
    assert all(same(a, b) for a, b in zip(local, dask))
    assert all(r["worker"].startswith("tcp://") for r in dask if r["success"])
    assert local[2]["worker"] == dask[2]["worker"] == ""  # refused by this process, never sent to a worker
    # each row is what phc.simulate gives in this process, without pickling
    for r in (local[0], local[3]):
        res = phc.simulate(crank, t_end=0.001, params={"EI": r["EI"]})
        assert r["slider_x.final"] == res.outputs["slider_x"][-1]
        assert r["steps"] == res.steps
        assert r["energy_balance_relative"] < 1e-12  # the midpoint rule keeps H to round-off


def test_compile_time_parameter_groups_runs_by_compilation(tmp_path, crank):
    """L (the rod's mesh length) is compiled in: L = 0.3 is the model's own compilation,
    L = 0.35 one more. The slider starts at r + L, its maximum over the run."""
    report = run_sweep(CRANK, tmp_path / "L.csv", params=[("L", "0.3,0.35"), ("EI", "30,60")], t_end=0.0005,
                       executor=LocalExecutor(2), progress=False, compiled=crank)
    assert report.success and report.n_compilations == 2
    for r in read_results(tmp_path / "L.csv"):
        assert r["slider_x.max"] == pytest.approx(0.15 + r["L"], abs=1e-12)


def test_a_recompiled_group_runs_on_the_base_models_backend():
    """`--backend numpy` holds for every compilation group, not only the base model: the
    flexible slider-crank has enough unknowns that the default choice would compile it."""
    from phc.sweep import compile_group

    base = phc.compile_model(CRANK, certify=False, backend="numpy")
    assert base.backend == "numpy"
    group = compile_group(base, CRANK, (("L", 0.35),), certify=False)
    assert group is not base and group.backend == "numpy"


def test_simulate_param_of_a_compile_time_parameter_recompiles_with_a_note(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main(["simulate", str(CRANK), "--param", "L=0.35", "--t-end", "0.0002", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "note: parameter `L` is used at compile time" in err and "recompiled with L = 0.35" in err
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert data["outputslider_x"][0] == pytest.approx(0.5, abs=1e-12)  # r + L


def test_scene_sweep_section(tmp_path):
    scene = tmp_path / "study.yaml"
    scene.write_text(f"model: {MSD}\nname: study\nt_end: 1.5\noutputs: {{x: spring.x}}\n"
                     "sweep:\n  parameters:\n    k: [2, 8]\n    c: uniform:0.1:0.3\n  samples: 2\n  seed: 3\n")
    report = run_sweep(scene, tmp_path / "s.csv", executor=LocalExecutor(1), progress=False)
    rows = read_results(tmp_path / "s.csv")
    assert len(rows) == 4 and report.design.sampling == "lhs"
    for r in rows:
        assert 0.1 <= r["c"] <= 0.3
        assert r["x.final"] == pytest.approx(msd_x(r["k"], 1.5, c=r["c"]), abs=1e-7)
    # the command line overrides the scene's entry
    report = run_sweep(scene, tmp_path / "t.csv", params=[("c", "0.4")], samples=None, executor=LocalExecutor(1),
                       progress=False)
    assert len(report.design.points) == 2


def test_mistakes_in_a_scene_sweep_section_are_located(tmp_path, capsys):
    scene = tmp_path / "study.yaml"
    scene.write_text(f"model: {MSD}\nsweep:\n  parameters:\n    kk: [2, 8]\n")
    assert main(["sweep", str(scene), "--out", str(tmp_path / "s.csv")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"{scene}:4:5: ") and "unknown parameter `kk`" in err[0]
    assert "PHC-E606" in err[0]
    scene.write_text(f"model: {MSD}\nsweep:\n  parameters:\n    k: '1:2'\n")
    assert main(["sweep", str(scene), "--out", str(tmp_path / "s.csv")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"{scene}:4:8: ") and "A:B:N" in err[0]


def test_command_line_mistakes_are_usage_errors(tmp_path, capsys):
    out = str(tmp_path / "r.csv")
    for argv, words in [
        (["--param", "k=1:2"], "A:B:N"),
        (["--param", "EI=1"], "unknown parameter `EI`"),
        (["--param", "k"], "NAME=SPEC"),
        (["--param", "k=1", "--scheduler", "tcp://x:1"], "--scheduler needs --executor dask"),
    ]:
        assert main(["sweep", str(MSD), "--out", out, "--quiet", *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("phc sweep: error: ") and words in err[0], err


def test_existing_results_need_resume_or_overwrite_and_must_match(tmp_path, msd, capsys):
    out = tmp_path / "r.csv"
    run_sweep(MSD, out, params=[("k", "1,2")], t_end=0.5, executor=LocalExecutor(1), progress=False, compiled=msd)
    with pytest.raises(SweepSetupError, match="--resume"):
        run_sweep(MSD, out, params=[("k", "1,2")], t_end=0.5, executor=LocalExecutor(1), progress=False,
                  compiled=msd)
    with pytest.raises(SweepSetupError, match="different sweep"):
        run_sweep(MSD, out, params=[("k", "1,3")], t_end=0.5, resume=True, executor=LocalExecutor(1),
                  progress=False, compiled=msd)
    report = run_sweep(MSD, out, params=[("k", "1,2")], t_end=0.5, resume=True, executor=LocalExecutor(1),
                       progress=False, compiled=msd)
    assert report.resumed == 2 and report.success  # nothing left to run


def test_a_torn_last_line_is_dropped_on_resume(tmp_path, msd):
    out = tmp_path / "r.csv"
    run_sweep(MSD, out, params=[("k", "1,2,3")], t_end=0.5, executor=LocalExecutor(1), progress=False, compiled=msd)
    lines = out.read_bytes().splitlines(keepends=True)
    out.write_bytes(b"".join(lines[:3]) + lines[3][:20])  # header, points 0 and 1, half of point 2
    report = run_sweep(MSD, out, params=[("k", "1,2,3")], t_end=0.5, resume=True, executor=LocalExecutor(1),
                       progress=False, compiled=msd)
    assert report.resumed == 2 and report.success
    rows = read_results(out)
    assert [r["point"] for r in rows] == [0, 1, 2]
    assert rows[2]["x.final"] == pytest.approx(msd_x(3.0, 0.5), abs=1e-7)


def test_append_log_writes_whole_lines(tmp_path):
    log = AppendLog(tmp_path / "a.csv", ["point", "message"])
    log.create()
    log.append([[0, "a, \"quoted\" message"], [1, "b"]])
    header, rows = log.read()
    assert header == ["point", "message"] and rows == [["0", "a, \"quoted\" message"], ["1", "b"]]


def interruptible():
    """SIGINT at its default and unblocked in the child (see tests/test_cli_faults.py)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_interrupt_then_resume(tmp_path):
    """Ctrl-C (SIGINT to the command) keeps the finished rows and exits 130; --resume runs
    only the rest: the kept rows are untouched (same worker process id)."""
    out = tmp_path / "r.csv"
    argv = [sys.executable, "-m", "phc", "sweep", str(MSD), "--param", "k=1:8:8", "--t-end", "20", "--workers", "1",
            "--out", str(out), "--quiet", "--no-certify"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                            preexec_fn=interruptible)
    # waits for an external event (the first finished row, or the child's exit); the deadline only
    # bounds the wait, generously for a loaded machine, and nothing asserts on the elapsed time
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if out.exists() and len(out.read_bytes().splitlines()) >= 2:
            break
        if proc.poll() is not None:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=SUBPROCESS_TIMEOUT)
    assert proc.returncode == 130, err
    assert "--resume" in err and "Traceback" not in err
    kept = read_results(out)
    assert 1 <= len(kept) < 8
    done = subprocess.run(argv + ["--resume"], capture_output=True, text=True, cwd=tmp_path, timeout=SUBPROCESS_TIMEOUT)
    assert done.returncode == 0, done.stderr
    rows = read_results(out)
    assert [r["point"] for r in rows] == list(range(8))
    for r in kept:
        assert rows[r["point"]] == r  # kept, not run again
    for r in rows:
        assert r["x.final"] == pytest.approx(msd_x(r["k"], 20.0), abs=1e-7)


def test_plot_one_and_two_parameters(tmp_path, msd, capsys):
    pytest.importorskip("matplotlib")
    out, png = tmp_path / "r.csv", tmp_path / "line.png"
    assert main(["sweep", str(MSD), "--param", "k=log:1:100:3", "--param", "c=0.2,0.4", "--t-end", "0.5",
                 "--workers", "1", "--out", str(out), "--quiet", "--plot", str(png), "--plot-against", "k"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    heat = tmp_path / "heat.png"
    assert main(["sweep", str(MSD), "--param", "k=log:1:100:3", "--param", "c=0.2,0.4", "--t-end", "0.5",
                 "--workers", "1", "--out", str(out), "--quiet", "--resume", "--plot", str(heat),
                 "--plot-output", "x.rms"]) == 0
    assert heat.stat().st_size > 1000
    assert main(["sweep", str(MSD), "--param", "k=log:1:100:3", "--param", "c=0.2,0.4", "--t-end", "0.5",
                 "--out", str(out), "--quiet", "--resume", "--plot", str(heat), "--plot-output", "nope"]) == 2
    assert "--plot-output `nope` is not a column" in capsys.readouterr().err


def test_parquet_has_the_rows_and_units(tmp_path, msd):
    pq = pytest.importorskip("pyarrow.parquet")
    report = run_sweep(MSD, tmp_path / "r.parquet", params=[("k", "1,2")], t_end=0.5, executor=LocalExecutor(1),
                       progress=False, compiled=msd)
    table = pq.read_table(report.paths["parquet"])
    assert table.column("k").to_pylist() == [1.0, 2.0]
    assert table.schema.field("k").metadata == {b"unit": b"N/m"}
    assert table.schema.field("cpu_time_s").metadata == {b"unit": b"s"}
    assert table.column("success").to_pylist() == [True, True]
    meta = json.loads((tmp_path / "r.sweep.json").read_text())
    assert meta["columns"]["k"] == {"unit": "N/m"}


@pytest.mark.slow
def test_a_point_whose_dask_worker_is_lost_is_run_again_and_the_row_says_so(tmp_path, msd):
    """Kill the worker process running a point: the scheduler runs it again on another
    worker; the row has attempts = 2 and names the lost worker."""
    distributed = pytest.importorskip("distributed")
    import logging
    import threading

    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None,
                                       silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    try:
        pids = client.run(os.getpid)
        killed = []

        def killer(event):
            _, msg = event
            if not killed and msg["point"] == 0:
                killed.append(msg["worker"])
                os.kill(pids[msg["worker"]], signal.SIGKILL)

        original = client.subscribe_topic

        def subscribe(topic, handler):
            return original(topic, lambda ev: (handler(ev), threading.Timer(0.5, killer, (ev,)).start()))

        client.subscribe_topic = subscribe
        report = run_sweep(MSD, tmp_path / "r.csv", params=[("k", "1,2")], t_end=400.0,
                           executor=DaskExecutor(client=client), progress=False, compiled=msd)
    finally:
        client.close()
        cluster.close()
    rows = read_results(tmp_path / "r.csv")
    assert killed and report.success
    assert rows[0]["attempts"] == 2 and killed[0] in rows[0]["message"]
    assert rows[0]["x.final"] == pytest.approx(msd_x(1.0, 400.0), abs=1e-7)


def test_shipped_stiffness_study_and_json_summary(tmp_path, msd, capsys):
    from phc.sweep import sweep_axes

    compiled = phc.compile_model(MODELS / "scenes" / "slider_crank_stiffness.yaml", certify=False)
    axes, spec, _ = sweep_axes(compiled, [])
    design = make_design(compiled, axes, spec.samples, spec.seed, spec.sampling)
    values = [p.values["EI"] for p in design.points]
    assert len(values) == 16 and values[0] == pytest.approx(68.27 / 10) and values[-1] == pytest.approx(682.7)
    assert np.allclose(np.diff(np.log(values)), np.log(100) / 15)
    assert main(["sweep", str(MSD), "--param", "k=1,2", "--t-end", "0.2", "--workers", "1", "--quiet",
                 "--format", "json", "--out", str(tmp_path / "r.csv")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["planned"], summary["succeeded"], summary["failed"], summary["n_compilations"]) == (2, 2, 0, 1)


def test_a_dask_worker_with_two_threads_gives_the_rows_of_the_local_pool(tmp_path):
    """`dask worker` runs two points at once on threads of one process by default: the
    generated module they share must be re-entrant (tests/codegen/test_reentrant.py). A linear
    chain whose sparse matrices depend on the swept `k` (memoized per parameter vector)."""
    distributed = pytest.importorskip("distributed")
    import logging

    sys.path.insert(0, str(Path(__file__).resolve().parent / "library"))
    try:
        from test_linear_phs import chain_model
    finally:
        sys.path.pop(0)
    path, _ = chain_model(tmp_path, 30, t_end=0.5)
    compiled = phc.compile_model(path, certify=False)
    assert "= _linear(p)" in compiled.source
    common = dict(params=[("k", "1,2,3,4,5,6,7,8")], progress=False, compiled=compiled, solver="midpoint")
    run_sweep(path, tmp_path / "local.csv", executor=LocalExecutor(1), **common)
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True, dashboard_address=None,
                                       silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    try:
        assert list(client.nthreads().values()) == [2]
        report = run_sweep(path, tmp_path / "dask.csv", executor=DaskExecutor(client=client), **common)
    finally:
        client.close()
        cluster.close()
    assert report.complete and not report.failed
    local, dask = read_results(tmp_path / "local.csv"), read_results(tmp_path / "dask.csv")
    assert [r["point"] for r in local] == list(range(8)) == [r["point"] for r in dask]
    assert all(same(a, b) for a, b in zip(local, dask))


def test_the_output_names_every_file_written_and_the_help_says_which(tmp_path, msd, capsys):
    """`-o r.csv` writes r.csv, r.parquet (with pyarrow) and r.sweep.json: the summary has one
    `wrote` line for each file that appeared, and `phc sweep --help` names them."""
    out = tmp_path / "out"
    out.mkdir()
    assert main(["sweep", str(MSD), "--param", "k=1,2", "--t-end", "0.5", "--workers", "1", "--quiet",
                 "-o", str(out / "r.csv"), "--series", str(out / "s.csv")]) == 0
    wrote = [line.split("wrote", 1)[1].strip() for line in capsys.readouterr().out.splitlines()
             if line.strip().startswith("wrote")]
    assert sorted(wrote) == sorted(str(p) for p in out.iterdir()), wrote
    assert {"r.csv", "r.sweep.json", "s.csv"} <= {Path(p).name for p in wrote}
    with pytest.raises(SystemExit):
        main(["sweep", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "RESULTS.csv" in help_text and "RESULTS.parquet" in help_text and "RESULTS.sweep.json" in help_text
