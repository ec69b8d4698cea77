"""What a state event costs in the compiled fixed-step loop (issue 34, item 8).

A block on a spring with Coulomb friction (``e_fr = Fc*sign(f_fr)``: switching conditions and a
set-valued sign, docs/events.md), driven by ``F sin(ω t)`` with F > F_c, sticks and slips again
a few times every period: many state events over a long run. On a compiled back end it runs

* with the compiled step loop (the chunk watches the switching functions after each step and
  hands back the step where one crosses zero; the Python loop's code locates the event,
  :mod:`phc.simulation.compiled_steps`), and
* with ``PHC_COMPILED_LOOP=0`` (the Python step loop on the same compiled functions: what every
  run with events did before),

against the same block with the law ``e_fr = d*f_fr`` at d = 0 (no friction, no events; the same
unknowns: a damped law would meet midpoint4's passivity guard, whose backward substep adds energy
through dissipation), compiled loop. It
prints the CPU time per step of each, and the cost of one event in steps of the event-free run:
(CPU of the run with events − its steps × the event-free run's CPU per step) / events. An
event's cost is the location (regula falsi on shortened steps, each a Newton solve in Python),
the restart from a consistent state (:func:`phc.simulation.events.integrate_switched`) and a
new entry into the compiled loop.

It runs on each back end of ``--backends`` (default ``numba,c``, those available); on ``c`` the C
step loop (``phc/codegen/c_runtime/steps.c``) watches the switching functions with the model
library's ``phc_events`` (its Python loop is what a run with events on the C back end did before).

CPU time (``time.process_time``): the compiled loop's runs best of ``--repeat`` after one warm-up
run (which compiles or loads the compiled loop and the model's functions), the Python loop's one
run (it takes seconds). Run from the repository root:
``python benchmarks/bench_event_cost.py``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import phc

BLOCK = """\
format_version: 1
name: driven_block
parameters:
  m: 1.0
  k: 4.0
  Fc: 1.0
  d: 0.0
  F: 2.5
  w: 3.0
components:
  push: {{type: effort_source, domain: mechanical.translational, value: "F*sin(w*t)"}}
  block:
    type: phs
    states: [p, x]
    hamiltonian: p**2/(2*m) + k*x**2/2
    ports:
      a: {{domain: mechanical.translational}}
    resistive:
      fr: {{law: ["{law}"]}}
    relations:
      - f_x = e_p
      - f_p = -e_x - e_fr - e_a
      - f_fr = e_p
      - f_a = e_p
connections:
  - [push.port, block.a]
simulation:
  t_end: {t_end}
  n_out: 201
  initial: {{block.x: 0.0, block.p: 0.0}}
"""

METHODS = (("midpoint", 1e-3), ("discrete_gradient", 1e-3), ("midpoint4", 2e-3))


def _run(model, solver, step, loop: str, repeat: int):
    """(best CPU seconds, the result) of `repeat` runs after a warm-up (the compiled loop's; the
    Python loop's runs call the functions the compiled loop's warm-up loaded, once: 5–20 s each)."""
    os.environ["PHC_COMPILED_LOOP"] = loop
    try:
        if loop != "0":
            phc.simulate(model, solver=solver, step=step)
        best, result = float("inf"), None
        for _ in range(repeat):
            start = time.process_time()
            result = phc.simulate(model, solver=solver, step=step)
            best = min(best, time.process_time() - start)
    finally:
        os.environ.pop("PHC_COMPILED_LOOP", None)
    assert result.success, result.message
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--t-end", type=float, default=20.0)
    parser.add_argument("--backends", default="numba,c",
                        help="back ends to measure, comma-separated (those that cannot be used are named and left out)")
    args = parser.parse_args()
    from phc.codegen.c_backend import available as c_available
    from phc.codegen.numba_backend import available as numba_available

    usable = {"numba": numba_available, "c": c_available}
    for backend in args.backends.split(","):
        ok, why = usable[backend]()
        if not ok:
            print(f"{backend} back end left out: {why}\n")
            continue
        _table(backend, args)
    print("One event in steps: (CPU of the run with events − its steps × the event-free run's CPU per step) / "
          "events / the event-free run's CPU per step; in ms: the same CPU over the events. Both include locating "
          "the event, the restart and re-entering the loop.")


def _table(backend: str, args) -> None:
    folder = Path(tempfile.mkdtemp())
    models = {}
    for name, law in (("events", "e_fr = Fc*sign(f_fr)"), ("smooth", "e_fr = d*f_fr")):
        path = folder / f"{name}.yaml"
        path.write_text(BLOCK.format(law=law, t_end=args.t_end))
        models[name] = phc.compile_model(path, certify=False, backend=backend)
        assert models[name].backend == backend, f"{backend} is needed"
    print(f"Driven Coulomb block (F = 2.5 F_c, ω = 3 rad/s) over {args.t_end:g} s, {backend} back end; CPU time, "
          f"best of {args.repeat} runs (the Python loop: one run).\n")
    print("| method | h | events | steps | µs/step, events, compiled loop | µs/step, events, Python loop "
          "| µs/step, no events (d = 0), compiled loop | one event, in steps (compiled loop) | one event [ms] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for solver, step in METHODS:
        fast, r_fast = _run(models["events"], solver, step, "1", args.repeat)
        slow, r_slow = _run(models["events"], solver, step, "0", 1)
        smooth, r_smooth = _run(models["smooth"], solver, step, "1", args.repeat)
        assert len(r_fast.events) == len(r_slow.events)
        n = max(len(r_fast.events), 1)
        per = smooth / r_smooth.steps
        event_fast = (fast - r_fast.steps * per) / n / per
        print(f"| {solver} | {step:g} | {len(r_fast.events)} | {r_fast.steps} | {1e6 * fast / r_fast.steps:.1f} "
              f"| {1e6 * slow / r_slow.steps:.1f} | {1e6 * per:.1f} | {event_fast:.0f} | {1e3 * event_fast * per:.2f} |")
    print()


if __name__ == "__main__":
    main()
