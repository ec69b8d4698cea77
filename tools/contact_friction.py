"""Coulomb friction at a closed contact against its closed forms, with every solver: the
table of docs/events.md ("Friction at a closed contact").

    PYTHONPATH=. python tools/contact_friction.py

Models: those of tests/simulation/test_friction.py. Columns: a block on a slope (θ = 0.4,
μ = 0.3) against s0 − ½ g (sin θ − μ cos θ) t²; a block launched at v0 = 3 on a floor
(μ = 0.3): its stop time against v0/(μ g), its position against the closed form; a block
pushed by c t: the slip time against t* = μ m g/c, x after against c (t − t*)³/(6 m); a block
on a spring (the Karnopp case): the reversal and stick times against π/2 and π; the largest
relative energy balance of the four runs; their CPU time.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "simulation"))

import phc  # noqa: E402
from test_friction import FLOOR, INCLINE, RAMP, SOLVERS, SPRING  # noqa: E402


def main() -> None:
    warnings.simplefilter("ignore")
    m, g, mu, theta, s0, v0, c = 2.0, 9.81, 0.3, 0.4, 2.0, 3.0, 4.0
    with tempfile.TemporaryDirectory() as tmp:
        models = {}
        for name, text in (("incline", INCLINE), ("floor", FLOOR), ("ramp", RAMP), ("spring", SPRING)):
            path = Path(tmp) / f"{name}.yaml"
            path.write_text(text)
            models[name] = phc.compile_model(path)
        print("| solver | slope s(t) | stop time | floor x(t) | slip time t* | x after t* | reversal, stick "
              "times | energy balance | CPU s |")
        print("|---|---|---|---|---|---|---|---|---|")
        for solver, kw in SOLVERS:
            cpu = time.process_time()
            runs = {name: phc.simulate(mod, solver=solver, **kw) for name, mod in models.items()}
            cpu = time.process_time() - cpu
            col = {name: (lambda n, r=r: r.y[:, r.variables.index(n)]) for name, r in runs.items()}
            r = runs["incline"]
            a = g * (math.sin(theta) - mu * math.cos(theta))
            s = math.cos(theta) * col["incline"]("block.x") + math.sin(theta) * col["incline"]("block.y")
            slope = np.abs(s - (s0 - 0.5 * a * r.t**2)).max()
            r = runs["floor"]
            t_s = v0 / (mu * g)
            stop = abs(r.events[-1].t - t_s)
            x = np.where(r.t < t_s, v0 * r.t - 0.5 * mu * g * r.t**2, v0**2 / (2 * mu * g))
            floor = np.abs(col["floor"]("block.x") - x).max()
            r = runs["ramp"]
            t_star = mu * m * g / c
            slip = abs(r.events[-1].t - t_star)
            after = r.t > t_star
            ramp = np.abs(col["ramp"]("bx.x")[after] - c * (r.t[after] - t_star)**3 / (6 * m)).max()
            r = runs["spring"]
            spring = max(abs(r.events[2].t - math.pi / 2), abs(r.events[3].t - math.pi))
            balance = max(run.energy_balance_relative for run in runs.values())
            step = f", h = {kw['step']:g}" if "step" in kw else ", rtol 1e-10"
            print(f"| `{solver}`{step} | {slope:.1e} | {stop:.1e} | {floor:.1e} | {slip:.1e} | {ramp:.1e} | "
                  f"{spring:.1e} | {balance:.1e} | {cpu:.1f} |")


if __name__ == "__main__":
    main()
