"""What BDF of each order must pay on a model's undamped modes: the lower bounds on IDA's steps
that no error weighting moves (issue 33, the 150 rad/s crank).

    python tools/bdf_mode_bounds.py models/scenes/slider_crank_150rad.yaml --steps 29316

Linearizes the model at its start (:func:`phc.linearize_model`), takes the undamped modes
(|Re λ| ≤ 1e-9 |λ|, ω = |Im λ|) and, for BDF of order k = 2 … 5 applied to ``y' = iωy``
(the characteristic polynomial ``Σ_{j=1..k} ∇^j/j − z`` in the shift, z = iωh), prints

* the band of ωh on the imaginary axis where its largest root has modulus above 1 (the
  undamped modes there grow every step: BDF1 and BDF2 have none, BDF3–5 have one);
* at ``--steps`` equal steps over the span, the worst mode's growth ``N·ln|ζ|`` over the
  run and how many modes grow beyond e;
* the fewest equal steps at which no mode grows beyond e over the run (the order's
  stability bound on this spectrum);
* BDF2's phase lag of the slowest oscillating mode over the run at ``--steps`` equal steps,
  ``N·|arg ζ − ωh|`` (≈ ω³h²T/3; for a fixed number of steps equal steps minimize Σh³, so a
  variable step sequence lags no less).

The error of an output the slowest mode moves is about that lag times the mode's share of
the output (0.36–0.45 of the crank's midspan deflection: docs/tolerances.md). A diagnostic
for developers, not part of phc's interface.
"""

from __future__ import annotations

import argparse
from math import comb

import numpy as np

import phc


def characteristic(k: int, z: complex) -> np.ndarray:
    """Coefficients (highest power first) of BDF-k's characteristic polynomial at z = hλ."""
    c = np.zeros(k + 1, complex)  # c[m]: coefficient of y_{n+1-m}
    for j in range(1, k + 1):
        for m in range(j + 1):
            c[m] += (-1) ** m * comb(j, m) / j
    c[0] -= z
    return c


def largest_root(k: int, wh: float) -> float:
    return float(np.max(np.abs(np.roots(characteristic(k, 1j * wh)))))


def unstable_band(k: int) -> tuple[float, float] | None:
    grid = np.logspace(-4, 2, 4000)
    bad = [x for x in grid if largest_root(k, x) > 1 + 1e-12]
    return (min(bad), max(bad)) if bad else None


def growth(k: int, omegas: np.ndarray, n: int, span: float) -> np.ndarray:
    """ln of each mode's amplification over n equal steps."""
    h = span / n
    return n * np.log(np.array([largest_root(k, w * h) for w in omegas]))


def fewest_stable_steps(k: int, omegas: np.ndarray, span: float, upto: int = 10**7) -> int | None:
    for n in np.unique(np.logspace(3, np.log10(upto), 600).astype(int)):
        if np.all(growth(k, omegas, int(n), span) < 1):
            return int(n)
    return None


def phase_lag(omega: float, n: int, span: float, k: int = 2) -> float:
    wh = omega * span / n
    roots = np.roots(characteristic(k, 1j * wh))
    principal = roots[np.argmin(np.abs(roots - np.exp(1j * wh)))]
    return float(n * abs(np.angle(principal) - wh))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("file")
    ap.add_argument("--steps", type=int, required=True, help="equal steps over the span to evaluate")
    ap.add_argument("--span", type=float, default=None, help="default: the scene's t_end − t_start")
    args = ap.parse_args(argv)
    lin = phc.linearize_model(args.file, certify=False)
    if args.span is None:
        opts = phc.compile_model(args.file, certify=False).options
        args.span = float(opts["t_end"]) - float(opts["t_start"])
    lam = np.array([m.eigenvalue for m in lin.modes])
    undamped = lam[(np.abs(lam.imag) > 0) & (np.abs(lam.real) <= 1e-9 * np.abs(lam))]
    omegas = np.sort(np.abs(undamped.imag))
    print(f"{args.file}: {len(omegas)} undamped modes, ω {omegas.min():.4g} … {omegas.max():.4g} rad/s; "
          f"span {args.span:g} s, {args.steps} equal steps (h = {args.span / args.steps:.3g} s)")
    out = {"omegas": omegas, "orders": {}}
    for k in (2, 3, 4, 5):
        band = unstable_band(k)
        g = growth(k, omegas, args.steps, args.span)
        n = fewest_stable_steps(k, omegas, args.span)
        out["orders"][k] = dict(band=band, worst=float(g.max()), growing=int(np.sum(g > 1)), fewest=n)
        print(f"  BDF{k}: unstable for ωh in " + (f"[{band[0]:.3g}, {band[1]:.3g}]" if band else "none")
              + f"; at {args.steps} steps the worst mode grows by e^{g.max():.3g} ({int(np.sum(g > 1))} modes beyond e);"
              + (f" no mode beyond e from {n} equal steps" if n else " every mode stays below e only beyond 1e7 steps"))
    lag = phase_lag(omegas.min(), args.steps, args.span)
    out["lag"] = lag
    print(f"  BDF2 phase lag of the slowest mode (ω = {omegas.min():.4g} rad/s) over the run: {lag:.3g} rad "
          f"(ω³h²T/3 = {omegas.min() ** 3 * (args.span / args.steps) ** 2 * args.span / 3:.3g})")
    return out


if __name__ == "__main__":
    main()
