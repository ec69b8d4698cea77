"""The BDF figures of `tools/bdf_mode_bounds.py` (issue 33: why the 150 rad/s crank's IDA steps
have a floor no error weighting moves) against what is known of BDF independently."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))

import bdf_mode_bounds as bounds  # noqa: E402


def test_only_bdf1_and_bdf2_are_stable_on_the_whole_imaginary_axis():
    """Dahlquist's second barrier: no A-stable linear multistep method has order above 2. BDF1
    and BDF2 are A-stable; BDF3–5 each leave part of the imaginary axis, where an undamped
    mode grows every step (BDF5's band ends above ωh = 9: its boundary locus reaches
    Re z > 0 only for |Im z| below about 10)."""
    assert bounds.unstable_band(1) is None and bounds.unstable_band(2) is None
    for k in (3, 4, 5):
        band = bounds.unstable_band(k)
        assert band is not None and band[0] < 1 < band[1] < 20, (k, band)
    assert bounds.largest_root(5, 1.0) > 1.1  # well inside BDF5's band: >10 % growth a step


@pytest.mark.parametrize("wh", [1e-3, 1e-2])
def test_bdf2_lags_an_undamped_mode_by_a_third_of_wh_cubed(wh):
    """The principal root of BDF2 on y' = iωy turns by ωh − (ωh)³/3 + O((ωh)⁵) a step (its
    series: error constant −2/9 of the local error ↔ a phase lag (ωh)³/3 per step), so over N
    steps the lag is N(ωh)³/3 — the formula the crank's analysis uses."""
    n, span = 1000, 1000 / 1.0
    omega = wh * n / span
    assert bounds.phase_lag(omega, n, span) == pytest.approx(n * wh ** 3 / 3, rel=5 * wh ** 2)


@pytest.mark.parametrize("k", [2, 3, 4, 5])
def test_the_principal_root_has_order_k(k):
    """BDF-k's principal root matches e^{iωh} to O((ωh)^{k+1}): halving ωh divides its error
    by about 2^{k+1} — the polynomial is BDF-k and not another method."""
    def err(wh):
        roots = np.roots(bounds.characteristic(k, 1j * wh))
        return np.min(np.abs(roots - np.exp(1j * wh)))
    ratio = err(0.02) / err(0.01)
    assert 2 ** (k + 1) * 0.9 < ratio < 2 ** (k + 1) * 1.1
