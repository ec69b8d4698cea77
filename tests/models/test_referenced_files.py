"""Files a model refers to (nested models, CSV tables, `.npz` matrices) are untrusted input.

They must stay inside the directory of the top-level file unless allowed (`--allow-path`,
`PHC_ALLOW_PATH`), be regular files of bounded size, never have their content quoted in a
message, never hang or exhaust the process, and never crash it (exit by a signal).
Everything ends in a located `file:line:col: ... [PHC-Exxx]` line and exit code 1.
"""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.frontend import files as phc_files
from phc.frontend import inputs
from phc.cli import main
from phc.errors import ModelError
from phc.frontend.elaborate import Reporter
from time_limits import SUBPROCESS_TIMEOUT

SECRET = "hunter2-s3cr3t-value"

MASS_WITH_TABLE = """format_version: 1
components:
  mass: {{type: mass, m: 1.0}}
ports:
  force: {{port: mass.port}}
simulation:
  t_end: {t_end}
  n_out: 101
  inputs:
    force: {{effort: {{file: {file}, column: {column}{extra}}}}}
  outputs: {{p: mass.p}}
"""

LEAF = """format_version: 1
parameters: {k: 1.0}
components:
  s: {type: spring, k: k}
ports:
  p: {port: s.port}
"""


def table_model(folder: Path, file: str, column: str = "F", name: str = "model.yaml", t_end: float = 1.0,
                extra: str = "") -> Path:
    path = folder / name
    path.write_text(MASS_WITH_TABLE.format(file=file, column=column, t_end=t_end, extra=extra))
    return path


def nested_model(folder: Path, file: str, name: str = "model.yaml") -> Path:
    path = folder / name
    path.write_text("format_version: 1\ncomponents:\n  m: {type: mass, m: 1.0}\n"
                    f"  sub: {{type: model, file: '{file}'}}\nconnections:\n  - [m.port, sub.p]\n")
    return path


def npz_model(folder: Path, npz: str, name: str, J: str = "J", states: int = 2) -> Path:
    path = folder / name
    path.write_text(f"""format_version: 1
components:
  lin:
    type: linear_phs
    states: {states}
    matrices: {npz}
    J: {J}
    ports:
      tip: {{B: [[0], [1]], domain: mechanical.translational}}
  free: {{type: zero_effort, domain: mechanical.translational}}
connections:
  - [lin.tip, free.port]
""")
    return path


def validate(capsys, *args) -> tuple[int, str]:
    code = main(["validate", *map(str, args)])
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert "Traceback" not in text and "internal error" not in text, text
    return code, text


def run_cli(args, timeout: float = 60, env=None) -> subprocess.CompletedProcess:
    """`phc ARGS` in a subprocess: a hang fails by timeout, a crash shows as returncode < 0."""
    return subprocess.run([sys.executable, "-m", "phc", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, **(env or {})})


@pytest.fixture
def alarm():
    """Fail (instead of hanging forever) if the test body blocks for 20 s."""
    def _timeout(signum, frame):
        raise TimeoutError("blocked: a read of a referenced file did not return")
    previous = signal.signal(signal.SIGALRM, _timeout)
    signal.alarm(20)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


# -- containment ------------------------------------------------------------------------

def _outside_tree(tmp_path) -> tuple[Path, Path]:
    """(project dir, a dir beside it) with a secret table and a model beside the project."""
    project, other = tmp_path / "project", tmp_path / "other"
    project.mkdir()
    other.mkdir()
    (other / "secret.csv").write_text(f"t,F\n0,{SECRET}\n")
    (other / "leaf.yaml").write_text(LEAF)
    return project, other


@pytest.mark.parametrize("how", ["dotdot", "absolute", "symlink", "symlinked_dir"])
def test_table_outside_the_tree_is_refused(tmp_path, capsys, how):
    project, other = _outside_tree(tmp_path)
    ref = {"dotdot": "../other/secret.csv", "absolute": str(other / "secret.csv"), "symlink": "link.csv",
           "symlinked_dir": "data/secret.csv"}[how]
    (project / "link.csv").symlink_to(other / "secret.csv")
    (project / "data").symlink_to(other, target_is_directory=True)
    model = table_model(project, ref)
    code, text = validate(capsys, model)
    assert code == 1
    assert f"{model}:10:28: simulation.inputs.force.effort.file: table `{ref}` lies outside the directory " \
           "of the top-level file" in text
    assert "--allow-path DIR" in text and "[PHC-E116]" in text
    assert SECRET not in text


