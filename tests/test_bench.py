"""`phc bench` (issue 7 item 2): a tiny work-precision sweep in CI.

The mass–spring–damper of models/mass_spring_damper.yaml (m = 1, k = 4, c = 0.4,
x(0) = 0.5, v(0) = 0) has the closed form x(t) = 0.5 e^{−0.2t}(cos ωt + (0.2/ω) sin ωt),
ω = √(k/m − (c/2m)²) = √3.96.
"""

from __future__ import annotations

import csv
import importlib.util
import math
from pathlib import Path

import pytest
import yaml

import phc
from phc.study.bench import run_bench

ROOT = Path(__file__).resolve().parents[1]
MSD = ROOT / "models" / "mass_spring_damper.yaml"
STRING = ROOT / "models" / "vibrating_string.yaml"
CLOSED_FORM = "0.5*exp(-0.2*t)*(cos(sqrt(3.96)*t) + 0.2/sqrt(3.96)*sin(sqrt(3.96)*t))"
HAVE_MPL = importlib.util.find_spec("matplotlib") is not None


def msd_scene(tmp_path: Path, reference: bool = True, name: str = "msd") -> Path:
    text = (f"format_version: 1\nmodel: {MSD}\nname: {name}\nt_end: 5.0\nn_out: 51\n"
            "outputs: {x: spring.x}\n")
    if reference:
        text += f"reference:\n  x: {CLOSED_FORM}\n"
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return path


def csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def table_rows(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines() if line.startswith("| ") and not line.startswith("| solver")]


def test_closed_form_matches_the_model_file():
    params = yaml.safe_load(MSD.read_text())
    values = {k: v["value"] for k, v in params["parameters"].items()}
    assert (values["m"], values["k"], values["c"]) == (1.0, 4.0, 0.4)
    assert params["simulation"]["initial"] == {"spring.x": 0.5, "mass.p": 0.0}
    zeta_omega = values["c"] / (2 * values["m"])
    assert math.isclose(zeta_omega, 0.2) and math.isclose(values["k"] / values["m"] - zeta_omega ** 2, 3.96)


def test_tiny_sweep_against_a_closed_form(tmp_path):
    report = run_bench(msd_scene(tmp_path), solvers=["ida", "midpoint"], tolerances=[1e-5, 1e-8],
                       steps=[0.1, 0.05], out_dir=tmp_path / "out", progress=False)
    assert not report.interrupted and report.success, report.render_text()
    assert report.reference == {"x": "closed form"} and not report.reference_settings
    assert len(report.rows) == 4
    rows = csv_rows(tmp_path / "out" / "bench.csv")
    assert len(rows) == 4 and [r["solver"] for r in rows] == ["ida", "ida", "midpoint", "midpoint"]
    assert len(table_rows(tmp_path / "out" / "bench.md")) == 4
    ida = [r for r in report.rows if r.solver == "ida"]
    assert ida[1].error < ida[0].error / 10  # tighter tolerance, smaller error
    mid = [r for r in report.rows if r.solver == "midpoint"]
    assert 3.5 < mid[0].error / mid[1].error < 4.5  # order 2: halving the step quarters the error
    assert all(r.energy_balance_relative < 1e-12 for r in mid)  # midpoint is energy-exact for quadratic H
    assert float(rows[0]["error_x"]) == pytest.approx(ida[0].error)
    if HAVE_MPL:
        assert (tmp_path / "out" / "bench.png").stat().st_size > 0 and "png" in report.paths
    else:
        assert "matplotlib" in report.plot_skipped
    text = report.render_text()
    assert "closed form: x" in text and "bench.csv" in text


