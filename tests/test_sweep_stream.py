"""A streamed sweep design (:class:`phc.sweep.design.Points`): the points are made on demand,
equal to an eager construction written here (grid, Latin hypercube, random); a million-point
design starts at once in bounded memory; executors take points only as workers free up;
rows are held as typed columns (:class:`phc.sweep.results.RowTable`); resuming reads the
results a row at a time and gives the rows of an uninterrupted sweep.

Physics is checked against the closed form of the damped oscillator (tests/closed_forms.py).
"""

from __future__ import annotations

import itertools
import json
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.cli import main
from phc.spec.sweep import parse_spec
from phc.sweep import (MACHINE_COLUMNS, LocalExecutor, RowTable, SweepSetupError, make_design, read_results,
                       run_point, run_sweep)
from phc.sweep import executors, run as sweep_run
from phc.sweep.results import RUN_COLUMNS, STATS, _kinds, iter_csv
from closed_forms import msd_x  # the free damped oscillator of models/mass_spring_damper.yaml

REPO = Path(__file__).resolve().parents[1]
MSD = REPO / "models" / "mass_spring_damper.yaml"
MiB = 2**20
MILLION = [("k", "1:2:1000"), ("c", "0.1:0.5:1000")]  # a grid of 10^6 points (the cap)


@pytest.fixture(scope="module")
def msd():
    return phc.compile_model(MSD)


def same(a: dict, b: dict) -> bool:
    """Rows equal in every column but timing and place (NaN equals NaN)."""
    keys = set(a) - set(MACHINE_COLUMNS)
    if keys != set(b) - set(MACHINE_COLUMNS):
        return False
    return all(a[k] == b[k] or (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])) for k in keys)


# -- the points equal an eager construction --------------------------------------------------


def eager_points(axes, samples, seed, sampling):
    """Every point's values, built the way the sweep built them before it was streamed: the
    grid's product (last axis fastest), and for each combination every sample; the unit
    samples drawn at once (uniform random, or one permutation plus a uniform offset per
    axis: a Latin hypercube), mapped through the inverse CDFs."""
    from scipy.special import ndtri

    grid = [a for a in axes if not a.sampled]
    sampled = [a for a in axes if a.sampled]
    draws = [{}]
    if sampled:
        rng = np.random.default_rng(seed)
        if sampling == "random":
            unit = rng.random((samples, len(sampled)))
        else:
            unit = np.empty((samples, len(sampled)))
            for j in range(len(sampled)):
                unit[:, j] = (rng.permutation(samples) + rng.random(samples)) / samples
        columns = []
        for j, a in enumerate(sampled):
            u = unit[:, j]
            columns.append(a.a + (a.b - a.a) * u if a.distribution == "uniform" else
                           np.exp(math.log(a.a) + (math.log(a.b) - math.log(a.a)) * u)
                           if a.distribution == "loguniform" else a.a + a.b * ndtri(np.clip(u, 1e-16, 1 - 1e-16)))
        draws = [dict(zip([a.name for a in sampled], map(float, row))) for row in np.column_stack(columns)]
    out = []
    for combo in itertools.product(*(a.values for a in grid)):
        fixed = dict(zip([a.name for a in grid], combo))
        out.extend({a.name: (fixed if a.name in fixed else d)[a.name] for a in axes} for d in draws)
    return out