@pytest.mark.parametrize("how", ["dotdot", "absolute", "symlink"])
def test_nested_model_outside_the_tree_is_refused(tmp_path, capsys, how):
    project, other = _outside_tree(tmp_path)
    ref = {"dotdot": "../other/leaf.yaml", "absolute": str(other / "leaf.yaml"), "symlink": "leaf.yaml"}[how]
    (project / "leaf.yaml").symlink_to(other / "leaf.yaml")
    model = nested_model(project, ref)
    code, text = validate(capsys, model)
    assert code == 1
    assert f"{model}:4:28: components.sub.file: nested model file `{ref}` lies outside" in text
    assert "[PHC-E116]" in text


def test_etc_passwd_is_neither_read_nor_quoted(tmp_path, capsys):
    model = nested_model(tmp_path, "../../../../../../../../../../etc/passwd")
    code, text = validate(capsys, model)
    assert code == 1 and "[PHC-E116]" in text
    assert "root:" not in text
    table = table_model(tmp_path, "/etc/passwd", name="t.yaml")
    code, text = validate(capsys, table)
    assert code == 1 and "[PHC-E116]" in text and "root:" not in text


def test_outside_is_refused_before_existence_is_checked(tmp_path, capsys):
    """A model cannot probe which files exist outside its tree: same message either way."""
    project, _ = _outside_tree(tmp_path)
    exists = table_model(project, "../other/secret.csv", name="a.yaml")
    missing = table_model(project, "../other/nothing.csv", name="b.yaml")
    _, text_a = validate(capsys, exists)
    _, text_b = validate(capsys, missing)
    assert "lies outside" in text_a and "lies outside" in text_b
    assert "not found" not in text_b


def test_allow_path_and_environment_allow_a_directory(tmp_path, capsys, monkeypatch):
    project, other = _outside_tree(tmp_path)
    (other / "force.csv").write_text("t,F\n0,0\n1,2\n")
    (project / "link.csv").symlink_to(other / "force.csv")
    for ref in ("../other/force.csv", str(other / "force.csv"), "link.csv"):
        model = table_model(project, ref)
        assert validate(capsys, model)[0] == 1
        code, text = validate(capsys, model, "--allow-path", other)
        assert code == 0, text
        monkeypatch.setenv("PHC_ALLOW_PATH", os.pathsep.join([str(tmp_path / "nowhere"), str(other)]))
        assert validate(capsys, model)[0] == 0
        monkeypatch.delenv("PHC_ALLOW_PATH")
    nested = nested_model(project, "../other/leaf.yaml", name="nested.yaml")
    assert validate(capsys, nested)[0] == 1
    assert validate(capsys, nested, "--allow-path", other)[0] == 0
    # and the Python API
    with pytest.raises(ModelError):
        phc.compile_model(nested)
    with phc_files.allow_paths([other]):
        dae, diags = phc.build_dae(nested)
    assert dae is not None and not diags.has_errors


def test_allow_path_must_name_a_directory(tmp_path, capsys):
    model = table_model(tmp_path, "x.csv")
    assert main(["validate", str(model), "--allow-path", str(tmp_path / "missing")]) == 2
    assert "--allow-path" in capsys.readouterr().err


def test_files_inside_the_tree_still_work(tmp_path, capsys):
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "force.csv").write_text("t,F\n0,0\n1,2\n")
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "leaf.yaml").write_text(LEAF)
    (tmp_path / "alias.csv").symlink_to(tmp_path / "data" / "force.csv")  # a symlink inside the tree
    assert validate(capsys, table_model(tmp_path, "data/force.csv"))[0] == 0
    assert validate(capsys, table_model(tmp_path, "alias.csv", name="b.yaml"))[0] == 0
    assert validate(capsys, nested_model(tmp_path, "parts/leaf.yaml", name="c.yaml"))[0] == 0


