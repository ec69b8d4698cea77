"""Scale of `phc check`: building and certifying a chain of library components.

A chain of P mass–spring units: mass i sits on a common-flow (1-)junction j_i, spring i
on a common-effort (0-)junction z_i between j_i and j_{i+1}; the left end is free
(zero_effort), the right end is held by a wall (zero_flow). That is 4P + 2 components and
4P + 1 connections, written as YAML into a temporary directory. For each size we time,
separately (wall clock, best of 3, sympy's expression cache cleared before each run so
that repeated runs do not get cheaper than a first one):

* ``phc.build_dae`` — read, elaborate, assemble, structural check;
* ``phc.checks.certify.certify`` — Dirac property of every component and the rank of the
  coupling map Γ of every connection, interconnected breadth-first, at 3 sampled states.

The certificate interconnects one connection at a time and represents each cluster by its
projection onto its open ports, so its cost should grow linearly with the number of
components: the ratio column divides the certify time by that of the 50-component chain.

Run: ``python benchmarks/bench_certify_chain.py`` (prints a Markdown table).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from sympy.core.cache import clear_cache

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import phc  # noqa: E402
from phc.checks.certify import certify  # noqa: E402

UNITS = (6, 12, 25, 50)          # 26, 50, 102, 202 components
BASELINE_UNITS = 12              # the 50-component chain
REPEAT = 3


def chain_yaml(units: int) -> str:
    dom = "domain: mechanical.translational"
    lines = ["format_version: 1", f"name: chain_{units}", "components:",
             f"  free: {{type: zero_effort, {dom}}}", f"  wall: {{type: zero_flow, {dom}}}"]
    for i in range(1, units + 1):
        lines += [f"  m{i}: {{type: mass, m: 1.0}}",
                  f"  k{i}: {{type: spring, k: 4.0}}",
                  f"  j{i}: {{type: junction, kind: common_flow, {dom}, ports: [m, l, r]}}",
                  f"  z{i}: {{type: junction, kind: common_effort, {dom}, ports: [l, r, k]}}"]
    lines += ["connections:", "  - [j1.l, free.port]"]
    for i in range(1, units + 1):
        lines += [f"  - [j{i}.m, m{i}.port]", f"  - [j{i}.r, z{i}.l]", f"  - [z{i}.k, k{i}.port]",
                  f"  - [z{i}.r, j{i + 1}.l]" if i < units else f"  - [z{i}.r, wall.port]"]
    lines += ["simulation:", "  initial: {k1.x: 0.1}"]
    return "\n".join(lines) + "\n"


def best_of(fn, repeat=REPEAT):
    best, value = float("inf"), None
    for _ in range(repeat):
        clear_cache()
        t = time.perf_counter()
        value = fn()
        best = min(best, time.perf_counter() - t)
    return best, value


def measure(directory: Path, units: int) -> dict:
    path = directory / f"chain_{units}.yaml"
    path.write_text(chain_yaml(units))
    build_s, (dae, diags) = best_of(lambda: phc.build_dae(path))
    if dae is None:
        raise SystemExit("\n".join(d.render() for d in diags))
    certify_s, cert = best_of(lambda: certify(dae))
    if not cert.certified:
        raise SystemExit(cert.render_text())
    return {"components": len(dae.topology.components), "connections": len(dae.topology.connections),
            "build": build_s, "certify": certify_s}


def main() -> None:
    # warm up imports and first-call costs outside the measurements
    with tempfile.TemporaryDirectory() as tmp:
        measure(Path(tmp), 2)
        rows = [measure(Path(tmp), units) for units in UNITS]
    base = next(r for r, u in zip(rows, UNITS) if u == BASELINE_UNITS)
    print("| components | connections | build_dae [s] | certify [s] | certify ratio vs 50 | "
          "certify per component [ms] |")
    print("|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['components']} | {r['connections']} | {r['build']:.3f} | {r['certify']:.3f} | "
              f"{r['certify'] / base['certify']:.2f} | {1e3 * r['certify'] / r['components']:.2f} |")


if __name__ == "__main__":
    main()
