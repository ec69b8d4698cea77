"""Where IDA's steps go: which variables dominate its weighted local-error norm, and what
the outputs' error is against a fine fixed-step reference.

    python tools/ida_error_budget.py models/scenes/slider_crank_150rad.yaml --rtol 1e-6 --atol 1e-8
    python tools/ida_error_budget.py SCENE --rtol 1e-6 --atol 1e-8 --loosen 'rod\\.kappa' 100
    python tools/ida_error_budget.py SCENE --rtol 1e-6 --atol 1e-8 --max-order 5

Runs IDA exactly as ``phc simulate --solver ida`` does (same scales, tolerances and order
choice), records every accepted step's (t, y) from phc's step hook, and estimates each
variable's local error of the steps as ``h³·y'''`` (third divided differences over the last
four step points: BDF2's error behaves so, and a constant factor common to all variables
does not change which dominates), weighted by IDA's own weights ``1/(rtol_loc·|y_i| + atol_i)``
with the tolerances phc passes to IDA (variables left out of IDA's error test are left out).
A step whose end lies past an output time is seen at that output time and not recorded (200
of the crank's 115 935 steps); the divided differences then span two steps (``--n-out``
sets fewer output times).
Printed: steps, CPU, the outputs' largest error over the output times relative to the
reference's range and to its largest magnitude (reference: ``midpoint4`` at
``--reference-step``), the variables with the largest share of the squared weighted error
(each step's split, averaged over the steps) and how often each is the largest, and how often the relative part ``rtol_loc·|y|``
of the dominant variable's tolerance exceeds its absolute part.

``--modes`` also splits the weighted local error of the differential variables among the
modes of the linearization (``F_ẏ λ v = −F_y v``, dense QZ, the energy accumulator left out)
at 25 steps spread over the run, by their ``|Im λ|``: the error vector is written in the
finite modes' eigenvectors (least squares), each mode's part is weighted as above, and each
step's split counts once in the average. The eigenvectors are not orthogonal in the weighted
norm, so the shares are a guide, not a partition.

``--local FRACTION`` sets IDA's local tolerance fraction (phc's is
``phc.simulation.ida.LOCAL_TOLERANCE``, 1/200) for the run.

``--loosen REGEX FACTOR`` multiplies IDA's absolute tolerance of the variables whose names
match by FACTOR (an experiment: which variables' tolerances hold the steps); ``--max-order``
fixes IDA's maximum order. A diagnostic for developers: it wraps phc's internal step hook and
tolerance set-up (phc.simulation.ida) and is not part of phc's interface.
"""

from __future__ import annotations

import argparse
import re
import time
import warnings

import numpy as np

import phc
import phc.simulation.ida as ida


