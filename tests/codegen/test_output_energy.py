"""An output written `H` is the total stored energy, distributed components included.

Strings and beams keep their energy as a sparse quadratic form ``coeff · xᵀ A x`` beside the
symbolic H of the lumped parts; an output `energy: H` read only the symbolic part and was 0
for a string while ``SimResult.H`` was right (a silent wrong answer). The reference here is
the independent evaluation of the energy: the generated ``hamiltonian`` function (the `H`
column of the results), and for the string the closed form of the energy its force pulse
puts in.

An output that uses `H` refers to the stored energy as the generated ``hamiltonian``
computes it (sparse quadratic forms), evaluated once per call of ``outputs``
(:data:`phc.ir.dae.STORED_ENERGY`): it works at any mesh size, on every back end, and the
generated code does not grow with the mesh. (It was refused above 2000 energy terms, about
660 string elements, because the energy was written out term by term.)
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import phc
from phc.ir.dae import STORED_ENERGY

MODELS = Path(__file__).resolve().parents[2] / "models"

BIG = 800
"""Elements of the large string: 2400 energy terms, above the former limit of 2000."""


@pytest.mark.parametrize("model", ["vibrating_string", "euler_bernoulli_beam", "timoshenko_beam",
                                   "controlled_beam", "mass_spring_damper"])
def test_output_H_is_the_total_energy(model):
    compiled = phc.compile_model(MODELS / f"{model}.yaml", certify=False)
    result = phc.simulate(compiled, n_out=21)
    assert result.success
    assert np.abs(result.H).max() > 0  # the run stores energy: the comparison is not 0 = 0
    np.testing.assert_allclose(result.outputs["energy"], result.H, rtol=1e-12, atol=1e-15 * np.abs(result.H).max())


def test_an_output_using_H_in_an_expression(tmp_path):
    """`2*H`, `v*H` and `H**2` see the whole energy too."""
    text = (MODELS / "vibrating_string.yaml").read_text(encoding="utf-8")
    text = text.replace("    energy: H", "    energy: H\n    twice: 2*H + 0*t\n    weighted: string.b.f*H\n"
                        "    squared: H**2")
    path = tmp_path / "string.yaml"
    path.write_text(text, encoding="utf-8")
    result = phc.simulate(phc.compile_model(path, certify=False), n_out=11)
    H, v = result.H, result.outputs["end_velocity"]
    scale = np.abs(H).max()
    assert scale > 0
    np.testing.assert_allclose(result.outputs["twice"], 2 * H, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(result.outputs["weighted"], v * H, rtol=0, atol=1e-12 * scale * np.abs(v).max())
    np.testing.assert_allclose(result.outputs["squared"], H ** 2, rtol=1e-11, atol=1e-12 * scale ** 2)


def _string(tmp_path, elements: int, outputs: str = "") -> Path:
    text = (MODELS / "vibrating_string.yaml").read_text(encoding="utf-8")
    assert "elements: 16" in text and "    energy: H" in text
    text = text.replace("elements: 16", f"elements: {elements}").replace("    energy: H", "    energy: H" + outputs)
    path = tmp_path / f"string{elements}.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def _available(backend: str) -> tuple[bool, str]:
    if backend == "numba":
        from phc.codegen import numba_backend

        return numba_backend.available()
    if backend == "c":
        from phc.codegen import c_backend

        return c_backend.available()
    return True, ""


@pytest.mark.parametrize("backend", ["numpy", "numba", "c"])
def test_an_output_H_of_a_string_beyond_the_former_limit(tmp_path, backend):
    """An 800-element string with `energy: H` compiles on every back end; the output equals
    the `H` column to round-off at every output time (the output takes the module's H),
    expressions of `H` (with a state, squared) are those expressions of the columns, and after the pulse
    the energy is what the pulse put in: 3 F0² tp / (8 Z), independent of the code."""
    ok, why = _available(backend)
    if not ok:
        pytest.skip(f"{backend} back end not available: {why}")
    path = _string(tmp_path, BIG, "\n    weighted: string.b.f*H - 2*H\n    squared: H**2")
    compiled = phc.compile_model(path, certify=False, backend=backend)
    assert compiled.backend == backend
    mod = compiled.module
    # the functions alone, at random states: the output is the module's H
    rng = np.random.default_rng(35)
    p = np.asarray(mod.full_parameters(), dtype=float)
    k_energy, k_weighted, k_v = (list(mod.OUTPUTS).index(name) for name in ("energy", "weighted", "end_velocity"))
    for _ in range(3):
        y, yp = rng.uniform(-1.0, 1.0, mod.N), rng.uniform(-1.0, 1.0, mod.N)
        out = np.asarray(mod.outputs(0.001, y, yp, p), dtype=float)
        H = float(mod.hamiltonian(0.001, y, p))
        S = float(mod.energy_scale(0.001, y, p))  # sum of |terms|: the size of the round-off
        assert abs(out[k_energy] - H) <= 1e-13 * S
        assert abs(out[k_weighted] - (out[k_v] - 2) * H) <= 1e-13 * S * (abs(out[k_v]) + 2)
    # a run: t_end before the pulse reaches the fixed end (L/c = 8 ms)
    result = phc.simulate(compiled, t_end=0.006, n_out=7, rtol=1e-8, atol=1e-12)
    assert result.success
    H = np.asarray(result.H)
    np.testing.assert_allclose(result.outputs["energy"], H, rtol=1e-12, atol=1e-15 * np.abs(H).max())
    v = np.asarray(result.outputs["end_velocity"])
    np.testing.assert_allclose(result.outputs["weighted"], (v - 2) * H, rtol=0,
                               atol=1e-12 * np.abs(H).max() * (np.abs(v).max() + 2))
    np.testing.assert_allclose(result.outputs["squared"], H ** 2, rtol=1e-12, atol=1e-15 * np.abs(H).max() ** 2)
    F0, tp, Z = 1.0, 0.004, math.sqrt(64.0 * 0.01)
    after = np.asarray(result.t) >= tp
    assert after.sum() >= 2
    # the mesh resolves the pulse with 400 elements: the discrete energy is the closed form to
    # well within 1e-3 (dispersion O((h/λ)²) ~ 1e-5; the run's tolerance 1e-8)
    np.testing.assert_allclose(np.asarray(result.outputs["energy"])[after], 3 * F0 ** 2 * tp / (8 * Z), rtol=1e-3)


def _generated(tmp_path, elements: int):
    """(IR, NumPy `outputs` source, C `phc_outputs` source, numba outputs kernel) of a string."""
    from phc.codegen.c_printer import c_source
    from phc.codegen.lower import lower_residual
    from phc.codegen.numba_backend import kernel_source
    from phc.codegen.printer import print_module

    dae, diags = phc.build_dae(_string(tmp_path, elements, "\n    twice: 2*H"))
    assert dae is not None, [d.render() for d in diags]
    ir = lower_residual(dae)
    module = print_module(ir)
    numpy_outputs = module[module.index("\ndef outputs("):]
    c = c_source(ir)
    start = c.index("void phc_outputs(")
    c_outputs = c[start:c.index("\n}\n", start)]
    _, kernels = kernel_source(ir)
    return ir, numpy_outputs, c_outputs, kernels.get("outputs")


def test_the_generated_outputs_do_not_grow_with_the_mesh(tmp_path):
    """The outputs that use `H` refer to the module's H (sparse forms, module constants shared
    with `hamiltonian`), not to thousands of terms: the `outputs` function of an 800-element
    string is as long as that of a 100-element one (names may gain a digit), on the NumPy
    and C back ends, and the numba kernel holds the same few expressions and the forms."""
    small, big = _generated(tmp_path, 100), _generated(tmp_path, BIG)
    for ir, kernel in ((small[0], small[3]), (big[0], big[3])):
        uses = sorted(name for name, e in ir.outputs if e.has(STORED_ENERGY))
        assert uses == ["energy", "twice"]
        assert kernel is not None  # numba kernels are printed without numba
        assert kernel.energy is not None and len(kernel.energy.sums) == len(ir.quadratic_energy) > 0
        assert not kernel.sums
    for text_small, text_big in ((small[1], big[1]), (small[2], big[2])):
        assert len(text_big) <= len(text_small) + 200
        assert len(re.findall(r"\by_string", text_big)) < 20  # a few states named, not 2400 terms
    assert "hamiltonian(t, y, p)" in big[1] and "phc_hamiltonian(t, y, p)" in big[2]
    ops = [sum(sp.count_ops(e) for e in k.expressions() + k.energy.expressions()) for k in (small[3], big[3])]
    assert ops[0] == ops[1] < 200
