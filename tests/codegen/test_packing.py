"""Long constant arrays of a generated module (:mod:`phc.codegen.packing`).

The module must rebuild every array bit for bit, whatever its content (a mesh's periodic
stencils, boundary entries, irregular data, signed zeros, inf and NaN), and a uniform mesh's
module must not grow with the element count.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import phc
from phc.codegen import packing

MODELS = Path(__file__).resolve().parents[2] / "models"


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


def _stencil_indices(n: int) -> np.ndarray:
    """Indices of a 1-D mesh's blocks: two boundary rows, n elements of an interleaved
    five-entry stencil, a second mesh with another stencil."""
    first = (np.arange(n)[:, None] * 4 + np.array([0, 1, 4, 2, 3])).ravel()
    second = (np.arange(n // 3)[:, None] * 3 + np.array([1, 2, 0])).ravel() + 10 * n
    return np.concatenate([[5, 9, 2], first, [7, 7, 1], second]).astype(np.int64)


@pytest.mark.parametrize("seed", range(4))
def test_every_array_comes_back_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    arrays = [(_stencil_indices(int(rng.integers(100, 5000))), "<i8"),
              (rng.integers(-10**12, 10**12, 20000).astype(np.int64), "<i8"),
              (np.concatenate([rng.random(10), np.tile([1.5, -2.0, 0.0, -0.0], 3000), [np.inf, np.nan, -np.inf],
                               np.tile([np.nan, 3.0], 2000), np.full(5000, 1e-300), rng.random(300)]), "<f8"),
              (rng.standard_normal(30000), "<f8")]
    for _ in range(100):  # interleaved sequences with a few entries off
        m = int(rng.integers(1, 4000))
        steps = rng.integers(-5, 5, size=int(rng.integers(1, 70)))
        x = np.cumsum(np.resize(steps, m)).astype(np.int64)
        x[rng.integers(0, m, size=3)] += 1
        arrays += [(x, "<i8"), (x.astype(float), "<f8"), (np.resize(steps.astype(float) / 3, m), "<f8")]
    for values, dtype in arrays:
        assert _same_bits(packing.decode(packing.pieces(values, dtype), dtype), values)


def test_int32_index_arrays_come_back_exactly():
    """The module's own index arrays are int32 where they fit (:func:`phc.codegen.printer._index_type`):
    their runs are found and rebuilt in int64, also near the top of the int32 range, where a run's
    second differences do not fit in 32 bits."""
    rng = np.random.default_rng(7)
    top = 2 ** 31 - 1
    arrays = [_stencil_indices(3000).astype(np.int32),
              np.concatenate([np.arange(5000) * 400_000, [top, 0, top, 0] * 300, [-2 ** 31, top]]).astype(np.int32),
              rng.integers(-2 ** 31, 2 ** 31, 5000).astype(np.int32)]
    for values in arrays:
        back = packing.decode(packing.pieces(values, "<i4"), "<i4")
        assert back.dtype == np.int32 and np.array_equal(back, values)


def test_a_mesh_stencil_prints_in_constant_size():
    sizes = [len(packing.expression(_stencil_indices(n), "<i8")) for n in (1000, 10000, 100000)]
    assert sizes[0] == pytest.approx(sizes[2], abs=20)  # only the counts' digits differ
    floats = [len(packing.expression(np.tile([0.25, -1.0, 0.25], n), "<f8")) for n in (1000, 100000)]
    assert floats[0] == pytest.approx(floats[1], abs=5)


def test_a_uniform_string_module_does_not_grow_with_its_mesh(tmp_path):
    """The generated modules of a 1000-element and a 4000-element string differ only in the
    digits of their counts (below a few hundred elements a mesh's stretches are shorter than
    the window a period is read from, and print literally); both rebuild the pattern."""
    size = {}
    for n in (1000, 4000):
        path = tmp_path / f"string{n}.yaml"
        path.write_text((MODELS / "vibrating_string.yaml").read_text().replace("elements: 16", f"elements: {n}"))
        compiled = phc.compile_model(path, certify=False, backend="numpy")
        size[n] = len(compiled.source)
        mod = compiled.module
        assert len(mod.JAC_ROWS) == len(mod.JAC_COLS) > 8 * n  # the mesh's whole pattern, rebuilt
        assert mod.JAC_ROWS.dtype == np.int64 and mod.JAC_ROWS.max() < mod.N and mod.JAC_COLS.max() < mod.N
    assert abs(size[4000] - size[1000]) < 0.01 * size[1000]