@pytest.mark.parametrize("specs, samples, sampling", [
    ([("k", "1:3:5"), ("c", "0.1,0.2,0.4"), ("accuracy.rtol", "log:1e-8:1e-4:3")], None, "lhs"),
    ([("k", "uniform:1:3"), ("c", "loguniform:0.05:0.5"), ("m", "normal:1:0.1")], 9000, "lhs"),
    ([("k", "uniform:1:3"), ("c", "loguniform:0.05:0.5"), ("m", "normal:1:0.1")], 9000, "random"),
    ([("k", "1,2,3"), ("c", "uniform:0.1:0.2"), ("m", "0.5,1")], 5000, "lhs"),  # samples cross chunks
    ([("k", "1,2"), ("c", "uniform:0.1:0.2")], 4097, "random"),
])
def test_points_equal_an_eager_construction(msd, specs, samples, sampling):
    axes = [parse_spec(n, s) for n, s in specs]
    design = make_design(msd, axes, samples=samples, seed=11, sampling=sampling)
    want = eager_points(axes, samples, 11, sampling)
    assert len(design.points) == len(want)
    got = [p.values for p in design.points]
    assert got == want  # exactly: the same draws and the same floating-point operations
    assert [p.index for p in design.points] == list(range(len(want)))
    # by index, backwards and out of order: the same as in order
    for i in (len(want) - 1, 4096, 4095, 0, 123, len(want) // 2, -1):
        if -len(want) <= i < len(want):
            assert design.points[i].values == want[i]
    assert [p.values for p in design.points[5:9]] == want[5:9]
    with pytest.raises(IndexError):
        design.points[len(want)]
    first = design.points[0]
    assert first.params == {n: v for n, v in first.values.items() if not n.startswith("accuracy.")}
    if "accuracy.rtol" in first.values:
        assert first.options == {"rtol": first.values["accuracy.rtol"]}


def test_the_digest_names_the_definition_not_the_points(msd):
    def digest(specs, samples=None, seed=0, sampling="lhs"):
        return make_design(msd, [parse_spec(n, s) for n, s in specs], samples=samples, seed=seed,
                           sampling=sampling).digest

    base = digest([("k", "1,2"), ("c", "uniform:0.1:0.2")], 4)
    assert base == digest([("k", "1,2"), ("c", "uniform:0.1:0.2")], 4)
    others = [digest([("k", "1,2"), ("c", "uniform:0.1:0.2")], 4, seed=1),
              digest([("k", "1,2"), ("c", "uniform:0.1:0.2")], 5),
              digest([("k", "1,2"), ("c", "uniform:0.1:0.2")], 4, sampling="random"),
              digest([("k", "1,3"), ("c", "uniform:0.1:0.2")], 4),
              digest([("k", "1,2"), ("c", "uniform:0.1:0.3")], 4),
              digest([("c", "uniform:0.1:0.2"), ("k", "1,2")], 4)]  # another order of the axes
    assert len({base, *others}) == len(others) + 1


# -- bounded memory ---------------------------------------------------------------------------


@pytest.mark.parametrize("specs, samples, sampling", [
    (MILLION, None, "lhs"),
    ([("k", "uniform:1:3"), ("c", "uniform:0.1:0.5")], 1_000_000, "lhs"),
    ([("k", "uniform:1:3"), ("c", "uniform:0.1:0.5")], 1_000_000, "random"),
])
def test_a_million_point_design_is_built_and_its_first_rows_made_in_bounded_memory(msd, specs, samples, sampling):
    """The eager design held 10^6 points of a few dicts each (gigabytes); streamed, a grid
    holds its axes and a Latin hypercube one int32 permutation per sampled axis (4 MB each),
    plus one chunk of samples. 32 MiB bounds all of it (two permutations and the 8 MB
    int64 one being made, with room)."""
    axes = [parse_spec(n, s) for n, s in specs]
    tracemalloc.start()
    try:
        design = make_design(msd, axes, samples=samples, seed=3, sampling=sampling)
        assert len(design.points) == 1_000_000
        first = [p.values for p in itertools.islice(design.points, 1000)]
        last = design.points[-1]
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 32 * MiB, peak / MiB
    assert last.index == 999_999 and len(first) == 1000
    if samples is None:  # the grid's last axis runs fastest: values from the axes themselves
        assert first[1] == {"k": 1.0, "c": axes[1].values[1]} and last.values == {"k": 2.0, "c": 0.5}
    else:
        for name, (lo, hi) in (("k", (1, 3)), ("c", (0.1, 0.5))):
            assert all(lo <= v[name] < hi for v in first)
    assert design.group_counts() == {(): 1_000_000}


def test_a_row_table_of_a_hundred_rows_of_a_million_point_sweep_is_small():
    """Typed columns growing by doubling: 100 rows of a sweep sized for 10^6 points take
    kilobytes (a table allocated for every point would take tens of megabytes)."""
    outputs = ["x", "v"]
    columns = ["point", "k", "accuracy.mesh.beam", *RUN_COLUMNS, *(f"{o}.{s}" for o in outputs for s in STATS),
               *MACHINE_COLUMNS]
    tracemalloc.start()
    try:
        table = RowTable(columns)
        for i in range(100):
            table[i] = {"point": i, "k": 1.0 + i, "accuracy.mesh.beam": 4 + i, "success": i % 3 != 0,
                        "message": f"run {i}", "steps": 10 * i, "t_final": 0.5, "x.final": i / 7,
                        "attempts": 1, "worker": "here"}
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 4 * MiB, peak / MiB
    assert len(table) == 100 and 99 in table and 100 not in table
    row = table[7]
    assert row["point"] == 7 and row["k"] == 8.0 and row["x.final"] == 7 / 7
    assert type(row["accuracy.mesh.beam"]) is int and row["accuracy.mesh.beam"] == 11  # an element count stays int
    assert type(row["steps"]) is int and type(row["success"]) is bool and row["message"] == "run 7"
    assert math.isnan(row["v.rms"])  # a column the row did not give
    assert table.count("success", False) == 34  # i = 0, 3, ..., 99
    del table[3]
    table[200] = dict(table[0], point=200)
    table[0] = dict(table[0], message="again")
    assert [r["point"] for r in table.ordered()][:4] == [0, 1, 2, 4] and list(table)[-1] == 200
    assert table[0]["message"] == "again" and len(table) == 100
    assert _kinds(columns)["accuracy.mesh.beam"] == "int"


def test_the_results_are_read_a_row_at_a_time_with_fields_of_any_length(tmp_path):
    path = tmp_path / "r.csv"
    long = "x" * 200_000  # longer than the csv module's default field limit (131 072)
    path.write_text(f'point,message\n0,"{long}"\n1,"a, ""quoted"" message"\n2,tor', encoding="utf-8")
    rows = iter_csv(path)
    assert next(rows) == ["point", "message"]
    assert next(rows) == ["0", long]
    assert list(rows) == [["1", 'a, "quoted" message']]  # the torn last line is left out
    import csv

    assert csv.field_size_limit() == 131_072  # the process keeps its own setting


# -- a million-point sweep starts at once ------------------------------------------------------


class InProcess:
    """An executor that runs points here, taking them one at a time from the sweep, and is
    interrupted (Ctrl-C) after `stop` rows: it records how many points it took."""

    name = "in-process"
    startup_s = 0.0

    def __init__(self, stop=None) -> None:
        self.stop, self.taken, self.runs = stop, 0, 0

    def describe(self) -> str:
        return "in this process"

    def run(self, models, tasks, outputs):
        self.runs += 1
        for task in tasks:
            self.taken += 1
            yield run_point(models[task["group"]], task)
            if self.stop is not None and self.taken >= self.stop:
                raise KeyboardInterrupt


def test_a_million_point_sweep_takes_and_checks_only_the_points_it_runs(tmp_path, msd, monkeypatch):
    """Interrupted after its first 3 rows, a 10^6-point sweep has made 3 points and checked
    3 against the model file (not a million up front), and the rows are right."""
    checked = []
    real = sweep_run._refused

    def spy(compiled, params):
        checked.append(dict(params))
        return real(compiled, params)

    monkeypatch.setattr(sweep_run, "_refused", spy)
    runner = InProcess(stop=3)
    tracemalloc.start()
    try:
        report = run_sweep(MSD, tmp_path / "r.csv", params=MILLION, t_end=0.5, executor=runner, progress=False,
                           compiled=msd)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert report.interrupted and report.planned == 1_000_000 and len(report.rows) == 3
    assert runner.taken == 3 and len(checked) == 3
    assert peak < 32 * MiB, peak / MiB
    rows = read_results(tmp_path / "r.csv")
    c = parse_spec("c", "0.1:0.5:1000").values
    assert [(r["point"], r["k"], r["c"]) for r in rows] == [(i, 1.0, c[i]) for i in range(3)]
    for r in rows:
        assert r["success"] and r["x.final"] == pytest.approx(msd_x(1.0, 0.5, c=r["c"]), abs=1e-7)
    meta = json.loads((tmp_path / "r.sweep.json").read_text())
    assert meta["points"] == 1_000_000 and meta["design"] == report.design.digest


class _Counted:
    """The tasks an executor takes, passed through and counted (`taken`)."""

    def __init__(self, tasks) -> None:
        self.tasks, self.taken = tasks, 0

    def __iter__(self):
        for task in self.tasks:
            self.taken += 1
            yield task


def test_the_local_pool_takes_at_most_one_point_ahead_of_its_workers(tmp_path, msd, monkeypatch):
    """2 workers: at most 3 points taken from the sweep before the first row (one per worker
    and the next, checked while they run). The points
    checked after the pool started (its copy of the model was pickled before) still run:
    the check's verdict travels with each point."""
    seen = {}

    class Spy(LocalExecutor):
        def run(self, models, tasks, outputs):
            counted = _Counted(tasks)
            for out in super().run(models, iter(counted), outputs):
                seen.setdefault("at first row", counted.taken)
                yield out

    report = run_sweep(MSD, tmp_path / "r.csv", params=[("k", "1,2,3,4,5,6,7,8")], t_end=0.5, executor=Spy(2),
                       progress=False, compiled=msd)
    assert seen["at first row"] <= 2 + 1
    rows = read_results(tmp_path / "r.csv")
    assert report.success and [r["point"] for r in rows] == list(range(8))
    for r in rows:
        assert r["success"] and r["attempts"] == 1, r
        assert r["x.final"] == pytest.approx(msd_x(r["k"], 0.5), abs=1e-7)


def test_dask_keeps_at_most_submit_ahead_points_in_flight(tmp_path, msd, monkeypatch):
    distributed = pytest.importorskip("distributed")
    import logging

    monkeypatch.setattr(executors, "SUBMIT_AHEAD", 2)
    flight = []

    class Spy(executors.DaskExecutor):
        def run(self, models, tasks, outputs):
            counted = _Counted(tasks)
            for n, out in enumerate(super().run(models, iter(counted), outputs)):
                flight.append(counted.taken - n)  # submitted, not yet returned (this row included)
                yield out

    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                                       silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    try:
        report = run_sweep(MSD, tmp_path / "r.csv", params=[("k", "1,2,3,4,5")], t_end=0.5,
                           executor=Spy(client=client), progress=False, compiled=msd)
    finally:
        client.close()
        cluster.close()
    assert report.success and len(flight) == 5 and max(flight) <= 2 + 1  # the next one goes before the row
    for r in read_results(tmp_path / "r.csv"):
        assert r["x.final"] == pytest.approx(msd_x(r["k"], 0.5), abs=1e-7)


# -- resume --------------------------------------------------------------------------------


def test_a_resumed_sweep_equals_an_uninterrupted_one(tmp_path, msd):
    common = dict(params=[("k", "1,2,3"), ("c", "0.3,-1,0.5"), ("m", "uniform:0.5:2")], samples=2, seed=5,
                  t_end=0.5, progress=False, compiled=msd)
    whole = tmp_path / "whole.csv"
    run_sweep(MSD, whole, executor=LocalExecutor(1), series=tmp_path / "whole-series.csv", **common)
    part = tmp_path / "part.csv"
    first = run_sweep(MSD, part, executor=InProcess(stop=5), series=tmp_path / "part-series.csv", **common)
    assert first.interrupted and 0 < len(first.rows) < 18
    report = run_sweep(MSD, part, executor=LocalExecutor(2), series=tmp_path / "part-series.csv", resume=True,
                       **common)
    assert report.complete and report.resumed == len(first.rows)
    a, b = read_results(whole), read_results(part)
    assert [r["point"] for r in b] == list(range(18))
    assert all(same(x, y) for x, y in zip(a, b)) and len(a) == len(b)
    assert sum(not r["success"] and "[PHC-E405]" in r["message"] for r in b) == 6  # c = -1, refused here
    series = [sorted(Path(p).read_text().splitlines()) for p in (tmp_path / "whole-series.csv",
                                                                 tmp_path / "part-series.csv")]
    assert series[0] == series[1] and len(series[0]) > 12


def test_nothing_to_run_starts_no_executor(tmp_path, msd, monkeypatch):
    """Resuming a finished sweep, or a sweep whose every point the model file refuses, runs
    nothing: no pool is started."""
    out = tmp_path / "r.csv"
    common = dict(params=[("k", "1,2")], t_end=0.5, progress=False, compiled=msd)
    run_sweep(MSD, out, executor=LocalExecutor(1), **common)

    def no_pool(self, *args, **kwargs):
        raise AssertionError("an executor was started")

    monkeypatch.setattr(LocalExecutor, "run", no_pool)
    report = run_sweep(MSD, out, resume=True, **common)
    assert report.success and report.resumed == 2
    spy = InProcess()
    report = run_sweep(MSD, tmp_path / "refused.csv", params=[("c", "-1,-2")], t_end=0.5, executor=spy,
                       progress=False, compiled=msd)
    assert spy.runs == 0 and report.complete and len(report.failed) == 2


def test_results_of_a_phc_that_recorded_every_point_are_refused_in_one_line(tmp_path, msd, capsys):
    out = tmp_path / "r.csv"
    argv = ["sweep", str(MSD), "--param", "k=1,2", "--t-end", "0.2", "--workers", "1", "--quiet", "--out", str(out)]
    assert main(argv) == 0
    meta_path = tmp_path / "r.sweep.json"
    meta = json.loads(meta_path.read_text())
    del meta["design"]
    meta_path.write_text(json.dumps(meta))
    capsys.readouterr()
    assert main([*argv, "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and "Traceback" not in err
    assert err.startswith(f"phc sweep: error: cannot resume `{out}`: its description does not record the design's "
                          "digest"), err
    with pytest.raises(SweepSetupError, match="--overwrite to start over"):
        run_sweep(MSD, out, params=[("k", "1,2")], t_end=0.2, resume=True, progress=False, compiled=msd)
