"""What `rtol` gives against closed forms and independent solutions, and whether units matter.

    python benchmarks/record.py units -- python benchmarks/bench_units.py

Three studies, each against a solution that does not come from phc:

* a 1 mm, 0.1 g pendulum released at 90° (two periods), written once in SI and once in
  grams and centimetres (mass ×1e3, length ×1e2, time ×1), IDA at ``rtol = atol`` from 1e-4
  to 1e-10, and the fixed-step solvers at equal steps; the error is the largest of
  ``|x/L − sin φ|`` against ``scipy.integrate.solve_ivp`` (DOP853, rtol = atol = 1e-12) on
  the minimal coordinate φ;
* ``models/mass_spring_damper.yaml`` at ``rtol = atol = 1e-6`` against its closed form;
* ``models/pendulum.yaml`` (8.5 periods of a 90° swing) at ``rtol = 1e-6``, ``atol`` 1e-6
  and 1e-12, against DOP853 at 1e-13 on φ.

docs/tolerances.md includes the table this script writes; the tests in
tests/simulation/test_scaling.py assert the same relations (factor ≤ 3 between the unit
systems, the closed form within 1e-4).
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import phc  # noqa: E402

SMALL_PENDULUM = """\
format_version: 1
name: small_pendulum
parameters:
  m: 1.0e-4
  L: 1.0e-3
  g: 9.81
components:
  bob:
    type: rigid
    q: [x, y]
    v: [vx, vy]
    M: [[m, 0], [0, m]]
    V: m*g*y
    constraints:
      - x**2 + y**2 - L**2
simulation:
  t_end: 0.15
  n_out: 151
  initial: {bob.x: L, bob.y: 0.0, bob.p_vx: 0.0, bob.p_vy: 0.0}
  outputs:
    x: bob.x