def test_a_scene_may_use_files_of_its_model_and_its_own_directory(tmp_path, capsys):
    (tmp_path / "scenes").mkdir()
    (tmp_path / "force.csv").write_text("t,F\n0,0\n1,2\n")
    table_model(tmp_path, "force.csv")
    (tmp_path / "scenes" / "scene_force.csv").write_text("t,F\n0,0\n1,-2\n")
    (tmp_path / "scenes" / "s.yaml").write_text("model: ../model.yaml\noutputs: {p: mass.p}\n")
    assert validate(capsys, tmp_path / "scenes" / "s.yaml")[0] == 0
    # a table named in the scene is relative to the scene
    (tmp_path / "scenes" / "s2.yaml").write_text(
        "model: ../model.yaml\noutputs: {p: mass.p}\ninputs:\n  force: {effort: {file: scene_force.csv, column: F}}\n")
    code, text = validate(capsys, tmp_path / "scenes" / "s2.yaml")
    assert code == 0, text


# -- only regular files, read without blocking ----------------------------------------

def test_fifos_are_refused_without_blocking(tmp_path):
    os.mkfifo(tmp_path / "pipe.csv")
    os.mkfifo(tmp_path / "pipe.npz")
    os.mkfifo(tmp_path / "pipe.yaml")
    models = [table_model(tmp_path, "pipe.csv", name="t.yaml"), npz_model(tmp_path, "pipe.npz", "n.yaml"),
              nested_model(tmp_path, "pipe.yaml", name="m.yaml")]
    # reading a FIFO without a writer blocks forever: the timeout only turns such a hang into a
    # failure (TimeoutExpired); nothing is timed, so it is generous for a loaded machine
    proc = run_cli(["validate", *models], timeout=600)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.splitlines()
    for model, key in zip(models, ("simulation.inputs.force.effort.file", "components.lin.matrices",
                                   "components.sub.file")):
        assert any(line.startswith(f"{model}:") and key in line and "is a FIFO (named pipe)" in line
                   and line.endswith("[PHC-E116]") for line in lines), proc.stderr


def test_a_fifo_swapped_in_after_the_check_does_not_hang(tmp_path, alarm):
    """`open` is non-blocking and checks the opened descriptor (fstat), not the name."""
    os.mkfifo(tmp_path / "pipe.csv")
    access = phc_files.FileAccess([tmp_path])
    with pytest.raises(phc_files.FileRefused, match="FIFO"):
        access.read_bytes(tmp_path / "pipe.csv", "pipe.csv", "table")


def test_dev_zero_is_refused(tmp_path, capsys):
    (tmp_path / "zero.csv").symlink_to("/dev/zero")
    model = table_model(tmp_path, "zero.csv")
    code, text = validate(capsys, model)
    assert code == 1 and "lies outside" in text
    code, text = validate(capsys, model, "--allow-path", "/dev")
    assert code == 1 and "table `zero.csv` is a character device; phc reads only regular files" in text
    code, text = validate(capsys, table_model(tmp_path, "/dev/zero", name="b.yaml"), "--allow-path", "/dev")
    assert code == 1 and "character device" in text


def test_directories_are_refused(tmp_path, capsys):
    (tmp_path / "dir.csv").mkdir()
    code, text = validate(capsys, table_model(tmp_path, "dir.csv"))
    assert code == 1 and "is a directory" in text and "[PHC-E116]" in text


def test_size_limits(tmp_path, capsys, monkeypatch):
    (tmp_path / "force.csv").write_text("t,F\n" + "".join(f"{i},{i}\n" for i in range(2000)))
    model = table_model(tmp_path, "force.csv")
    assert validate(capsys, model)[0] == 0
    monkeypatch.setenv("PHC_MAX_TABLE_MB", "0.01")  # 10485 bytes; the table has 17784
    code, text = validate(capsys, model)
    assert code == 1 and "is 17784 bytes, above the limit of 10485 bytes" in text and "PHC_MAX_TABLE_MB" in text
    assert phc_files.size_limit("table") == 10485  # 0.01 MiB
    monkeypatch.setenv("PHC_MAX_TABLE_MB", "nonsense")
    assert phc_files.size_limit("table") == phc_files.SIZE_LIMITS["table"]


# -- table content never leaks ---------------------------------------------------------

