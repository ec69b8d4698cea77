"""Results that do not hang on the last bits of floating point.

BLAS kernels, FMA and summation order differ between CPUs, and with them the round-off of
every solve. The outcomes below once depended on it (each was right on one processor and
wrong on another); they are rerun here in fresh processes under OpenBLAS kernels for other
CPUs (``OPENBLAS_CORETYPE``, read by OpenBLAS when it loads; only kernels this CPU can run).
``tools/portable_suite.sh`` runs the whole default suite that way before a release.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


FLAGS = _cpu_flags()
KERNELS = [k for k, needs in (("Prescott", "sse3"), ("Haswell", "avx2"), ("SkylakeX", "avx512f")) if needs in FLAGS
           or (needs == "sse3" and "pni" in FLAGS)]

pytestmark = pytest.mark.skipif(not KERNELS or sys.platform != "linux",
                                reason="needs Linux on x86-64 (OpenBLAS kernels chosen by OPENBLAS_CORETYPE)")


def _run(code: str, kernel: str, tmp_path) -> dict:
    env = dict(os.environ, OPENBLAS_CORETYPE=kernel, PHC_CACHE_DIR=str(tmp_path / "cache"))
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=900,
                         cwd=REPO)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


FOLDED = """
import json, phc
r = phc.simulate(phc.compile_model("models/rigid_slider_crank.yaml"), params={"L": 0.15})
print(json.dumps({"success": r.success, "message": r.message, "t": float(r.t[-1])}))
"""


@pytest.mark.parametrize("kernel", KERNELS)
def test_ida_stops_at_the_folded_crank_s_singular_configuration_on_every_kernel(kernel, tmp_path):
    """With L = r the rod folds onto the crank at θ = ωt = π/2. IDA fails there with some
    kernels and crawls (steps of 5e-9 s, to max_steps after 200 s) with others; both must end
    in the diagnosis of the singular configuration, within a fraction of a degree of it."""
    out = _run(FOLDED, kernel, tmp_path)
    assert out["success"] is False
    assert "singular configuration" in out["message"], out["message"]
    assert "max_steps" not in out["message"], out["message"]
    theta = 150.0 * out["t"]
    assert abs(theta - 3.141592653589793 / 2) < 0.02  # rad: IDA stops within about a degree


OVERFLOW = """
import json, pathlib, phc
path = pathlib.Path(%r) / "m.yaml"
path.write_text('''format_version: 1
name: state_model
parameters: {a: 1.0}
components:
  s:
    type: phs
    states: [q]
    hamiltonian: exp(a*q)
    J: [[0]]
    R: [[0]]
    ports:
      u: {domain: electrical, causality: effort_in, B: [[1]]}
  src: {type: effort_source, domain: electrical, value: 1000}
connections:
  - [s.u, src.port]
simulation: {t_end: 2.0, n_out: 201, initial: {s.q: 0.0}}
''')
r = phc.simulate(phc.compile_model(path, certify=False), solver="midpoint", step=0.01)
print(json.dumps({"success": r.success, "t": float(r.t[-1]), "q": float(r["s.q"][-1])}))
"""


@pytest.mark.parametrize("kernel", KERNELS)
def test_midpoint_follows_q_1000t_until_exp_overflows_on_every_kernel(kernel, tmp_path):
    """q' = 1000 with H = exp(q): the midpoint rule is exact for q (linear), and the run stops
    where exp(q) overflows (q = 709.78). With some kernels Newton once accepted a step off
    by 15 and the run went on to t = 1.09."""
    out = _run(OVERFLOW % str(tmp_path), kernel, tmp_path)
    assert out["success"] is False
    assert 0.69 <= out["t"] <= 0.70978
    assert abs(out["q"] - 1000 * out["t"]) < 1e-9 * 1000 * out["t"]  # Newton's tolerance, relative