"""
SI = dict(m=1e-4, L=1e-3, g=9.81)
GRAMS_CM = dict(m=1e-4 * 1e3, L=1e-3 * 1e2, g=9.81 * 1e2)


def _phi(t, g, L, tol=1e-12):
    sol = solve_ivp(lambda _, u: [u[1], -g / L * math.sin(u[0])], (t[0], t[-1]), [math.pi / 2, 0.0],
                    method="DOP853", rtol=tol, atol=tol, t_eval=t)
    return sol.y[0]


def _small_error(compiled, params, **options):
    t0 = time.perf_counter()
    r = phc.simulate(compiled, params=params, **options)
    wall = time.perf_counter() - t0
    if not r.success:
        return float("nan"), r.steps, wall
    phi = _phi(r.t, params["g"], params["L"])
    return float(np.abs(r["x"] / params["L"] - np.sin(phi)).max()), r.steps, wall


def _pendulum_errors(r) -> dict[float, float]:
    """Largest error of the shipped pendulum's angle (relative to its 90° amplitude) up to
    t = 2, 10 and 20 s, against DOP853 at 1e-13 on the minimal coordinate."""
    phi = _phi(r.t, 9.81, 1.0, tol=1e-13)
    err = np.abs(np.asarray(r["angle"]) - phi) / (math.pi / 2)
    return {T: float(err[r.t <= T + 1e-12].max()) for T in (2.0, 10.0, 20.0)}


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "small_pendulum.yaml"
        path.write_text(SMALL_PENDULUM)
        small = phc.compile_model(path, certify=False, backend="numpy")
        print("### A 1 mm pendulum in SI and in grams–centimetres (two periods of a 90° swing)\n")
        print("Largest error of x/L against DOP853 at 1e-12 on the angle.\n")
        print("| solver | rtol = atol or step | error, SI | error, g–cm | factor | error / rtol (SI) | steps (SI) |")
        print("|---|---|---:|---:|---:|---:|---:|")
        for tol in (1e-4, 1e-6, 1e-8, 1e-10):
            e_si, steps, _ = _small_error(small, SI, rtol=tol, atol=tol)
            e_cg, _, _ = _small_error(small, GRAMS_CM, rtol=tol, atol=tol)
            print(f"| ida | {tol:g} | {e_si:.2e} | {e_cg:.2e} | {max(e_si, e_cg) / min(e_si, e_cg):.2f} "
                  f"| {e_si / tol:.0f} | {steps} |")
        for solver, step in (("midpoint", 2e-4), ("discrete_gradient", 2e-4), ("midpoint4", 1e-3)):
            e_si, steps, _ = _small_error(small, SI, solver=solver, step=step, t_end=0.08)
            e_cg, _, _ = _small_error(small, GRAMS_CM, solver=solver, step=step, t_end=0.08)
            print(f"| {solver} (to t = 0.08) | h = {step:g} | {e_si:.2e} | {e_cg:.2e} "
                  f"| {max(e_si, e_cg) / min(e_si, e_cg):.2f} | — | {steps} |")

    print("\n### Shipped models at rtol = 1e-6\n")
    print("| model | against | atol | largest error | relative to | steps | wall [s] |")
    print("|---|---|---|---:|---|---:|---:|")
    msd = phc.compile_model(ROOT / "models" / "mass_spring_damper.yaml", certify=False, backend="numpy")
    t0 = time.perf_counter()
    r = phc.simulate(msd, rtol=1e-6, atol=1e-6)
    wall = time.perf_counter() - t0
    m, k, c, x0 = 1.0, 4.0, 0.4, 0.5
    w = math.sqrt(k / m)
    zeta = c / (2 * math.sqrt(k * m))
    wd = w * math.sqrt(1 - zeta**2)
    closed = np.exp(-zeta * w * r.t) * (x0 * np.cos(wd * r.t) + zeta * w * x0 / wd * np.sin(wd * r.t))
    print(f"| mass_spring_damper, 10 s (3 periods, decaying) | closed form | 1e-6 "
          f"| {np.abs(r['x'] - closed).max() / x0:.1e} | x₀ | {r.steps} | {wall:.2f} |")
    pend = phc.compile_model(ROOT / "models" / "pendulum.yaml", certify=False, backend="numpy")
    for atol in (1e-6, 1e-12):
        t0 = time.perf_counter()
        r = phc.simulate(pend, rtol=1e-6, atol=atol)
        wall = time.perf_counter() - t0
        at = _pendulum_errors(r)
        print(f"| pendulum, 20 s (8.5 periods of a 90° swing) | DOP853 at 1e-13 | {atol:g} "
              f"| {at[20.0]:.1e} (to t = 2: {at[2.0]:.1e}; to t = 10: {at[10.0]:.1e}) | 90° | {r.steps} | {wall:.2f} |")
    try:
        fast = phc.compile_model(ROOT / "models" / "pendulum.yaml", certify=False, backend="numba")
    except Exception:  # noqa: BLE001 - numba is optional: the NumPy module then
        fast = pend
    backend = getattr(fast, "backend", None) or "numpy"
    print(f"\nThe same pendulum with phc's energy-conserving solvers (no `rtol`: the step sets the accuracy; "
          f"{backend} backend, after a warm-up run):\n")
    print("| solver | step | largest error (relative to 90°) | to t = 2 | to t = 10 "
          "| energy balance error (relative) | steps | wall [s] |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for solver, step in (("midpoint4", 1e-2), ("midpoint4", 4e-3), ("discrete_gradient", 1e-3)):
        phc.simulate(fast, solver=solver, step=step, t_end=0.1)  # warm-up (JIT of the step loop)
        t0 = time.perf_counter()
        r = phc.simulate(fast, solver=solver, step=step)
        wall = time.perf_counter() - t0
        at = _pendulum_errors(r)
        print(f"| {solver} | {step:g} | {at[20.0]:.1e} | {at[2.0]:.1e} | {at[10.0]:.1e} "
              f"| {r.energy_balance_relative:.1e} | {r.steps} | {wall:.2f} |")
    print("\nIDA's error grows faster than linearly in time (its energy drifts, and with it the period); "
          "an energy-conserving solver's phase error grows linearly.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