def test_secret_looking_csv_content_is_never_quoted(tmp_path, capsys):
    (tmp_path / "creds.csv").write_text(f"AWS_SECRET_ACCESS_KEY={SECRET},DB_PASSWORD={SECRET}\n1,2\n")
    (tmp_path / "passwd.csv").write_text(f"root:x:0:0:{SECRET}:/root:/bin/bash\nbin:x:1:1\n")
    (tmp_path / "words.csv").write_text(f"t,password\n0,{SECRET}\n")
    (tmp_path / "binary.csv").write_bytes(b"t,F\n\xff\xfe" + SECRET.encode() + b"\n")
    for i, (file, column) in enumerate([("creds.csv", "F"), ("passwd.csv", "F"), ("words.csv", "password"),
                                        ("words.csv", "F"), ("binary.csv", "F")]):
        code, text = validate(capsys, table_model(tmp_path, file, column, name=f"m{i}.yaml"))
        assert code == 1 and "[PHC-E213]" in text
        assert SECRET not in text and "AWS_SECRET" not in text and "root:x" not in text, text


def test_header_names_are_shown_when_they_parsed_as_a_header(tmp_path, capsys):
    (tmp_path / "force.csv").write_text("t,Force\n0,0\n1,2\n")
    code, text = validate(capsys, table_model(tmp_path, "force.csv", "force"))
    assert code == 1
    assert "table `force.csv` has no column `force`; its columns: t, Force (did you mean `Force`?)" in text


def test_a_field_longer_than_the_csv_limit_is_a_located_error(tmp_path, capsys):
    (tmp_path / "long.csv").write_text("t,F\n0," + "7" * 200_000 + "\n")
    code, text = validate(capsys, table_model(tmp_path, "long.csv"))
    assert code == 1
    assert "model.yaml:10:28: simulation.inputs.force.effort.file: table `long.csv` line 2: a field is longer " \
           "than 131072 characters" in text
    assert "7777" not in text


