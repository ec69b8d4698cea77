"""Persistent contact against its closed forms, with every solver that handles events: the
table of docs/events.md ("Persistent contact").

    PYTHONPATH=. python tools/persistent_contact.py

Models: the bouncing ball and the ball lifted off the floor of tests/simulation/test_impacts.py
(BALL to 6 s, LIFT). Columns: the ball closes its contact at the 62nd impact; its time against
the closed form t1 (1 + 2 e (1 − e^61)/(1 − e)); the largest |λ − m g| and |x| while it rests;
the energy dissipated against m g h0; the energy balance; then the lift-off time against
t* = m g/c, x against c (t − t*)³/(6 m), and the CPU time of both runs.
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
from test_impacts import BALL, LIFT, SOLVERS  # noqa: E402


def main() -> None:
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        ball = Path(tmp) / "ball.yaml"
        ball.write_text(BALL)
        lift = Path(tmp) / "lift.yaml"
        lift.write_text(LIFT)
        ball, lift = phc.compile_model(ball), phc.compile_model(lift)
        m, g, h0, e, c = 0.1, 9.81, 1.0, 0.8, 2.0
        t1 = math.sqrt(2 * h0 / g)
        t_close = t1 * (1 + 2 * e * (1 - e**61) / (1 - e))
        t_lift = m * g / c
        print("| solver | closes at (error) | |λ − m g| at rest | |x| at rest | energy dissipated (relative) "
              "| energy balance | lift-off time (error) | x after lift-off (error) | CPU s |")
        print("|---|---|---|---|---|---|---|---|---|")
        for solver, kw in SOLVERS:
            start = time.process_time()
            r = phc.simulate(ball, solver=solver, t_end=6.0, **kw)
            closes = [ev.t for ev in r.events if ev.kind == "close"]
            x = r.y[:, r.variables.index("ball.x")]
            force = r.y[:, r.variables.index("floor.force")]
            rest = r.t > closes[0]
            lost = r.energy_supplied[-1] + m * g * (h0 - x[-1])
            q = phc.simulate(lift, solver=solver, **kw)
            cpu = time.process_time() - start
            opened = [ev.t for ev in q.events if ev.kind == "open"]
            xl = q.y[:, q.variables.index("ball.x")]
            after = q.t > t_lift
            exact = c * (q.t[after] - t_lift)**3 / (6 * m)
            step = f", h = {kw['step']:g}" if "step" in kw else ", rtol 1e-11"
            print(f"| `{solver}`{step} | {abs(closes[0] - t_close):.1e} | {np.abs(force[rest] - m * g).max():.1e} "
                  f"| {np.abs(x[rest]).max():.1e} | {abs(lost / (m * g * h0) - 1):.1e} "
                  f"| {max(r.energy_balance_relative, 1e-300):.1e} | {abs(opened[0] - t_lift):.1e} "
                  f"| {np.abs(xl[after] - exact).max():.1e} | {cpu:.1f} |")


if __name__ == "__main__":
    main()
