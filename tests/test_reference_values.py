"""Reference values (a published reference solution as data) in `phc bench` (issue 17 item 3).

The mass–spring–damper of models/mass_spring_damper.yaml (m = 1, k = 4, c = 0.4,
x(0) = 0.5, v(0) = 0) has the closed form x(t) = 0.5 e^{−0.2t}(cos ωt + (0.2/ω) sin ωt),
ω = √3.96 (tests/test_bench.py checks it against the model file). Written into a CSV at
times off the output grid, the errors `phc bench` reports against it must be the errors
computed directly from a run that outputs at those times.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.study.bench import run_bench
from phc.errors import ModelError, SimulationSetupError

ROOT = Path(__file__).resolve().parents[1]
MSD = ROOT / "models" / "mass_spring_damper.yaml"
OMEGA = math.sqrt(3.96)
TIMES = [0.37, 1.234, 2.0, 4.9]  # 0.37, 1.234, 4.9 are off the 0.1 grid


def x_exact(t):
    t = np.asarray(t, dtype=float)
    return 0.5 * np.exp(-0.2 * t) * (np.cos(OMEGA * t) + 0.2 / OMEGA * np.sin(OMEGA * t))


def scene(tmp_path: Path, reference_values: str, extra: str = "") -> Path:
    shutil.copy(MSD, tmp_path / "msd_model.yaml")
    path = tmp_path / "msd.yaml"
    path.write_text("format_version: 1\nmodel: msd_model.yaml\nname: msd\nt_end: 5.0\nn_out: 51\n"
                    "outputs: {x: spring.x, v: mass.p}\n" + extra + reference_values)
    return path


def write_csv(tmp_path: Path, text: str, name: str = "ref.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def closed_form_csv(tmp_path: Path) -> Path:
    lines = ["# x(t) of the mass-spring-damper in closed form (a stand-in for a published solution)", "t,x"]
    lines += [f"{t!r},{x!r}" for t, x in zip(TIMES, x_exact(TIMES).tolist())]
    return write_csv(tmp_path, "\n".join(lines) + "\n")


def located(err: ModelError) -> list[str]:
    return [d.render() for d in err.diagnostics]


def test_errors_against_a_file_equal_the_directly_computed_ones(tmp_path):
    closed_form_csv(tmp_path)
    path = scene(tmp_path, "reference_values: {file: ref.csv, source: closed form}\n",
                 extra='reference: {v: "0*t"}\n')  # v keeps its own (wrong, but closed-form) reference
    report = run_bench(path, solvers=["ida", "midpoint"], tolerances=[1e-6], steps=[0.1, 0.05],
                       out_dir=tmp_path / "out", progress=False, plot=False, reference_cache=False)
    assert report.success, report.render_text()
    assert report.reference == {"x": "published reference (ref.csv, 4 points)", "v": "closed form"}
    assert not report.reference_settings  # no reference run was needed
    compiled = phc.compile_model(path)
    t_run = np.union1d(np.linspace(0, 5, 51), TIMES)
    for row in report.rows:
        kw = dict(step=row.step) if row.fixed_step else dict(rtol=row.rtol, atol=row.atol)
        res = phc.simulate(compiled, solver=row.solver, t_eval=t_run, **kw)
        at = np.searchsorted(res.t, TIMES)
        assert np.allclose(res.t[at], TIMES, rtol=0, atol=1e-15)  # the run output exactly there
        direct = np.max(np.abs(res.outputs["x"][at] - x_exact(TIMES)))
        assert row.errors["x"] == pytest.approx(direct, rel=1e-9, abs=1e-15)
        assert row.relative_errors["x"] == pytest.approx(direct / np.max(np.abs(x_exact(TIMES))), rel=1e-9)
        grid = np.isin(res.t, np.linspace(0, 5, 51))  # v's closed form on the output grid only
        assert row.errors["v"] == pytest.approx(np.max(np.abs(res.outputs["v"][grid])), rel=1e-9)
        assert 0 < row.errors["x"] < 0.02
    mid = [r for r in report.rows if r.solver == "midpoint"]
    assert 3.5 < mid[0].errors["x"] / mid[1].errors["x"] < 4.5  # order 2 at the published times too
    md = (tmp_path / "out" / "bench.md").read_text()
    assert "published reference (ref.csv, 4 points)" in md and "Source: closed form." in md
    assert "max over the output grid" in md and "max over its reference times" in md
    assert "Relative error per output" in md
    assert "published reference (ref.csv, 4 points): x" in report.render_text()


def test_inline_values_and_the_command_line_file(tmp_path, capsys):
    t = ", ".join(repr(v) for v in TIMES)
    x = ", ".join(repr(v) for v in x_exact(TIMES).tolist())
    path = scene(tmp_path, f"reference_values:\n  t: [{t}]\n  values: {{x: [{x}]}}\n")
    kwargs = dict(solvers=["midpoint"], steps=[0.1], out_dir=tmp_path / "out", progress=False, plot=False,
                  outputs=["x"])
    inline = run_bench(path, **kwargs)
    assert inline.reference == {"x": "published reference (inline, 4 points)"}
    # the same values from a file on the command line replace the scene's (here: one time left empty)
    csv_path = write_csv(tmp_path, "t,x\n" + "".join(
        f"{ti!r},{xi!r}\n" if i != 1 else f"{ti!r},\n" for i, (ti, xi) in enumerate(zip(TIMES, x_exact(TIMES).tolist()))),
        "other.csv")
    other = run_bench(path, reference=csv_path, **kwargs)
    assert other.reference == {"x": "published reference (" + str(csv_path) + ", 3 points)"}
    three = [0, 2, 3]
    res = phc.simulate(phc.compile_model(path), solver="midpoint", step=0.1,
                       t_eval=np.union1d(np.linspace(0, 5, 51), TIMES))
    at = np.searchsorted(res.t, TIMES)
    direct = np.abs(res.outputs["x"][at] - x_exact(TIMES))
    assert inline.rows[0].errors["x"] == pytest.approx(direct.max(), rel=1e-9)
    assert other.rows[0].errors["x"] == pytest.approx(direct[three].max(), rel=1e-9)  # the run still stops at 1.234
    from phc.cli import main
    assert main(["bench", str(path), "--solver", "midpoint", "--step", "0.1", "--output", "x", "--quiet",
                 "--no-plot", "--out-dir", str(tmp_path / "cli"), "--reference", str(csv_path)]) == 0
    assert f"published reference ({csv_path}, 3 points): x" in capsys.readouterr().out


@pytest.mark.parametrize("csv_text, where, words", [
    ("t,xx\n0.5,1\n", (1, 3), ["`xx`, which is not a requested output", "did you mean `x`?"]),
    ("# source\nt,x\n0.5,1\n7.5,2\n", (4, 1), ["reference time 7.5 lies outside the run (0 to 5)"]),
    ("t,x\n0.5,1\n0.7,abc\n", (3, 5), ["cell of column `x` is not a number"]),
    ("t,x\n0.5,1\n0.4,2\n", (3, 1), ["must increase strictly"]),
    ("t,x\n0.5,1,3\n", (2, 1), ["this row has 3 cells, the header 2"]),
    ("time,x\n0.5,1\n", (1, 1), ["no time column `t`"]),
    ("t,x\n0.5,nan\n", (2, 5), ["must be finite"]),
    ("t,x\n0.5,\n", (1, 3), ["`x` has no reference value"]),
])
def test_a_bad_file_is_a_located_error(tmp_path, csv_text, where, words):
    write_csv(tmp_path, csv_text)
    path = scene(tmp_path, "reference_values: {file: ref.csv}\n")
    with pytest.raises(ModelError) as err:
        phc.compile_model(path)
    (line,) = located(err.value)
    assert line.startswith(f"{tmp_path / 'ref.csv'}:{where[0]}:{where[1]}: ") and line.endswith("[PHC-E607]")
    for w in words:
        assert w in line
    # the same file on the command line: the same located error
    ok = scene(tmp_path, "")
    with pytest.raises(ModelError) as err2:
        run_bench(ok, reference=tmp_path / "ref.csv", solvers=["midpoint"], steps=[0.1], out_dir=tmp_path,
                  progress=False, plot=False)
    assert located(err2.value) == [line]


def test_bad_scene_entries_are_located(tmp_path):
    path = scene(tmp_path, "reference_values: {file: missing.csv}\n")
    with pytest.raises(ModelError) as err:
        phc.compile_model(path)
    (line,) = located(err.value)
    assert line.startswith(f"{path}:7:26: ") and "reference values `missing.csv` not found" in line

    (tmp_path / "sub").mkdir()
    outside = scene(tmp_path / "sub", "reference_values: {file: ../../ref.csv}\n")
    write_csv(tmp_path.parent, "t,x\n1,1\n", "ref.csv")
    with pytest.raises(ModelError) as err:
        phc.compile_model(outside)
    assert "lies outside the directory" in located(err.value)[0] and "[PHC-E116]" not in located(err.value)[0]

    path = scene(tmp_path, "reference_values:\n  t: [0.5, 9.0]\n  values: {x: [1, 2]}\n")
    with pytest.raises(ModelError) as err:
        phc.compile_model(path)
    assert located(err.value)[0].startswith(f"{path}:8:12: reference time 9 lies outside the run")

    path = scene(tmp_path, "reference_values:\n  t: [0.5, 1.0]\n  values: {x: [1]}\n")
    with pytest.raises(ModelError) as err:
        phc.compile_model(path)
    assert located(err.value)[0].startswith(f"{path}:9:15: `x` has 1 value, `t` has 2")

    path = scene(tmp_path, "reference_values: {file: ref.csv, t: [1.0]}\n")
    with pytest.raises(ModelError) as err:
        phc.compile_model(path)
    assert "give either `file`" in located(err.value)[0] and located(err.value)[0].startswith(f"{path}:7:")

    write_csv(tmp_path, "t,x\n1,1\n")
    path = scene(tmp_path, "reference_values: {file: ref.csv}\n", extra='reference: {x: "0*t"}\n')
    with pytest.raises(ModelError) as err:
        phc.compile_model(path)
    assert "both a closed form (`reference`) and reference values" in located(err.value)[0]


def test_an_unreadable_command_line_file_is_a_usage_error(tmp_path):
    path = scene(tmp_path, "")
    with pytest.raises(SimulationSetupError, match="--reference: cannot read reference values"):
        run_bench(path, reference=tmp_path / "nope.csv", solvers=["midpoint"], steps=[0.1], out_dir=tmp_path,
                  progress=False, plot=False)
