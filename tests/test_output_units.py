"""Outputs and the model's system of units (docs/units.md, "Outputs in another unit").

An output declared in another scale than its value (`unit: mm` for a spring's `x` in m) is
converted into the declared unit; before, the value in m was merely labelled mm (wrong by
1000, km/h by 3.6). A sum or comparison of a state (whose unit the model's system of units
fixes) with a parameter in another scale (`spring.x - b`, `b` in mm) is refused (PHC-E171)
like one of two parameters in m and mm. The expected numbers are the closed-form solution
x(t) = x0 cos(w t), v(t) = -x0 w sin(w t), w = sqrt(k/m), of the undamped mass-spring."""

from __future__ import annotations

import csv
import math
import textwrap

import pytest

import phc
from phc.cli import main

pytest.importorskip("pint")


def _model(outputs: str, *, k: str = "{value: 4.0, unit: N/m}", m: str = "{value: 1.0, unit: kg}",
           x0: str = "{value: 0.1, unit: m}", extra: str = "", t_end: float = 1.0) -> str:
    return textwrap.dedent(f"""\
        format_version: 1
        parameters:
          k: {k}
          m: {m}
          x0: {x0}
        {extra}
        components:
          mass: {{type: mass, m: m}}
          spring: {{type: spring, k: k}}
        connections:
          - [mass.port, spring.port]
        simulation:
          t_end: {t_end}
          n_out: 3
          initial: {{spring.x: x0, mass.p: 0}}
          outputs:
        """) + textwrap.indent(textwrap.dedent(outputs), "    ")


def _diagnostic(tmp_path, capsys, text: str, code: str) -> tuple[str, str]:
    path = tmp_path / "model.yaml"
    path.write_text(text)
    assert main(["validate", str(path)]) == 1
    out = capsys.readouterr()
    lines = [ln for ln in (out.out + out.err).splitlines() if code in ln]
    assert len(lines) == 1, out
    return str(path), lines[0]


def _run(tmp_path, text: str):
    path = tmp_path / "model.yaml"
    path.write_text(text)
    result = phc.simulate(phc.compile_model(path, certify=False))
    assert result.success
    return result


def test_output_declared_in_mm_and_km_per_h_is_converted(tmp_path):
    result = _run(tmp_path, _model("""\
        x_mm: {value: spring.x, unit: mm}
        v_kmh: {value: mass.p/m, unit: km/h}
        """))
    t = result.t
    w = math.sqrt(4.0 / 1.0)
    for ti, x, v in zip(t, result["x_mm"], result["v_kmh"]):
        assert x == pytest.approx(1000 * 0.1 * math.cos(w * ti), abs=1e-4)  # mm
        assert v == pytest.approx(3.6 * -0.1 * w * math.sin(w * ti), abs=1e-4)  # km/h
    assert result.units["x_mm"] == "mm" and result.units["v_kmh"] == "km/h"


def test_si_model_with_outputs_in_m_runs_unconverted(tmp_path):
    result = _run(tmp_path, _model("""\
        x: {value: spring.x, unit: m}
        v: {value: mass.p/m, unit: m/s}
        """))
    w = 2.0
    for ti, x, v in zip(result.t, result["x"], result["v"]):
        assert x == pytest.approx(0.1 * math.cos(w * ti), abs=1e-7)
        assert v == pytest.approx(-0.1 * w * math.sin(w * ti), abs=1e-7)
    assert result.units["x"] == "m"


def test_mm_g_ms_model_with_outputs_in_mm_runs_and_in_m_is_converted(tmp_path):
    # k 4 N/mm, m 1000 g: the system is mm, g, ms (force in N); w = sqrt(4000/1) 1/s = 2/ms
    result = _run(tmp_path, _model("""\
        x: {value: spring.x, unit: mm}
        x_m: {value: spring.x, unit: m}
        v: {value: mass.p/m, unit: mm/ms}
        """, k="{value: 4.0, unit: N/mm}", m="{value: 1000.0, unit: g}", x0="{value: 100.0, unit: mm}",
        t_end=1.0))
    w = math.sqrt(4000.0) / 1000.0  # per ms
    assert result.units.get("t") == "ms"  # the time is in ms: the CSV header said `t [s]`
    for ti, x, xm, v in zip(result.t, result["x"], result["x_m"], result["v"]):
        assert x == pytest.approx(100.0 * math.cos(w * ti), abs=1e-5)
        assert xm == pytest.approx(0.1 * math.cos(w * ti), abs=1e-8)
        assert v == pytest.approx(-100.0 * w * math.sin(w * ti), abs=1e-6)


def test_state_minus_parameter_in_mm_is_refused(tmp_path, capsys):
    path, line = _diagnostic(tmp_path, capsys, _model("""\
        over: {value: "spring.x - b", unit: m}
        """, extra="  b: {value: 50, unit: mm}"), "PHC-E171")
    assert line.startswith(f"{path}:17:19:")  # line 17, column 19: the output's value
    assert "simulation.outputs.over.value" in line
    assert "different scales" in line and "`spring.x` is m" in line and "`-b` is mm" in line


def test_comparison_of_state_with_gap_in_mm_is_refused(tmp_path, capsys):
    path, line = _diagnostic(tmp_path, capsys, _model("""\
        hit: {value: "ifelse(spring.x > gap, 1, 0)", unit: "1"}
        """, extra="  gap: {value: 50, unit: mm}"), "PHC-E171")
    assert line.startswith(f"{path}:17:18:")
    assert "compares sides of one dimension but different scales" in line and "`gap` is mm" in line


def test_state_minus_parameter_in_the_models_scale_runs(tmp_path):
    # the same sum in a consistent mm-g-ms model: x and b both in mm
    result = _run(tmp_path, _model("""\
        over: {value: "spring.x - b", unit: mm}
        """, k="{value: 4.0, unit: N/mm}", m="{value: 1000.0, unit: g}", x0="{value: 100.0, unit: mm}",
        extra="  b: {value: 50, unit: mm}"))
    w = math.sqrt(4000.0) / 1000.0
    for ti, over in zip(result.t, result["over"]):
        assert over == pytest.approx(100.0 * math.cos(w * ti) - 50.0, abs=1e-5)
