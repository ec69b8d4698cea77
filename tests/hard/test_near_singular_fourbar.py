"""A four-bar that passes near, not through, its change point (crank a = 0.1, coupler
b = 0.3, ground d = 0.3, rocker c = 0.1 + 1e-6: a parallelogram at c = 0.1).

Its constraint forces are determined far worse than its motion there. The fixed-step
solvers used to fail with "Newton did not converge; reduce `step`", and a shorter step
stopped them earlier (h = 3e-5 at t = 0.1523, 1e-5 at 0.1456, 3e-6 at 0.1380). Now a stagnating
iteration whose state corrections are at round-off is accepted, and the singularity
monitor decides: every step stops at the same place, near the change point, with the
conditioning in the message. IDA, with error control, passes (not tested here).
"""

from __future__ import annotations

import re

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


def test_a_shorter_step_stops_at_the_same_place_and_says_why(compiled):
    stops = []
    for h in (3e-5, 1e-5):
        r = phc.simulate(compiled, solver="midpoint", step=h, t_end=0.2, n_out=81, backend="numpy")
        assert not r.success
        assert "near a singular configuration" in r.message and "reduce `step`" not in r.message, r.message
        stops.append(float(re.search(r"stopped at t = ([0-9.]+)", r.message).group(1)))
        ratio = float(re.search(r"= ([0-9.e+-]+) < 1e-06", r.message).group(1))
        assert ratio < 1e-6
    assert abs(stops[0] - stops[1]) < 2e-3, stops  # not earlier with the shorter step
    assert 0.150 < min(stops)  # near the change point (theta = pi at t = pi/20 = 0.157)