def test_too_many_rows(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(inputs, "MAX_TABLE_ROWS", 100)
    (tmp_path / "rows.csv").write_text("t,F\n" + "".join(f"{i},{i}\n" for i in range(101)))
    code, text = validate(capsys, table_model(tmp_path, "rows.csv"))
    assert code == 1 and "table `rows.csv` has more than 100 data rows" in text


def test_row_errors_name_the_row_not_the_content(tmp_path, capsys):
    (tmp_path / "bad.csv").write_text(f"t,F\n0,1\n\n1,{SECRET}\n")
    code, text = validate(capsys, table_model(tmp_path, "bad.csv"))
    assert code == 1 and "table `bad.csv` row 3: `t` and `F` must be numbers" in text and SECRET not in text
    (tmp_path / "order.csv").write_text("t,F\n0,1\n2,1\n1,1\n")
    code, text = validate(capsys, table_model(tmp_path, "order.csv", name="b.yaml"))
    assert code == 1 and "row 4: column `t` must increase strictly" in text
    (tmp_path / "nan.csv").write_text("t,F\n0,1\n1,nan\n")
    code, text = validate(capsys, table_model(tmp_path, "nan.csv", name="c.yaml"))
    assert code == 1 and "row 3: values must be finite" in text


# -- breakpoints of tables ---------------------------------------------------------------

def test_zero_order_hold_breakpoints_are_its_jumps():
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    v = np.array([1.0, 1.0, 2.0, 2.0, 0.0])
    assert inputs.table_breakpoints(t, v, "previous") == ([2.0, 4.0], 0)


def test_linear_breakpoints_are_its_kinks_up_to_a_cap():
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    v = np.array([0.0, 1.0, 2.0, 2.0, 2.0])  # ramp, collinear row at 1, kink at 2, flat after
    assert inputs.table_breakpoints(t, v, "linear") == ([0.0, 2.0], 2)  # the ramp starts from a hold at 0
    n = inputs.MAX_KINK_BREAKPOINTS + 1
    t = np.arange(n + 2, dtype=float)
    v = (np.arange(n + 2) % 2).astype(float)  # a zigzag: every interior row is a kink, ends too
    points, kinks = inputs.table_breakpoints(t, v, "linear")
    assert points == [] and kinks == n + 2
    ramp = np.linspace(0.0, 1.0, 100_000)
    assert inputs.table_breakpoints(ramp, 3 * ramp, "linear")[1] == 2  # rounding is not a kink


def test_a_100000_row_table_takes_few_steps_with_the_right_answer(tmp_path):
    """ṗ = −F(t) for the mass's exposed port: p(t) is minus the integral of the linear
    interpolant, the trapezoidal sums of the table (exact for a piecewise-linear F). Every
    row was a breakpoint before (253 s: a restart and at least one step per row); now none
    is and IDA's error control follows F (counted in steps and evaluations, not timed)."""
    n = 100_000
    t = np.linspace(0.0, 10.0, n)
    force = np.sin(3 * t) + 0.5 * np.cos(0.7 * t)
    np.savetxt(tmp_path / "force.csv", np.c_[t, force], delimiter=",", header="t,F", comments="", fmt="%.17g")
    model = table_model(tmp_path, "force.csv", t_end=10.0)
    compiled = phc.compile_model(model)
    info = [d for d in compiled.diagnostics if d.code == "PHC-I214"]
    assert len(info) == 1 and "100,000 kinks" in info[0].message
    assert compiled.module.BREAKPOINTS == ()
    result = phc.simulate(compiled)
    assert result.success
    # far fewer steps than rows (measured: about 4900 steps, 5800 residuals, 100 Jacobians)
    assert result.steps < n // 5 and result.n_residual_evals < n // 2, (result.steps, result.n_residual_evals)
    integral = np.concatenate([[0.0], np.cumsum(np.diff(t) * (force[1:] + force[:-1]) / 2)])
    exact = -np.interp(result.t, t, integral)
    # rtol 1e-8, atol 1e-10 over ~1000 steps of an O(1) solution
    assert np.abs(result.outputs["p"] - exact).max() < 1e-6


def test_a_few_rows_are_still_breakpoints(tmp_path):
    (tmp_path / "force.csv").write_text("t,F\n0,0\n0.5,0\n1,2\n")
    compiled = phc.compile_model(table_model(tmp_path, "force.csv", t_end=2.0))
    assert compiled.module.BREAKPOINTS == (0.5, 1.0)
    (tmp_path / "step.csv").write_text("t,F\n0,0\n0.5,0\n1,2\n1.5,2\n")
    compiled = phc.compile_model(table_model(tmp_path, "step.csv", name="b.yaml", t_end=2.0,
                                             extra=", interpolation: previous"))
    assert compiled.module.BREAKPOINTS == (1.0,)


# -- nested models: read once, bounded --------------------------------------------------

def diamond(folder: Path, levels: int) -> Path:
    """level i includes level i+1 twice: 2**levels copies of the leaf, levels+1 files."""
    (folder / f"l{levels}.yaml").write_text(LEAF)
    for i in range(levels - 1, -1, -1):
        (folder / f"l{i}.yaml").write_text(f"""format_version: 1
components:
  a: {{type: model, file: l{i + 1}.yaml}}
  b: {{type: model, file: l{i + 1}.yaml}}
  j: {{type: junction, kind: common_effort, domain: mechanical.translational, ports: [x, y, z]}}
connections:
  - [j.x, a.p]
  - [j.y, b.p]
ports:
  p: {{port: j.z}}
""")
    return nested_model(folder, "l0.yaml")


def test_each_nested_file_is_read_once(tmp_path, monkeypatch):
    import phc.frontend.elaborate as elab

    reads = []
    original = elab.load_spec_bytes
    monkeypatch.setattr(elab, "load_spec_bytes", lambda raw, path: reads.append(str(path)) or original(raw, path))
    model = diamond(tmp_path, 5)
    dae, diags = phc.build_dae(model)
    assert dae is not None, diags.render_text()
    assert dae.n_states - 1 == 1 + 2 ** 5  # the mass and 32 springs
    assert sorted(reads) == sorted(str(tmp_path / f"l{i}.yaml") for i in range(6))


def test_a_diamond_of_18_levels_is_refused_before_expanding(tmp_path, capsys, monkeypatch):
    """2**19 - 1 copies, counted without making them: each of the 19 files is read once, each
    of the 37 references is followed once (the count is memoized per file), and no file is
    elaborated (counted, not timed)."""
    import phc.frontend.elaborate as elab

    reads, refs, elaborated = [], [], []
    load_spec_bytes, nested_ref = elab.load_spec_bytes, elab._Elaborator._nested_ref
    monkeypatch.setattr(elab, "load_spec_bytes",
                        lambda raw, path: reads.append(str(path)) or load_spec_bytes(raw, path))
    monkeypatch.setattr(elab._Elaborator, "_nested_ref", lambda self, *a, **k: refs.append(a[1]) or nested_ref(self, *a, **k))
    monkeypatch.setattr(elab._Elaborator, "_elaborate_file", lambda self, ctx, overrides: elaborated.append(ctx.file))
    model = diamond(tmp_path, 18)
    code, text = validate(capsys, model)
    assert code == 1
    assert (f"{model}:4:28: components.sub.file: nested models expand to {2 ** 19 - 1:,} copies of model files, "
            f"above the limit of {phc_files.MAX_MODEL_INSTANCES:,}") in text
    assert "[PHC-E117]" in text
    assert sorted(reads) == sorted(str(tmp_path / f"l{i}.yaml") for i in range(19))
    assert len(refs) == 1 + 2 * 18, len(refs)
    assert elaborated == []


def test_nesting_depth_is_limited(tmp_path, capsys):
    depth = phc_files.MAX_INCLUDE_DEPTH + 3
    (tmp_path / f"c{depth}.yaml").write_text(LEAF)
    for i in range(depth - 1, -1, -1):
        (tmp_path / f"c{i}.yaml").write_text(
            f"format_version: 1\ncomponents:\n  sub: {{type: model, file: c{i + 1}.yaml}}\n"
            "ports:\n  p: {port: sub.p}\n")
    model = nested_model(tmp_path, "c0.yaml")
    code, text = validate(capsys, model)
    assert code == 1
    errors = [line for line in text.splitlines() if "[PHC-E117]" in line]
    assert len(errors) == 1, text
    # model.yaml is depth 0, c{i}.yaml depth i + 1: the deepest allowed file may not include one more
    assert errors[0].startswith(f"{tmp_path / f'c{phc_files.MAX_INCLUDE_DEPTH - 1}.yaml'}:3:")
    assert f"nest more than {phc_files.MAX_INCLUDE_DEPTH} levels deep" in errors[0]


def test_nested_file_must_be_valid_utf8(tmp_path, capsys):
    (tmp_path / "leaf.yaml").write_bytes(b"format_version: 1\n# \xff\n")
    code, text = validate(capsys, nested_model(tmp_path, "leaf.yaml"))
    assert code == 1 and "leaf.yaml:1:1: the file is not valid UTF-8 (byte 0xff on line 2)" in text


def test_a_reporter_without_roots_confines_to_the_referring_directory(tmp_path):
    b = Reporter()
    (tmp_path / "sub").mkdir()
    with pytest.raises(phc_files.FileRefused) as err:
        b.files.resolve(tmp_path / "sub" / "m.yaml", "../x.csv", "table")
    assert err.value.reason == "outside"


# -- .npz matrices -------------------------------------------------------------------------

def _csr_parts(name, data, indices, indptr, shape):
    return {f"{name}.data": np.asarray(data, dtype=float), f"{name}.indices": np.asarray(indices),
            f"{name}.indptr": np.asarray(indptr), f"{name}.shape": np.asarray(shape)}


def _npy_bytes(header: dict, payload: bytes = b"") -> bytes:
    text = repr(header).encode("latin1")
    pad = 64 - (10 + len(text) + 1) % 64
    text += b" " * pad + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text + payload


def _zip(path: Path, members: dict[str, bytes], compression=zipfile.ZIP_STORED) -> None:
    with zipfile.ZipFile(path, "w", compression=compression) as z:
        for name, data in members.items():
            z.writestr(name, data)


def _write_bad_npz_cases(folder: Path) -> dict[str, tuple[str, str]]:
    """case -> (J reference, expected message fragment); writes <case>.npz and <case>.yaml."""
    good_J = np.array([[0.0, 1.0], [-1.0, 0.0]])
    cases = {
        "out_of_range": (_csr_parts("J", [1, -1], [0, 7], [0, 1, 2], [2, 2]), "`J.indices` must lie in 0 … 1"),
        "negative_index": (_csr_parts("J", [1, -1], [1, -5], [0, 1, 2], [2, 2]), "`J.indices` must lie in 0 … 1"),
        "indptr_decreasing": (_csr_parts("J", [1, -1], [1, 0], [0, 2, 1], [2, 2]), "must start at 0 and never "
                              "decrease"),
        "indptr_length": (_csr_parts("J", [1, -1], [1, 0], [0, 1], [2, 2]), "`J.indptr` has 2 entries, expected "
                          "rows + 1 = 3"),
        "indptr_end": (_csr_parts("J", [1, -1], [1, 0], [0, 1, 9], [2, 2]), "`J.indptr` ends at 9"),
        "indptr_huge": (_csr_parts("J", [1, -1], [1, 0], [0, 2 ** 40, 2], [2, 2]), "never decrease"),
        "float_indices": ({**_csr_parts("J", [1, -1], [1, 0], [0, 1, 2], [2, 2]),
                           "J.indices": np.array([1.0, 0.0])}, "`J.indices` in `bad_float_indices.npz` must hold "
                          "integers"),
        "data_length": (_csr_parts("J", [1, -1, 3], [1, 0], [0, 1, 2], [2, 2]), "`J.indices` has 2 entries but "
                        "`J.data` has 3"),
        "shape_huge": (_csr_parts("J", [1, -1], [1, 0], [0, 1, 2], [10 ** 12, 10 ** 12]), "`J.shape` must hold "
                       "two sizes"),
        "missing_part": ({k: v for k, v in _csr_parts("J", [1, -1], [1, 0], [0, 1, 2], [2, 2]).items()
                          if k != "J.indptr"}, "has no `J.indptr`"),
        "three_d": ({"J": np.zeros((2, 2, 2))}, "is 3-D"),
        "zero_d": ({"J": np.array(1.0)}, "is 0-D"),
        "empty": ({"J": np.zeros((0, 2))}, "is empty"),
        "strings": ({"J": np.array([["a", "b"], ["c", "d"]])}, "holds strings"),
        "complex": ({"J": good_J.astype(complex)}, "holds complex numbers"),
        "nan": ({"J": np.array([[0.0, np.nan], [-1.0, 0.0]])}, "has non-finite entries"),
        "wrong_shape": ({"J": np.zeros((3, 3))}, "`J` is 3 × 3, expected 2 × 2"),
        "big_endian": ({"J": good_J.astype(">f8")}, None),  # fine: converted to native order
        "fortran": ({"J": np.asfortranarray(good_J)}, None),
    }
    out = {}
    for case, (arrays, fragment) in cases.items():
        np.savez(folder / f"bad_{case}.npz", **arrays)
        out[case] = ("J", fragment)
    # object array: written with pickling allowed, must never be unpickled
    obj = np.empty(2, dtype=object)
    obj[:] = [{"a": 1}, [1, 2]]
    np.savez(folder / "bad_object.npz", J=obj)
    out["object"] = ("J", "holds Python objects")
    # a header claiming 10^12 × 10^12 entries, with no data behind it
    _zip(folder / "bad_huge_header.npz",
         {"J.npy": _npy_bytes({"descr": "<f8", "fortran_order": False, "shape": (10 ** 12, 10 ** 12)})})
    out["huge_header"] = ("J", "claims 1,000,000,000,000 × 1,000,000,000,000 entries")
    # a header longer than numpy's safety limit, and one that does not parse
    _zip(folder / "bad_header_garbage.npz", {"J.npy": b"\x93NUMPY\x01\x00" + struct.pack("<H", 20) + b"{'x': (" * 3})
    out["header_garbage"] = ("J", "is not a valid .npy array")
    # truncated: the data stop halfway
    full = _npy_bytes({"descr": "<f8", "fortran_order": False, "shape": (2, 2)}, good_J.tobytes())
    _zip(folder / "bad_truncated_member.npz", {"J.npy": full[:-16]})
    out["truncated_member"] = ("J", "is truncated or corrupt")
    np.savez(folder / "whole.npz", J=good_J)
    raw = (folder / "whole.npz").read_bytes()
    (folder / "bad_truncated_file.npz").write_bytes(raw[: len(raw) // 2])
    out["truncated_file"] = ("J", "is not a valid .npz (zip) file")
    (folder / "bad_not_zip.npz").write_text(f"AWS_SECRET_ACCESS_KEY={SECRET}\n")
    out["not_zip"] = ("J", "is not a valid .npz (zip) file")
    # bzip2 members cannot be bounded while decompressing
    _zip(folder / "bad_bzip2.npz", {"J.npy": full}, compression=zipfile.ZIP_BZIP2)
    out["bzip2"] = ("J", "uses a compression phc does not read")
    # a zip bomb: 64 MiB of zeros deflated to ~64 KiB, under a budget of 8 MiB (set below)
    zeros = np.zeros(8 * 2 ** 20)  # 64 MiB
    with zipfile.ZipFile(folder / "bad_bomb.npz", "w", compression=zipfile.ZIP_DEFLATED) as z:
        with z.open("J.npy", "w", force_zip64=True) as member:
            np.lib.format.write_array(member, zeros.reshape(2 ** 12, 2 ** 11))
    out["bomb"] = ("J", "unpacks to 67,108,992 bytes, above the budget of 8,388,608 bytes")
    # a member whose declared size lies about deflate's ratio (4 GiB claimed from a few bytes)
    data = zlib.compress(full)[2:-4]
    with zipfile.ZipFile(folder / "bad_ratio.npz", "w") as z:
        info = zipfile.ZipInfo("J.npy")
        info.compress_type = zipfile.ZIP_DEFLATED
        z.writestr(info, full)
    raw = bytearray((folder / "bad_ratio.npz").read_bytes())
    # patch the central directory's uncompressed size (offset 24 in the entry) to 4 MiB
    cd = raw.rfind(b"PK\x01\x02")
    raw[cd + 24: cd + 28] = struct.pack("<I", 4 * 2 ** 20)
    (folder / "bad_ratio.npz").write_bytes(bytes(raw))
    del data
    out["ratio"] = ("J", "claims to unpack")
    for case, (ref, _) in out.items():
        npz_model(folder, f"bad_{case}.npz", f"bad_{case}.yaml", J=ref)
    return out


def test_malformed_npz_files_end_in_located_errors_never_a_crash(tmp_path):
    cases = _write_bad_npz_cases(tmp_path)
    models = [tmp_path / f"bad_{case}.yaml" for case in cases]
    proc = run_cli(["validate", *models], timeout=SUBPROCESS_TIMEOUT, env={"PHC_MAX_MATRICES_MB": "8"})
    assert proc.returncode >= 0, f"killed by signal {-proc.returncode}"
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr and "internal error" not in proc.stderr, proc.stderr
    assert SECRET not in proc.stderr + proc.stdout
    lines = proc.stderr.splitlines()
    for case, (_, fragment) in cases.items():
        model = tmp_path / f"bad_{case}.yaml"
        mine = [line for line in lines if line.startswith(f"{model}:")]
        if fragment is None:
            assert not mine, mine
            assert f"{model}: ok" in proc.stdout
            continue
        assert mine, f"{case}: no diagnostic\n{proc.stderr}"
        assert any(fragment in line for line in mine), f"{case}: {mine}"
        for line in mine:
            assert line.startswith((f"{model}:7:", f"{model}:6:")), line  # at `J:` or `matrices:`
            assert line.endswith(("[PHC-E130]", "[PHC-E131]", "[PHC-E102]", "[PHC-E012]")), line


def test_a_valid_sparse_npz_still_works(tmp_path):
    np.savez(tmp_path / "m.npz", **_csr_parts("J", [1.0, -1.0], [1, 0], [0, 1, 2], [2, 2]))
    dae, diags = phc.build_dae(npz_model(tmp_path, "m.npz", "m.yaml"))
    assert dae is not None, diags.render_text()


def test_npz_outside_the_tree_and_missing(tmp_path, capsys):
    project, other = _outside_tree(tmp_path)
    np.savez(other / "m.npz", J=np.array([[0.0, 1.0], [-1.0, 0.0]]))
    code, text = validate(capsys, npz_model(project, "../other/m.npz", "m.yaml"))
    assert code == 1 and "matrices file `../other/m.npz` lies outside" in text and "[PHC-E116]" in text
    code, text = validate(capsys, npz_model(project, "nothing.npz", "n.yaml"))
    assert code == 1 and "matrices file `nothing.npz` not found" in text and "[PHC-E130]" in text
