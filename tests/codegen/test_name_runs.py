"""Per-unknown tuples of the generated module are printed as runs.

A mesh's names (``string.p[0]`` … ``string.p[9999]``) and its repeated roles are printed as
one line per run (``*_indexed('string.p', 0, 10000)``, ``*('state',) * 10000``) and
DIFFERENTIAL as run lengths: one name a line made Python's compilation of a 10⁴-element
string's module take about 0.9 KiB per name. The loaded module must hold exactly the names
the printer was given, in order; the source must not grow with the mesh in these tuples.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import phc
from phc.codegen.load import load_generated
from phc.codegen.printer import RUN_LENGTH, _array, _tuple

MODELS = Path(__file__).resolve().parents[2] / "models"


def _load_tuple(values):
    source = "\n".join([
        "def _indexed(_stem, _start, _stop, _tail=''):",
        "    return tuple(f'{_stem}[{_i}]{_tail}' for _i in range(_start, _stop))",
        f"VALUES = {_tuple(values)}",
    ]) + "\n"
    module, _ = load_generated(source, "names")
    return module.VALUES, source


def test_runs_give_back_every_name_in_order():
    values = ([f"s.p[{i}]" for i in range(20)]                 # a run from 0
              + [f"s.p[{i}].x" for i in range(5, 5 + RUN_LENGTH)]  # a run with a tail, from 5
              + ["a.x", "b.y"]                                 # single names
              + [f"c[{i}]" for i in range(RUN_LENGTH - 1)]     # too short for a run
              + ["s.q[01]", "s.q[02]", *[f"s.q[{i}]" for i in range(3, 12)]]  # leading zeros: not indices
              + [f"d[{i}]" for i in (0, 1, 2, 4, 5, 6, 7, 8, 9, 10)]  # a gap
              + ["state"] * 30 + ["effort"] * 3)
    loaded, source = _load_tuple(values)
    assert loaded == tuple(values)
    assert "*_indexed('s.p', 0, 20)" in source
    assert f"*_indexed('s.p', 5, {5 + RUN_LENGTH}, '.x')" in source
    assert "*('state',) * 30" in source
    assert "'s.q[01]'" in source


def test_empty_and_short_tuples():
    assert _load_tuple([])[0] == ()
    assert _load_tuple(["x"])[0] == ("x",)


def test_boolean_array_as_run_lengths():
    values = [True] * 300 + [False] * 300 + [True] + [False] * 10
    source = f"import numpy as np\nA = {_array(values, 'bool')}\n"
    assert "np.repeat" in source
    module, _ = load_generated(source, "bools")
    assert module.A.dtype == np.bool_
    assert module.A.tolist() == values


def test_string_module_names_do_not_grow_with_the_mesh(tmp_path):
    """The loaded module's VARIABLES, ROLES, EQUATIONS and DIFFERENTIAL are the assembled
    model's; the lines printing them are as many for 400 elements as for 40."""
    lines = {}
    for n in (40, 400):
        path = tmp_path / f"string{n}.yaml"
        path.write_text((MODELS / "vibrating_string.yaml").read_text().replace("elements: 16", f"elements: {n}"))
        compiled = phc.compile_model(path, certify=False, backend="numpy")
        mod, dae = compiled.module, compiled.dae
        assert mod.VARIABLES == tuple(v.name for v in dae.variables)
        assert mod.ROLES == tuple(v.role for v in dae.variables)
        assert mod.DIFFERENTIAL.tolist() == [bool(v.differential) for v in dae.variables]
        assert len(mod.EQUATIONS) == mod.N
        text = compiled.source
        start = text.index("\nVARIABLES = (")
        lines[n] = text[start:text.index("\nPARAMETERS = ", start)].count("\n")
    assert lines[40] == lines[400]
