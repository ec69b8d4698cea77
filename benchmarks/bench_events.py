"""Event-time and solution errors of the non-smooth test models (issue 14, item 2).

Runs the models of ``tests/simulation/test_events.py`` — an RL circuit whose source steps
at ``t = T`` (``ifelse(t < T, 0, V0)``), a Coulomb-friction block on a spring (slips,
reverses at π/2, sticks at π), a block pushed by ``c·t`` against Coulomb friction (sticks
until ``F_c/c``), and a half-wave rectifier (diode ``ifelse(e_D > 0, …)``) — with each
solver, and prints the errors of the located switching times and of the outputs against
the closed forms and the independent scipy solution defined in that test file. The
figures are those of ``docs/events.md``.

Run from the repository root: ``python benchmarks/bench_events.py``.
"""

from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "simulation"))

import phc  # noqa: E402
import test_events as models  # noqa: E402


def _compile(folder: Path, text: str, name: str):
    path = folder / name
    path.write_text(text)
    return phc.compile_model(path)


def main() -> None:
    folder = Path(tempfile.mkdtemp())
    rl = _compile(folder, models.RL.format(value="ifelse(t < T, 0, V0)"), "rl.yaml")
    for solver in ("ida", "midpoint"):
        for T in (0.01, 0.0123456789012):
            r = phc.simulate(rl, params={"T": T}, **models._step_kw(solver, 1e-4))
            print(f"source step     {solver:17s} T = {T}: |t_event - T| = {abs(r.events[0].t - T):.1e}")
    block = _compile(folder, models.FRICTION.format(law="e_fr = Fc*sign(f_fr)"), "friction.yaml")
    for solver, h in (("ida", None), ("midpoint", 1e-3), ("discrete_gradient", 1e-3), ("midpoint4", 2e-3)):
        r = phc.simulate(block, **models._step_kw(solver, h))
        errors = (abs(r.events[0].t - math.pi / 2), abs(r.events[1].t - math.pi))
        x_error = np.abs(r["block.x"] - models._coulomb_closed_form(r.t)).max()
        print(f"Coulomb block   {solver:17s} h = {h}: reversal {errors[0]:.1e}, stick {errors[1]:.1e}, "
              f"position {x_error:.1e}, energy balance {r.energy_balance_relative:.1e}")
    pushed = _compile(folder, models.PUSHED.format(force="c*t"), "pushed.yaml")
    for solver in ("ida", "midpoint"):
        r = phc.simulate(pushed, **models._step_kw(solver, 1e-3))
        v = np.where(r.t < 0.75, 0.0, (r.t - 0.75) ** 2)
        print(f"pushed block    {solver:17s}: slip {abs(r.events[1].t - 0.75):.1e}, "
              f"velocity {np.abs(r['v'] - v).max():.1e}")
    rectifier = _compile(folder, models.RECTIFIER, "rectifier.yaml")
    for solver, h in (("ida", None), ("midpoint", 1e-5), ("midpoint4", 1e-5)):
        r = phc.simulate(rectifier, **models._step_kw(solver, h))
        reference, switches = models._rectifier_reference(r.t)
        worst = max(abs(e.t - s) for e, s in zip(r.events, switches))
        print(f"rectifier       {solver:17s} h = {h}: {len(r.events)} switches to {worst:.1e} s, "
              f"capacitor voltage {np.abs(r['vC'] - reference).max():.1e} V")


if __name__ == "__main__":
    main()
