"""A four-bar that passes near, not through, its change point (crank a = 0.1, coupler
b = 0.3, ground d = 0.3, rocker c = 0.1 + 1e-6: a parallelogram at c = 0.1).

Its constraint forces are determined far worse than its motion there. The fixed-step
solvers used to fail with "Newton did not converge; reduce `step`", and a shorter step
stopped them earlier (h = 3e-5 at t = 0.1523, 1e-5 at 0.1456, 3e-6 at 0.1380); then the
singularity monitor stopped them at the change point. Now a failed iteration there is retried
with the least-norm correction and the run passes it when one step and two half steps agree
on the motion (as for the N four-bar mechanism, tests/hard/test_n_four_bar.py).
"""

from __future__ import annotations


import numpy as np
import pytest

import phc

MODEL = """\
format_version: 1
name: parallelogram
parameters:
  a: 0.1
  b: 0.3
  c: 0.100001
  d: 0.3
  Jc: 1.0e-3
  mb: 0.2
  Jb: "mb*b**2/12"
  Jr: 1.0e-3
  om: 10.0
components:
  crank:
    type: rigid
    q: [theta]
    v: [w]
    M: [[Jc]]
    ports:
      pin:
        domain: mechanical.translational
        dimension: 2
        B: [["-a*sin(theta)", "a*cos(theta)"]]
        position: ["a*cos(theta)", "a*sin(theta)"]
  coupler:
    type: rigid
    q: [x, y, phi]
    v: [vx, vy, w]
    M: [[mb, 0, 0], [0, mb, 0], [0, 0, Jb]]
    ports:
      a:
        domain: mechanical.translational
        dimension: 2
        B: [[1, 0], [0, 1], ["b/2*sin(phi)", "-b/2*cos(phi)"]]
        position: ["x - b/2*cos(phi)", "y - b/2*sin(phi)"]
      b:
        domain: mechanical.translational
        dimension: 2
        B: [[1, 0], [0, 1], ["-b/2*sin(phi)", "b/2*cos(phi)"]]
        position: ["x + b/2*cos(phi)", "y + b/2*sin(phi)"]
  rocker:
    type: rigid
    q: [psi]
    v: [u]
    M: [[Jr]]
    ports:
      pin:
        domain: mechanical.translational
        dimension: 2
        B: [["-c*sin(psi)", "c*cos(psi)"]]
        position: ["d + c*cos(psi)", "c*sin(psi)"]
connections:
  - [crank.pin, coupler.a]
  - [coupler.b, rocker.pin]
simulation:
  t_end: 0.5
  rtol: 1.0e-8
  atol: 1.0e-8
  initial:
    crank.theta: 1.5707963267948966
    crank.p_w: Jc*om
    coupler.x: {value: 0.15, guess: true}
    coupler.y: {value: 0.1, guess: true}
    coupler.phi: {value: 0.0, guess: true}
    rocker.psi: {value: 1.57, guess: true}
  outputs:
    theta: crank.theta
    psi: rocker.psi
"""


@pytest.fixture(scope="module")
def compiled(tmp_path_factory):
    path = tmp_path_factory.mktemp("fourbar") / "fourbar.yaml"
    path.write_text(MODEL)
    return phc.compile_model(path, certify=False)


def test_the_fixed_step_solver_passes_the_change_point_at_second_order(compiled):
    """The crank passes θ = π (t ≈ 0.157), where the equilibrated Newton matrix's conditioning
    falls below 1e-6: Newton's iteration fails there, is retried with the least-norm correction
    (the weak direction lies in the position-constraint rows), and one step and two half steps
    agree on the motion, so the run goes on and says so. The motion past the change point is
    the midpoint rule's: halving the step divides the error at t = 0.2 by 4 (second order;
    3 to 5 leaves room for the higher-order terms). IDA stops before the change point, so the
    order is the independent check."""
    ends = []
    for h in (4e-5, 2e-5, 1e-5):
        r = phc.simulate(compiled, solver="midpoint", step=h, t_end=0.2, n_out=81, backend="numpy")
        assert r.success, r.message
        assert "rank drop(s) of the position constraints" in r.message
        ends.append(np.array([r["crank.theta"][-1], r["rocker.psi"][-1]]))
    ratio = np.abs(ends[0] - ends[1]) / np.abs(ends[1] - ends[2])
    assert np.all((3.0 < ratio) & (ratio < 5.0)), ratio
