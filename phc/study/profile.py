"""Where the time goes: ``phc simulate --profile``.

CPU time of one run, split into the compile stages (read/elaborate/assemble/check, lower,
print, load, describe — from :attr:`phc.codegen.compiled.CompiledModel.timings`), the generated module's
residual and Jacobian evaluations (timed by wrapping the module's functions during the
run), the rest of the integration (the solver's own work: step control, Newton updates,
sparse LU factorizations and solves), and post-processing (energy figures, outputs).
A user reads it to decide: many residual evaluations → loosen the tolerance or switch
effects off; expensive Jacobians/factorizations → coarsen the mesh; compile → cache hits.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field


@dataclass
class _Counter:
    calls: int = 0
    seconds: float = 0.0


@dataclass
class Profile:
    compile: dict[str, float]
    counters: dict[str, _Counter] = field(default_factory=dict)
    run_cpu: float = 0.0
    """CPU seconds of the integration (consistent initialization included)."""
    total_cpu: float = 0.0
    """CPU seconds of `simulate` as a whole (post-processing included)."""

    def rows(self) -> list[tuple[str, float, str]]:
        """(part, seconds, note) in the order they happen."""
        stages = {"elaborate": "read, elaborate, assemble, structural check", "lower": "Jacobian (symbolic)",
                  "print": "code generation", "load": "import of the generated module",
                  "describe": "model description (initial values, places of the outputs)"}
        out = [(f"compile: {k}", v, stages.get(k, "")) for k, v in self.compile.items()]
        res, jac = self.counters.get("residual", _Counter()), self.counters.get("jacobian", _Counter())
        out.append(("residual evaluations", res.seconds, f"{res.calls} calls, "
                    f"{1e6 * res.seconds / max(res.calls, 1):.1f} µs each"))
        out.append(("Jacobian evaluations", jac.seconds, f"{jac.calls} calls, "
                    f"{1e6 * jac.seconds / max(jac.calls, 1):.1f} µs each"))
        solver = max(self.run_cpu - res.seconds - jac.seconds, 0.0)
        out.append(("solver and linear algebra", solver, "step control, Newton, sparse LU factorizations and solves"))
        out.append(("post-processing", max(self.total_cpu - self.run_cpu, 0.0), "energy balance, invariants, outputs"))
        return out

    def to_dict(self) -> dict:
        return {part: {"seconds": sec, "note": note} for part, sec, note in self.rows()}

    def render_text(self) -> str:
        rows = self.rows()
        total = sum(sec for _, sec, _ in rows) or 1.0
        lines = ["  profile  (CPU seconds)"]
        for part, sec, note in rows:
            lines.append(f"    {part:<28} {sec:9.4f}  {100 * sec / total:5.1f} %  {note}")
        lines.append(f"    {'total':<28} {total:9.4f}")
        return "\n".join(lines)


@contextmanager
def profiled(compiled):
    """Time the generated module's residual and Jacobian while the block runs (the module
    functions are wrapped and restored afterwards)."""
    mod = compiled.module
    prof = Profile(dict(compiled.timings))
    saved = {}
    for name in ("residual", "jacobian"):
        func = getattr(mod, name)
        counter = prof.counters[name] = _Counter()

        def wrapper(*args, _func=func, _counter=counter):
            t = time.process_time()
            try:
                return _func(*args)
            finally:
                _counter.seconds += time.process_time() - t
                _counter.calls += 1

        saved[name] = func
        setattr(mod, name, wrapper)
    start = time.process_time()
    try:
        yield prof
    finally:
        prof.total_cpu = time.process_time() - start
        for name, func in saved.items():
            setattr(mod, name, func)
