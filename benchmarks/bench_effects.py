"""Effect sets of the flexible slider–crank (issue 6, item 5): what fidelity costs.

The model `models/flexible_slider_crank.yaml` (seed section 5.2: crank wheel, moving-frame
Euler–Bernoulli rod with 8 Hermite elements, slider on a guide; crank at 150 rad/s, rod
straight at t = 0) is simulated over 0.1 s under five effect sets, each written as a
temporary scene file:

* full — every effect of the rod on;
* no moving frame — ``moving_frame: off`` (drops K_r, K_f of seed Prop.
  flexbeam-flexible-modulation);
* modal k = 2, 4 — ``modes: k`` (:mod:`phc.library.modal`: the 4 static boundary modes
  plus k fixed-interface modes of the rod's velocity field);
* rigid — ``flexibility: off`` (a rigid link with the rod's mass and inertia).

All rows use the same solver (implicit midpoint, step 2e-5 s, the step of the shipped
scene `slider_crank_rigid.yaml`) and the same output grid (201 points). Columns: compiled
size (states, equations, Jacobian nonzeros, as ``phc simulate`` reports them), CPU time of
``phc.simulate`` (process time, best of 3), the relative energy-balance error, and the
maximum error against the full model of the slider position ``rod.qf[0]`` and of the
midspan deflection ``rod.w[0]`` (n/a for the rigid rod, which has none).

Run: ``python benchmarks/bench_effects.py`` (prints a Markdown table).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import phc  # noqa: E402
from phc.frontend.files import allow_paths  # noqa: E402

MODEL = ROOT / "models" / "flexible_slider_crank.yaml"
STEP, T_END, N_OUT = 2.0e-5, 0.1, 201
EFFECT_SETS = [
    ("full", None),
    ("no moving-frame terms", "{moving_frame: off}"),
    ("modal k = 2", "{modes: 2}"),
    ("modal k = 4", "{modes: 4}"),
    ("rigid", "{flexibility: off}"),
]


def write_scene(directory: Path, index: int, effects) -> Path:
    flexible = effects is None or "flexibility: off" not in effects
    lines = ["format_version: 1", f"model: {MODEL.as_posix()}", f"name: effects_{index}"]
    if effects:
        lines += ["effects:", f"  rod: {effects}"]
    lines += [f"t_end: {T_END}", f"n_out: {N_OUT}", f"accuracy: {{step: {STEP}}}", "solver: midpoint",
              "outputs:", "  slider_x: rod.qf[0]"]
    if flexible:
        lines.append("  w_mid: rod.w[0]")
    path = directory / f"effects_{index}.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def run(path: Path, repeat: int = 3):
    with allow_paths([MODEL.parent]):  # the scenes are written to a temporary directory
        compiled = phc.compile_model(path)
    best, result = np.inf, None
    for _ in range(repeat):
        t0 = time.process_time()
        result = phc.simulate(compiled)
        best = min(best, time.process_time() - t0)
    if not result.success:
        raise RuntimeError(f"{path.name}: {result.message}")
    return compiled, result, best


def main() -> None:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        results = {}
        for i, (label, effects) in enumerate(EFFECT_SETS):
            compiled, result, cpu = run(write_scene(Path(tmp), i, effects))
            results[label] = (compiled, result, cpu)
            print(f"  {label}: {cpu:.2f} s", file=sys.stderr)
    reference = results["full"][1]
    for label, (compiled, result, cpu) in results.items():
        dx = np.abs(result["slider_x"] - reference["slider_x"]).max()
        dw = (f"{np.abs(result['w_mid'] - reference['w_mid']).max():.2e}" if "w_mid" in result.outputs
              else "n/a")
        rows.append(f"| {label} | {compiled.n_states} | {compiled.n_equations} | {compiled.jacobian_nnz} "
                    f"| {cpu:.2f} | {result.energy_balance_relative:.1e} | {dx:.2e} | {dw} |")
    w_scale = np.abs(reference["w_mid"]).max()
    print(f"Flexible slider–crank over {T_END} s, implicit midpoint h = {STEP} s "
          f"(max |w(L/2)| of the full model: {w_scale:.3e} m)\n")
    print("| effect set | states | equations | Jacobian nnz | CPU s (best of 3) | energy balance (rel.) "
          "| max error slider x [m] | max error w(L/2) [m] |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
