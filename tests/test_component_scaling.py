"""Many lumped components: the work of reading, assembling, lowering, printing and
certifying a model grows linearly with its components (issue 38).

Measured in operations, never in time, on a generated chain of damped mass–spring cells
(a wall, then per cell a two-terminal spring, a mass and a damper to ground):

* the model file is parsed once per ``compile_model``, ``validate_file`` and
  ``certify_model`` (it was read three to six times, and ``phc check`` assembled it twice);
* sympy's work in the lowering and the printing — the arguments flattened by ``Add`` (a
  Python ``sum`` of sympy terms re-flattens the growing sum at every term) and the
  derivatives taken (``diff`` of the energy-balance row differentiated every term by every
  symbol of the row);
* the bytecode instructions of phc's own code run by the front end (``build_dae``: a scan
  of every port per component) and by the certificate of the compiled equations (every
  unknown and parameter per dissipative term).

For cells n, 2n, 4n the increments w(2n) − w(n) and w(4n) − w(2n) of a count w are
compared: a fixed cost cancels, work linear in the cells doubles the increment, a
quadratic term quadruples its part of it. At these sizes the quadratic parts removed in
issue 38 made the ratio 2.22–2.62; it is 2.00–2.07 without them (sorting, n log n, is the
rest). The structure certificate's per-component scan of all states is not seen at sizes a
test can afford (its share is below 1 %); bench_components.py shows it.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import sympy as sp
from sympy.core.cache import clear_cache

import phc
import phc.frontend.source
from phc.checks import certify_model
from phc.codegen.lower import lower_residual
from phc.codegen.printer import print_module

LINEAR = 2.15
"""Largest ratio of consecutive increments accepted (linear: 2; quadratic: up to 4)."""
CELLS = (16, 32, 64)
PHC = str(Path(phc.__file__).resolve().parent)


def damped_chain(cells: int) -> str:
    dom = "domain: mechanical.translational"
    lines = ["format_version: 1", f"name: damped_chain_{cells}", "parameters:",
             "  m: {value: 1.0, unit: kg}", "  k: {value: 100.0, unit: N/m}", "  c: {value: 0.5, unit: N*s/m}",
             "components:", f"  wall: {{type: zero_flow, {dom}}}"]
    for i in range(1, cells + 1):
        lines += [f"  k{i}: {{type: spring, k: k, terminals: [a, b]}}",
                  f"  m{i}: {{type: mass, m: m, ports: [{'l, r, d' if i < cells else 'l, d'}]}}",
                  f"  d{i}: {{type: damper, d: c}}"]
    lines += ["connections:", "  - [wall.port, k1.a]"]
    for i in range(1, cells + 1):
        lines += [f"  - [k{i}.b, m{i}.l]", f"  - [m{i}.d, d{i}.port]"]
        if i < cells:
            lines.append(f"  - [m{i}.r, k{i + 1}.a]")
    lines += ["simulation:", "  t_end: 1.0", "  initial: {k1.x: 0.01}", "  outputs: {x1: k1.x, energy: H}"]
    return "\n".join(lines) + "\n"


def _write(tmp_path: Path, cells: int) -> Path:
    path = tmp_path / f"damped_chain_{cells}.yaml"
    path.write_text(damped_chain(cells))
    return path


def _assert_linear(counts: dict, what: str) -> None:
    (n1, w1), (n2, w2), (n4, w4) = sorted(counts.items())
    assert n2 == 2 * n1 and n4 == 4 * n1
    ratio = (w4 - w2) / (w2 - w1)
    assert ratio <= LINEAR, (f"{what} is not linear in the number of components: counts {counts} for "
                             f"{sorted(counts)} cells, the increment grows {ratio:.2f}× per doubling "
                             f"(linear: 2, quadratic: 4)")


# ---------------------------------------------------------------------------------------
# the file is parsed once


@pytest.fixture
def parses(monkeypatch):
    """Counts of :func:`phc.frontend.source.load_yaml` by file name, with the parsed files
    :func:`phc.frontend.source.read_yaml_file` keeps emptied first."""
    counts: dict = {}
    load = phc.frontend.source.load_yaml

    def counting(text, file, **kwargs):
        counts[Path(file).name] = counts.get(Path(file).name, 0) + 1
        return load(text, file, **kwargs)

    monkeypatch.setattr(phc.frontend.source, "_PARSED", {})
    monkeypatch.setattr(phc.frontend.source, "load_yaml", counting)
    return counts


def test_compile_parses_the_model_file_once(tmp_path, parses):
    path = _write(tmp_path, 2)
    phc.compile_model(path, backend="numpy")
    assert parses == {path.name: 1}


def test_check_parses_and_assembles_the_model_file_once(tmp_path, parses, monkeypatch):
    import phc.pipeline

    monkeypatch.setenv("PHC_BACKEND", "numpy")  # the check compiles; no JIT wanted here
    path = _write(tmp_path, 2)
    built = []
    elaborate = phc.pipeline.elaborate
    monkeypatch.setattr(phc.pipeline, "elaborate", lambda *a, **k: built.append(a[0]) or elaborate(*a, **k))
    report = certify_model(path)
    assert report.certified, report.render_text()
    assert report.compiled is not None  # the compiled equations were certified too
    assert parses == {path.name: 1}
    assert len(built) == 1


def test_validate_parses_the_model_file_once(tmp_path, parses):
    path = _write(tmp_path, 2)
    dae, diags, kind = phc.validate_file(path)
    assert dae is not None and kind == "model", [d.render() for d in diags]
    assert parses == {path.name: 1}


def test_a_file_changed_on_disk_is_parsed_again(tmp_path, parses):
    path = _write(tmp_path, 1)
    first, _, _ = phc.frontend.source.read_yaml_file(path)
    path.write_text(damped_chain(2))
    second, _, _ = phc.frontend.source.read_yaml_file(path)
    assert parses == {path.name: 2}
    assert len(second["components"]) == len(first["components"]) + 3


def test_each_reader_gets_its_own_data(tmp_path, parses):
    path = _write(tmp_path, 1)
    first, smap, _ = phc.frontend.source.read_yaml_file(path)
    first["components"].clear()
    again, smap_again, _ = phc.frontend.source.read_yaml_file(path)
    assert parses == {path.name: 1}
    assert "wall" in again["components"]  # not the data the first reader changed
    assert smap_again.locate(("components", "wall")) == smap.locate(("components", "wall"))


def test_the_same_text_under_another_name_reports_that_name(tmp_path, parses, monkeypatch):
    path = _write(tmp_path, 1)
    _, smap, _ = phc.frontend.source.read_yaml_file(path)
    monkeypatch.chdir(tmp_path)
    _, smap_here, _ = phc.frontend.source.read_yaml_file("./" + path.name)
    assert parses == {path.name: 1}
    assert smap_here.locate(("components", "wall")).file == "./" + path.name
    assert smap.locate(("components", "wall")).file == str(path)


# ---------------------------------------------------------------------------------------
# sympy's work in the front end and the code generation


class _SympyWork:
    """Arguments flattened by ``Add`` and derivatives taken, while counting."""

    def __init__(self, monkeypatch):
        self.count = 0
        add_flatten = sp.Add.flatten.__func__
        diff = sp.Derivative.__new__

        def flatten(cls, seq):
            self.count += len(seq)
            return add_flatten(cls, seq)

        def derivative(cls, expr, *variables, **kwargs):
            self.count += 1
            return diff(cls, expr, *variables, **kwargs)

        monkeypatch.setattr(sp.Add, "flatten", classmethod(flatten))
        monkeypatch.setattr(sp.Derivative, "__new__", derivative)


def test_sympy_work_is_linear_in_components(tmp_path, monkeypatch):
    work = _SympyWork(monkeypatch)
    counts = {}
    for cells in CELLS:
        dae, diags = phc.build_dae(_write(tmp_path, cells))
        assert dae is not None, [d.render() for d in diags]
        clear_cache()  # each size does its own work, not the cached results of the one before
        work.count = 0
        print_module(lower_residual(dae))
        counts[cells] = work.count
    _assert_linear(counts, "sympy's work in the lowering and printing")


# ---------------------------------------------------------------------------------------
# phc's own loops in the certificates


def _phc_operations(fn) -> int:
    """Bytecode instructions of phc's own code run by `fn()`, comprehensions included (frames
    of other packages are not traced)."""
    count = 0

    def local(frame, event, arg):
        nonlocal count
        if event == "opcode":
            count += 1
        return local

    def calls(frame, event, arg):
        if not frame.f_code.co_filename.startswith(PHC):
            return None
        frame.f_trace_opcodes = True
        return local

    previous = sys.gettrace()
    sys.settrace(calls)
    try:
        fn()
    finally:
        sys.settrace(previous)
    return count


def test_front_end_work_is_linear_in_components(tmp_path):
    counts = {}
    for cells in CELLS:
        path = _write(tmp_path, cells)
        clear_cache()
        counts[cells] = _phc_operations(lambda: phc.build_dae(path))
    _assert_linear(counts, "the front end (phc's instructions run by build_dae)")


def test_compiled_certificate_work_is_linear_in_components(tmp_path):
    from phc.checks.compiled import certify_compiled

    counts = {}
    for cells in CELLS:
        compiled = phc.compile_model(_write(tmp_path, cells), certify=False, backend="numpy")
        counts[cells] = _phc_operations(lambda: certify_compiled(compiled, n_random=0))
    _assert_linear(counts, "the certificate of the compiled equations (phc's instructions run)")