def test_reference_run_is_cached(tmp_path):
    cache = tmp_path / "cache"
    scene = msd_scene(tmp_path, reference=False)
    kwargs = dict(solvers=["ida"], tolerances=[1e-6], out_dir=tmp_path / "out", reference_cache=cache,
                  progress=False, plot=False)
    first = run_bench(scene, **kwargs)
    assert first.reference == {"x": "reference run"} and not first.reference_cache_hit
    assert first.reference_settings["rtol"] <= 1e-8 and first.reference_cache_path.is_file()
    calls = []
    original = phc.simulate

    def counting(*args, **kw):
        calls.append(kw)
        return original(*args, **kw)

    import phc as phc_module
    phc_module.simulate, saved = counting, phc_module.simulate
    try:
        second = run_bench(scene, **kwargs)
    finally:
        phc_module.simulate = saved
    assert second.reference_cache_hit and len(calls) == 2  # only the swept point ran (and its untimed warm-up)
    assert second.rows[0].error == pytest.approx(first.rows[0].error)
    assert 0 < first.rows[0].error < 1e-4
    assert "cached" in second.render_text() and second.plot_skipped == "not requested"
    # another scene content is another key
    scene.write_text(scene.read_text().replace("n_out: 51", "n_out: 41"))
    third = run_bench(scene, **kwargs)
    assert not third.reference_cache_hit


def test_interrupt_keeps_the_finished_rows(tmp_path, monkeypatch):
    original = phc.simulate
    calls = []

    def interrupting(*args, **kw):
        calls.append(1)
        if len(calls) == 5:  # warm-up, ida ×2, warm-up, then the first midpoint point
            raise KeyboardInterrupt
        return original(*args, **kw)

    monkeypatch.setattr(phc, "simulate", interrupting)
    report = run_bench(msd_scene(tmp_path), solvers=["ida", "midpoint"], tolerances=[1e-5, 1e-8],
                       steps=[0.1, 0.05], out_dir=tmp_path, progress=False, plot=False)
    assert report.interrupted and not report.success
    assert len(report.rows) == 2 and report.planned == 4
    assert len(csv_rows(tmp_path / "bench.csv")) == 2
    assert "Interrupted" in (tmp_path / "bench.md").read_text()
    assert "INTERRUPTED" in report.render_text()


def test_a_failed_run_is_a_row(tmp_path):
    report = run_bench(msd_scene(tmp_path), solvers=["ida", "no_such_solver"], tolerances=[1e-6],
                       out_dir=tmp_path, progress=False, plot=False)
    assert [r.success for r in report.rows] == [True, False]
    assert "unknown solver" in report.rows[1].message and math.isnan(report.rows[1].error)
    assert "unknown solver" in csv_rows(tmp_path / "bench.csv")[1]["message"]


def test_a_mesh_out_of_range_is_a_located_failed_row(tmp_path):
    scene = tmp_path / "string.yaml"
    scene.write_text(f"format_version: 1\nmodel: {STRING}\nt_end: 0.003\nn_out: 31\n"
                     "outputs: {end_velocity: string.b.f}\n")
    report = run_bench(scene, solvers=["midpoint"], steps=[1e-4], meshes={"string": [300_000]},
                       out_dir=tmp_path / "out", reference_cache=False, progress=False, plot=False)
    (row,) = report.rows
    assert not row.success and row.message.startswith(f"compilation failed: {scene}:")
    assert "accuracy.mesh.string" in row.message and "200000" in row.message
    assert report.reference_message.startswith("the reference mesh does not compile")


def test_without_matplotlib_the_png_is_skipped(tmp_path, monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)  # makes the import fail
    report = run_bench(msd_scene(tmp_path), solvers=["ida"], tolerances=[1e-6], out_dir=tmp_path, progress=False)
    assert "matplotlib is not installed" in report.plot_skipped
    assert not (tmp_path / "bench.png").exists() and "png" not in report.paths
    assert "plot       skipped" in report.render_text()


def test_mesh_sweep_against_the_finest_mesh(tmp_path):
    scene = tmp_path / "string.yaml"
    scene.write_text(f"format_version: 1\nmodel: {STRING}\nt_end: 0.003\nn_out: 31\n"
                     "outputs: {end_velocity: string.b.f}\n")
    report = run_bench(scene, solvers=["ida"], tolerances=[1e-7], meshes={"string": [4, 8]},
                       out_dir=tmp_path / "out", reference_cache=tmp_path / "cache", progress=False, plot=False)
    assert report.success, report.render_text()
    assert report.reference_settings["mesh"] == {"string": 8}
    coarse, fine = report.rows
    assert (coarse.mesh, fine.mesh) == ({"string": 4}, {"string": 8})
    assert fine.error < coarse.error / 10  # the finest mesh differs from its reference only in time
    assert [r["mesh"] for r in csv_rows(tmp_path / "out" / "bench.csv")] == ["string=4", "string=8"]


