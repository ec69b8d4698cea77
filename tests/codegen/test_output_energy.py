"""An output written `H` is the total stored energy, distributed components included.

Strings and beams keep their energy as a sparse quadratic form ``coeff · xᵀ A x`` beside the
symbolic H of the lumped parts; an output `energy: H` read only the symbolic part and was 0
for a string while ``SimResult.H`` was right (a silent wrong answer). The reference here is
the independent evaluation of the energy: the generated ``hamiltonian`` function.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.mark.parametrize("model", ["vibrating_string", "euler_bernoulli_beam", "timoshenko_beam",
                                   "controlled_beam", "mass_spring_damper"])
def test_output_H_is_the_total_energy(model):
    compiled = phc.compile_model(MODELS / f"{model}.yaml", certify=False)
    result = phc.simulate(compiled, n_out=21)
    assert result.success
    assert np.abs(result.H).max() > 0  # the run stores energy: the comparison is not 0 = 0
    np.testing.assert_allclose(result.outputs["energy"], result.H, rtol=1e-12, atol=1e-15 * np.abs(result.H).max())


def test_an_output_using_H_in_an_expression(tmp_path):
    """`2*H` and `H - H0`-like uses see the whole energy too; a state named like `H` is not H."""
    text = (MODELS / "vibrating_string.yaml").read_text(encoding="utf-8")
    text = text.replace("    energy: H", "    energy: H\n    twice: 2*H + 0*t")
    path = tmp_path / "string.yaml"
    path.write_text(text, encoding="utf-8")
    result = phc.simulate(phc.compile_model(path, certify=False), n_out=11)
    np.testing.assert_allclose(result.outputs["twice"], 2 * result.H, rtol=1e-12, atol=1e-18)


def test_an_energy_too_long_to_write_out_is_a_located_error(tmp_path):
    """Above MAX_OUTPUT_ENERGY_TERMS the sum would make generated code Python cannot compile
    (a 3000-element string: RecursionError); the output is refused where it is written.
    Just below the limit the output compiles and is right."""
    from phc.assemble import MAX_OUTPUT_ENERGY_TERMS

    text = (MODELS / "vibrating_string.yaml").read_text(encoding="utf-8")
    line = next(i for i, s in enumerate(text.splitlines(), 1) if s.strip().startswith("energy: H"))
    terms_per_element = 3  # mass and stiffness forms of the P1/P0 pair
    big = tmp_path / "big.yaml"
    big.write_text(text.replace("elements: 16", f"elements: {MAX_OUTPUT_ENERGY_TERMS // terms_per_element + 10}"))
    with pytest.raises(phc.ModelError, match=rf"big.yaml:{line}:\d+: .*output `energy` uses `H`.*PHC-E604"):
        phc.compile_model(big, certify=False)
    near = tmp_path / "near.yaml"
    near.write_text(text.replace("elements: 16", f"elements: {MAX_OUTPUT_ENERGY_TERMS // terms_per_element - 10}"))
    result = phc.simulate(phc.compile_model(near, certify=False), t_end=1e-3, n_out=3)
    np.testing.assert_allclose(result.outputs["energy"], result.H, rtol=1e-10, atol=1e-18)