def main(argv=None) -> dict:
    """Run and print; returns the figures printed: ``steps``, ``errors`` (output name →
    (of its range, of its largest magnitude)), ``share`` (variable name → share of the squared
    weighted local error), ``relative`` and, with ``--modes``, ``modes`` ((low, high) → share)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("file")
    ap.add_argument("--rtol", type=float, default=1e-6)
    ap.add_argument("--atol", type=float, default=1e-8)
    ap.add_argument("--max-order", type=int, default=None)
    ap.add_argument("--loosen", nargs=2, action="append", default=[], metavar=("REGEX", "FACTOR"))
    ap.add_argument("--reference-step", type=float, default=2.5e-6)
    ap.add_argument("--backend", default=None)
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--local", type=float, default=None)
    ap.add_argument("--modes", action="store_true")
    ap.add_argument("--n-out", type=int, default=None, help="output times (fewer: more steps recorded)")
    args = ap.parse_args(argv)

    compiled = phc.compile_model(args.file, certify=False, backend=args.backend)
    seen: dict = {}
    options = ida.solver_options

    def solver_options(mod, p, *, rtol, atol, **kw):
        atol = np.array(atol, dtype=float)
        names = list(mod.VARIABLES)
        for pattern, factor in args.loosen:
            hit = [j for j, name in enumerate(names) if re.search(pattern, name)]
            atol[hit] *= float(factor)
        settings, state = options(mod, p, rtol=rtol, atol=atol, **kw)
        seen.update(names=names, rtol=rtol, atol=np.array(settings["atol"], dtype=float), mod=mod, p=p)
        return settings, state

    ts, ys = [], []
    hook = ida._StepHook
    call, rewind = hook.__call__, hook.rewind

    def record(self, t, y, yp):
        step = self.calls.evaluations != self.evaluations_seen and t != self.target
        call(self, t, y, yp)
        if step:
            ts.append(float(t))
            ys.append(np.array(y))

    def restart(self, *a):  # phc started the run again at another order: keep the last run's steps
        ts.clear()
        ys.clear()
        return rewind(self, *a)

    fraction = ida.local_fraction
    ida.solver_options, hook.__call__, hook.rewind = solver_options, record, restart
    if args.local is not None:
        ida.local_fraction = lambda rtol: args.local
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            start = time.process_time()
            run = phc.simulate(compiled, solver="ida", rtol=args.rtol, atol=args.atol, max_order=args.max_order,
                               n_out=args.n_out)
            cpu = time.process_time() - start
    finally:
        ida.solver_options, hook.__call__, hook.rewind = options, call, rewind
        ida.local_fraction = fraction
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = phc.simulate(compiled, solver="midpoint4", step=args.reference_step, t_eval=run.t)
    figures: dict = {"steps": run.steps, "errors": {}}
    print(f"{args.file}: IDA rtol {args.rtol:g}, atol {args.atol:g}: {run.steps} steps, {cpu:.2f} s CPU, "
          f"success {run.success}")
    print(f"  {run.message}")
    for name, values in run.outputs.items():
        a, b = np.asarray(values, dtype=float), np.asarray(ref.outputs[name], dtype=float)
        k = min(len(a), len(b))
        err = float(np.abs(a[:k] - b[:k]).max())
        figures["errors"][name] = (err / np.ptp(b[:k]), err / np.abs(b[:k]).max())
        print(f"  output {name}: error {err / np.ptp(b[:k]):.2e} of its range, "
              f"{err / np.abs(b[:k]).max():.2e} of its largest magnitude (midpoint4, h = {args.reference_step:g})")

    T, Y = np.array(ts), np.array(ys)
    names, atol, rtol = seen["names"], seen["atol"], seen["rtol"]
    D = Y.copy()
    for j in range(1, 4):
        D = (D[1:] - D[:-1]) / (T[j:] - T[:-j])[:, None]
    h = np.diff(T)[2:]
    weighted = np.abs((h ** 3)[:, None] * 6.0 * D) / (rtol * np.abs(Y[3:]) + atol[None, :])
    weighted[:, atol >= ida.ALGEBRAIC_ATOL] = 0.0  # not in IDA's error test
    # each step's split of its squared weighted error, averaged over the steps (a few steps,
    # such as the first ones, must not outweigh the rest)
    square = weighted ** 2
    total = square.sum(axis=1)
    share = (square[total > 0] / total[total > 0, None]).mean(axis=0)
    top = weighted.argmax(axis=1)
    often = np.bincount(top, minlength=len(names)) / len(top)
    relative = (rtol * np.abs(Y[3:])[np.arange(len(top)), top] > atol[top]).mean()
    print(f"  {len(T)} steps of the last run recorded (h median {np.median(np.diff(T)):.2e} s); "
          f"IDA's local rtol {rtol:.1e}")
    print("  variable                 share  largest  atol_i (IDA)")
    for j in np.argsort(-share)[:args.top]:
        print(f"  {names[j]:22s} {share[j]:7.3f} {often[j]:8.3f}  {atol[j]:.2e}")
    print(f"  the dominant variable's relative part rtol·|y| exceeds its atol_i at {relative:.0%} of the steps")
    figures.update(share={name: float(share[j]) for j, name in enumerate(names)}, relative=float(relative))
    if args.modes:
        figures["modes"] = _modes(seen, T, Y, (h ** 3)[:, None] * 6.0 * D, rtol, atol)
    return figures


def _modes(seen, T, Y, E, rtol, atol) -> dict:
    import scipy.linalg as sla

    from phc.study.linearize import dense_jacobians

    mod, p = seen["mod"], seen["p"]
    # the energy accumulator (its rate is the power; nothing depends on it) is no part of the
    # model's dynamics: left out, its zero eigenvalue does not absorb the others' parts
    keep = np.array([name != "energy.supplied" for name in seen["names"]])
    tested = (np.asarray(mod.DIFFERENTIAL, dtype=bool) & (atol < ida.ALGEBRAIC_ATOL))[keep]
    Y_full = Y
    Y, E, atol = Y[:, keep], E[:, keep], atol[keep]
    bands = [(0.0, 2e3), (2e3, 2e4), (2e4, 2e5), (2e5, np.inf)]
    total = np.zeros(len(bands))
    for n in np.linspace(10, len(E) - 1, 25).astype(int):
        y, t = Y[n + 3], T[n + 3]
        yp = (Y_full[n + 3] - Y_full[n + 2]) / (T[n + 3] - T[n + 2])
        Fy, Fyp = dense_jacobians(mod, t, Y_full[n + 3], yp, p)
        Fy, Fyp = Fy[np.ix_(keep, keep)], Fyp[np.ix_(keep, keep)]
        lam, V = sla.eig(-Fy, Fyp)
        finite = np.isfinite(lam) & (np.abs(lam) < 1e8)
        Vd = V[tested][:, finite]
        c = np.linalg.lstsq(Vd, E[n][tested].astype(complex), rcond=None)[0]
        w = 1.0 / (rtol * np.abs(y[tested]) + atol[tested])
        part = np.array([np.mean(np.abs(w * c[m] * Vd[:, m]) ** 2) for m in range(Vd.shape[1])])
        omega = np.abs(lam[finite].imag)
        if part.sum() > 0:  # each step's split counts once (a few steps must not outweigh the rest)
            for b, (lo, hi) in enumerate(bands):
                total[b] += part[(omega >= lo) & (omega < hi)].sum() / part.sum()
    total /= total.sum()
    print("  share of the weighted local error of the differential variables by mode, |Im λ| in rad/s:")
    for (lo, hi), share in zip(bands, total):
        print(f"    [{lo:.0e}, {hi:.0e}): {share:.3f}")
    return {band: float(share) for band, share in zip(bands, total)}


if __name__ == "__main__":
    main()