def test_parse_meshes_and_repeats(tmp_path):
    from phc.study.bench import parse_meshes
    from phc.errors import SimulationSetupError
    assert parse_meshes(["rod=4,8", "beam=2", "rod=16"]) == {"rod": [4, 8, 16], "beam": [2]}
    for bad in ("rod", "rod=", "rod=a", "=4", "rod=0"):
        with pytest.raises(SimulationSetupError):
            parse_meshes([bad])
    report = run_bench(msd_scene(tmp_path), solvers=["midpoint"], steps=[0.1], repeats=3, out_dir=tmp_path,
                       progress=False, plot=False)
    row = report.rows[0]
    assert row.repeats == 3 and row.cpu_time_s <= row.cpu_time_median_s


def test_cli_bench_runs_a_tiny_sweep(tmp_path, capsys):
    from phc.cli import main

    scene = msd_scene(tmp_path)
    out = tmp_path / "cli"
    args = ["bench", str(scene), "--solver", "midpoint", "--step", "0.1", "--step", "0.05", "--quiet",
            "--no-plot", "--out-dir", str(out)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "closed form: x" in text and (out / "bench.csv").is_file() and (out / "bench.md").is_file()
    assert len(csv_rows(out / "bench.csv")) == 2
    assert main(args + ["--format", "json"]) == 0
    assert '"interrupted": false' in capsys.readouterr().out.replace("False", "false")
    # --target-error: finer steps until midpoint's error (~1e-3 at 0.05) is within 1e-4
    assert main(args + ["--target-error", "1e-4"]) == 0
    rows = csv_rows(out / "bench.csv")
    assert len(rows) > 2 and min(float(r["error_relative"]) for r in rows) <= 1e-4


def test_simulate_reports_the_error_against_a_scenes_closed_form(tmp_path, capsys):
    """`phc simulate` of a scene with `reference:` prints max |y − y_ref| per output (and the
    JSON summary carries it): the mass–spring–damper's x against its closed form."""
    import json

    import numpy as np

    from phc.cli import main

    scene = msd_scene(tmp_path)
    assert main(["simulate", str(scene), "--quiet", "--format", "json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    err = summary["reference_errors"]["x"]
    run = phc.simulate(phc.compile_model(scene))
    w = math.sqrt(3.96)
    exact = 0.5 * np.exp(-0.2 * run.t) * (np.cos(w * run.t) + 0.2 / w * np.sin(w * run.t))
    assert err["max"] == pytest.approx(np.abs(run["x"] - exact).max(), rel=1e-6, abs=1e-15)
    assert err["relative"] == pytest.approx(err["max"] / np.abs(exact).max(), rel=1e-6)
    assert 0 < err["max"] < 1e-4
    assert main(["simulate", str(scene), "--quiet"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("reference"))
    assert f"x {err['max']:.3e} (relative {err['relative']:.3e})" in line


def test_a_fixed_step_row_reports_the_step_taken(tmp_path):
    """The output interval (0.1 s) is split into equal steps no longer than asked: 0.04 gives
    three steps of 1/30 s. The row said 0.04, and the work-precision table then showed a
    wrong order."""
    report = run_bench(msd_scene(tmp_path), solvers=["midpoint"], steps=[0.04], out_dir=tmp_path / "out",
                       progress=False)
    (row,) = report.rows
    assert row.step == pytest.approx(0.1 / 3)
    assert float(csv_rows(tmp_path / "out" / "bench.csv")[0]["step"]) == pytest.approx(0.1 / 3)


def _row(solver, *, rtol=None, step=None, steps=0, cpu=0.0, error=1.0):
    from phc.study.bench import BenchRow

    row = BenchRow(solver, {}, rtol=rtol, atol=None if rtol is None else rtol / 100, step=step, success=True,
                   steps=steps, cpu_time_s=cpu)
    row.errors = {"x": error}
    row.relative_errors = {"x": error}
    return row


def test_the_work_check_flags_a_looser_setting_that_costs_more():
    """Issue 33: a looser tolerance is never slower. A looser rtol with more steps than a
    tighter one (beyond the noise factor) is flagged, also when the trap is not next to its
    neighbour; equal work within the noise is not; nor is a fixed step or another solver."""
    from phc.study.bench import CPU_FLOOR_S, CPU_NOISE, STEPS_NOISE, work_flags

    rows = [_row("ida", rtol=1e-4, steps=1500, cpu=0.10), _row("ida", rtol=1e-6, steps=1000, cpu=0.09),
            _row("ida", rtol=1e-8, steps=1300, cpu=0.12),
            _row("midpoint", step=0.1, steps=10, cpu=0.05), _row("midpoint", step=0.05, steps=20, cpu=0.04)]
    flags = work_flags(rows)
    assert [(f.looser, f.tighter, f.what) for f in flags] == [("rtol 0.0001", "rtol 1e-06", "steps"),
                                                              ("rtol 0.0001", "rtol 1e-08", "steps")]
    assert "1500 steps" in flags[0].text() and "(1.50×)" in flags[0].text()
    # within the noise: not flagged
    rows = [_row("ida", rtol=1e-4, steps=int(1000 * STEPS_NOISE), cpu=0.1), _row("ida", rtol=1e-6, steps=1000, cpu=0.1)]
    assert work_flags(rows) == []
    # CPU: beyond the factor and the floor both
    slow = 0.1 * CPU_NOISE + CPU_FLOOR_S
    rows = [_row("ida", rtol=1e-4, steps=10, cpu=slow * 1.01), _row("ida", rtol=1e-6, steps=10, cpu=0.1)]
    assert [f.what for f in work_flags(rows)] == ["CPU"]
    rows = [_row("ida", rtol=1e-4, steps=10, cpu=0.004), _row("ida", rtol=1e-6, steps=10, cpu=0.001)]
    assert work_flags(rows) == []  # 4× but 3 ms: timer noise
    failed = _row("ida", rtol=1e-4, steps=5000)
    failed.success = False
    assert work_flags([failed, _row("ida", rtol=1e-6, steps=10)]) == []


def test_the_pareto_front():
    from phc.study.bench import pareto_front

    rows = [_row("ida", rtol=1e-4, cpu=1.0, error=1e-4), _row("ida", rtol=1e-6, cpu=2.0, error=1e-6),
            _row("midpoint", step=0.1, cpu=1.5, error=1e-3),   # slower and less accurate than the first
            _row("midpoint4", step=0.1, cpu=0.5, error=1e-2),  # fastest
            _row("midpoint4", step=0.05, cpu=2.0, error=1e-6)]  # ties the second: both stay
    assert pareto_front(rows) == [0, 1, 3, 4]


def test_a_fixed_step_reference_cross_checked_by_ida(tmp_path):
    """The mass–spring–damper without its closed form: the reference is midpoint4 at the
    finest step / 16, cross-checked by IDA at rtol 1e-10. Both are within ~1e-9 of the
    closed form (midpoint4 at h = 0.1/16: error ~ (ωh)⁴/... ≈ 1e-9; IDA at 1e-10), so their gap
    is below 1e-7, and the rows' errors against it agree with the errors against the closed
    form to that gap."""
    cache = tmp_path / "cache"
    closed = run_bench(msd_scene(tmp_path, name="closed"), solvers=["ida", "midpoint"], tolerances=[1e-5],
                       steps=[0.1], out_dir=tmp_path / "a", progress=False, plot=False, reference_cache=cache)
    ref = run_bench(msd_scene(tmp_path, reference=False), solvers=["ida", "midpoint"], tolerances=[1e-5],
                    steps=[0.1], out_dir=tmp_path / "b", progress=False, plot=False, reference_cache=cache,
                    reference_solver="midpoint4", cross_check=True)
    assert ref.reference_settings["solver"] == "midpoint4"
    assert ref.reference_settings["step"] == pytest.approx(0.1 / 16)
    assert ref.reference_check["solver"] == "ida" and ref.reference_check["rtol"] == pytest.approx(1e-10)
    gap = ref.reference_gap["x"]
    assert 0 < gap < 1e-7
    for a, b in zip(closed.rows, ref.rows):
        assert b.error_relative == pytest.approx(a.error_relative, abs=2 * gap)
    text = (tmp_path / "b" / "bench.md").read_text()
    assert "Cross-check: a second reference run (ida rtol 1.0e-10" in text and "Work check" in text
    assert "agrees with ida rtol 1.0e-10" in ref.render_text()


def test_the_next_finer_step_follows_the_measured_order():
    """Issue 33: the fixed-step sweep's steps come from the accuracy asked for. Rows with the
    error of an order-4 method (err = h⁴) at 0.1 and 0.05: to reach 1e-8 from 0.05⁴ = 6.25e-6
    takes a factor (625)^(1/4) = 5 in h, three halvings (2³ = 8 ≥ 5; two give 4 < 5); an order-2
    method (err = h²) at 0.05, 2.5e-3, needs 500^(1/2) ≈ 22: capped at three halvings at once.
    Done when the target is reached; stopped when the error stalls, a finer step failed, or the
    budget in steps or CPU time is spent."""
    from phc.study.bench import EXTEND_MAX_CPU_S, EXTEND_MAX_HALVINGS, next_finer_step

    def rows(order, steps, cpu=0.01):
        return [_row("midpoint", step=h, cpu=cpu, error=h ** order) for h in steps]

    assert next_finer_step(rows(4, [0.1, 0.05]), 1e-8, 0.05) == pytest.approx(0.05 / 8)
    assert next_finer_step(rows(4, [0.1, 0.05]), 2e-6, 0.05) == pytest.approx(0.025)  # (3.1)^(1/4) < 2: one
    assert next_finer_step(rows(2, [0.1, 0.05]), 1e-8, 0.05) == pytest.approx(0.05 / 8)
    assert next_finer_step(rows(4, [0.05]), 1e-8, 0.05) == pytest.approx(0.025)  # one row: halve
    assert next_finer_step(rows(4, [0.1, 0.05]), 1e-5, 0.05) is None  # reached
    stalled = rows(4, [0.1, 0.05]) + [_row("midpoint", step=0.025, cpu=0.01, error=0.05 ** 4 * 0.9)]
    assert next_finer_step(stalled, 1e-8, 0.05) is None  # a halving bought < 2^0.5: round-off or the reference
    failed = rows(4, [0.1, 0.05, 0.025])
    failed[-1].success = False
    assert next_finer_step(failed, 1e-8, 0.05) is None
    floor = 0.05 / 2 ** EXTEND_MAX_HALVINGS
    assert next_finer_step(rows(2, [2 * floor, floor]), 1e-12, 0.05) is None  # no finer than the budget
    assert next_finer_step(rows(2, [4 * floor, 2 * floor]), 1e-12, 0.05) == pytest.approx(floor)  # up to it
    slow = EXTEND_MAX_CPU_S / 3  # one halving doubles the time: 2/3 of the budget fits, 4/3 does not
    assert next_finer_step(rows(4, [0.1, 0.05], cpu=slow), 1e-8, 0.05) == pytest.approx(0.025)
    assert next_finer_step(rows(4, [0.1, 0.05], cpu=slow), 1e-8, 0.05, repeats=2) is None


def test_a_fixed_step_sweep_goes_on_until_the_target_is_reached(tmp_path):
    """The mass–spring–damper against its closed form: midpoint listed at 0.1 and 0.05 only
    (relative error ~1e-3) goes on to finer steps until one reaches 1e-6 — order 2 from ~1e-3
    needs ~30× in h, more than the listed steps — and the finest added row is the first to
    reach it; without a target only the listed steps run."""
    report = run_bench(msd_scene(tmp_path), solvers=["midpoint"], steps=[0.1, 0.05], out_dir=tmp_path / "out",
                       progress=False, plot=False, target_error=1e-6)
    assert report.success, report.render_text()
    mid = sorted(report.rows, key=lambda r: -r.step)
    assert len(mid) > 2 and mid[1].error_relative > 1e-4
    assert mid[-1].error_relative <= 1e-6 < mid[-2].error_relative
    assert all(a.error_relative > b.error_relative for a, b in zip(mid, mid[1:]))
    plain = run_bench(msd_scene(tmp_path), solvers=["midpoint"], steps=[0.1, 0.05], out_dir=tmp_path / "o2",
                      progress=False, plot=False)
    assert len(plain.rows) == 2
