"""Model texts more than one test module uses (one copy each)."""

WHEEL = """\
format_version: 1
name: wheel_on_moving_axle
parameters: {m: 2.0, J: 0.05, e: 0.1, g: 9.81, c: 0.02, ax: 0.2, ay: 0.1, w: 3.0, th0: 0.3, om0: 1.0}
components:
  wheel:
    type: rigid
    description: an unbalanced wheel (centre of mass e off the axle) on an axle carried by a moving support
    q: [x, y, theta]
    v: [vx, vy, om]
    M: [[m, 0, 0], [0, m, 0], [0, 0, J]]
    V: m*g*y
    damping: [0, 0, c*om]      # bearing friction between wheel and axle
    constraints:
      - x - e*cos(theta) - ax*sin(w*t)
      - y - e*sin(theta) - ay*sin(2*w*t)
simulation:
  t_end: 4.0
  n_out: 401
  rtol: 1.0e-10
  atol: 1.0e-10
  initial:
    wheel.x: e*cos(th0)
    wheel.y: e*sin(th0)
    wheel.theta: th0
    wheel.p_vx: m*(ax*w - e*om0*sin(th0))
    wheel.p_vy: m*(2*ay*w + e*om0*cos(th0))
    wheel.p_om: J*om0
"""
"""A wheel whose axle moves on a prescribed support (time in a rigid constraint):
tests/library/test_rheonomic.py solves it independently, tests/simulation/test_scaling.py
checks its potential gives no energy floor."""

# A spring whose two softening terms a parameter c = 0 switches off through ifelse(c > 0, .../c, 0):
# tests/test_guarded_terms.py, tests/codegen/test_float_arguments.py
GUARDED_DIVISION = """\
format_version: 1
name: guarded_division
parameters:
  m: {value: 1.0, unit: kg}
  k: {value: 4.0, unit: N/m}
  c: {value: 0.0, unit: m^2, description: "softening length squared; 0 turns the term off"}
components:
  body:
    type: rigid
    q: [x]
    v: [vx]
    M: [[m]]
    V: "k*x**2/2 + ifelse(c > 0, k*x**4/(4*c), 0) + ifelse(c > 0, k*x**2/c, 0)"
simulation:
  t_end: 1.0
  n_out: 11
  rtol: 1.0e-8
  atol: 1.0e-10
  initial:
    body.x: 0.1
    body.p_vx: 0.0
  outputs:
    x: body.x
"""


# minimal models of the modulation, pde1d, crank_wheel and linear_phs types: the compiled
# certificate's cases (tests/checks/test_compiled_certificate.py) and the registry's
# (tests/test_registry.py)

LINEAR = """
format_version: 1
parameters: {k: 4.0}
components:
  chain:
    type: linear_phs
    states: 4
    matrices: chain.npz
    J: J
    R: R
    Q: Q
    scale: {Q: k}
    ports:
      tip: {B: [[0], [0], [0], [1]], domain: mechanical.translational}
  push: {type: effort_source, domain: mechanical.translational, value: "cos(2*t)"}
connections:
  - [chain.tip, push.port]
simulation:
  t_end: 1
  initial: {"chain.x[0]": 0.1}
"""


MODULATION = """
format_version: 1
parameters: {m: 1.0, k: 4.0, b: 0.7}
components:
  mass: {type: mass, m: m, dimension: 2}
  spring: {type: spring, k: k, dimension: 2}
  mod:
    type: modulation
    K: [[0, "b*(1 + spring.x[0])"], ["-b*(1 + spring.x[0])", 0]]
  node: {type: junction, kind: common_flow, dimension: 2, ports: [m, s]}
connections:
  - [mass.port, mod.a]
  - [mod.b, node.m]
  - [node.s, spring.port]
simulation:
  t_end: 1
  initial: {"spring.x[0]": 0.1, "spring.x[1]": 0.0}
"""


PDE1D = """
format_version: 1
parameters: {rho: 2.0, T: 8.0}
components:
  s:
    type: pde1d
    order: 1
    variables: [p, eps]
    P: [[[0, 0], [0, 0]], [[0, 1], [1, 0]]]
    H: [["1/rho", 0], [0, T]]
    W_f: [[0, 0, 1, 0], [1, 0, 0, 0]]
    W_e: [[0, 0, 0, 1], [0, -1, 0, 0]]
    ports: [left, right]
    port_domains: [mechanical.translational, mechanical.translational]
    length: 1.0
    elements: 8
  l: {type: zero_flow, domain: mechanical.translational}
  r: {type: effort_source, domain: mechanical.translational, value: "sin(3*t)"}
connections:
  - [s.left, l.port]
  - [s.right, r.port]
"""


CRANK = """
format_version: 1
components:
  wheel: {type: crank_wheel, radius: 0.15, inertia: 1.0e-3}
  spring: {type: spring, k: 100.0, dimension: 2, domain: mechanical.translational}
  torque: {type: effort_source, domain: mechanical.rotational, value: "0.1*sin(5*t)"}
connections:
  - [wheel.pin, spring.port]
  - [wheel.drive, torque.port]
simulation:
  t_end: 0.5
  initial: {wheel.theta: 0.0, wheel.p_theta: 0.01}
"""


# a string reduced to 4 modes (tests/checks/test_rows.py, tests/test_registry.py)
STRING_MODES = """
format_version: 1
components:
  s: {type: string, length: 1.0, rho: 2.0, T: 8.0, elements: 12, effects: {modes: 4}}
  l: {type: zero_flow, domain: mechanical.translational}
  r: {type: effort_source, domain: mechanical.translational, value: "sin(3*t)"}
connections:
  - [s.a, l.port]
  - [s.b, r.port]
"""


# Every function and condition of the model language in one model: the back ends must print
# each like the Python module (tests/codegen/test_backends.py, tests/codegen/test_c_backend.py).
EVERY_FUNCTION = """
format_version: 1
name: every_function
parameters:
  m: 1.5       # no units: the outputs mix a length and a momentum in every function on purpose
  k: 4.0
components:
  mass: {type: mass, m: m}
  spring: {type: spring, k: k}
  kick:
    type: effort_source
    domain: mechanical.translational
    value: "0.01*sign(t - 0.3) + 0.02*heaviside(spring.x - 0.05)"
  node: {type: junction, kind: common_flow, domain: mechanical.translational, ports: [a, b, c, d, e]}
connections:
  - [node.a, mass.port]
  - [node.b, spring.port]
  - [node.e, kick.port]
ports:
  force: {port: node.c}
  pulse: {port: node.d}
simulation:
  t_end: 1.0
  initial: {spring.x: 0.3, mass.p: 0.0}
  inputs:
    force: {effort: "-0.1*sin(3*t)"}
    pulse: {effort: "0.05*t**2"}
  outputs:
    trig: "sin(spring.x) + cos(mass.p) - tan(0.3*spring.x) + atan2(spring.x, mass.p - 0.2)"
    inverse: "asin(0.5*tanh(spring.x)) + acos(0.4*tanh(mass.p)) + atan(spring.x)"
    hyperbolic: "sinh(spring.x) * cosh(mass.p) / (1 + tanh(spring.x)**2)"
    powers: "sqrt(1 + spring.x**2) + (2 + mass.p**2)**1.5 + 1/sqrt(3 + spring.x**2) + spring.x**3 - mass.p**(-2)"
    logs: "exp(-spring.x**2) + log(2 + mass.p**2)"
    switches: "abs(spring.x) + sign(mass.p) + heaviside(spring.x - 0.1) + min(spring.x, mass.p, 0.2)
      + max(spring.x, -mass.p)"
    choices: "ifelse(spring.x > 0, spring.x**2, -mass.p) + ifelse(mass.p <= 0.1 and spring.x < 2, 1, 2)"
    constants: "pi*spring.x + 2/3*mass.p - 7/4 + 1e-300*spring.x"
"""


# A nested part (a gear stage) and a model that uses it from `gear.yaml` beside it
# (tests/test_fastpath.py, tests/test_cache_keys.py, tests/test_cli_multi.py).
GEAR_PART = """\
format_version: 1
name: gear_stage
kind: part
parameters:
  N: 3.0
components:
  g: {type: transformer, ratio: N, domain_a: mechanical.rotational}
ports:
  input: {port: g.a}
  output: {port: g.b}
"""

USES_GEAR = """\
format_version: 1
name: geared_load
parameters:
  tau: 2.0
  J: 0.5
components:
  motor: {type: effort_source, domain: mechanical.rotational, value: tau}
  stage: {type: model, file: gear.yaml}
  load: {type: mass, m: J, domain: mechanical.rotational}
connections:
  - [motor.port, stage.input]
  - [stage.output, load.port]
simulation:
  t_end: 1.0
  n_out: 11
  initial: {load.p: 0.0}
  outputs: {p: load.p}
"""


# Two rigidly joined masses with a spring beside them (a loop that does not constrain; a
# lossless model whose powers all cancel in uniform motion).
BESIDE_RIGID = """\
format_version: 1
name: beside_rigid
components:
  m1: {type: mass, m: 1.0, ports: [a, b]}
  m2: {type: mass, m: 2.0, ports: [a, b]}
  k: {type: spring, k: 3.0, terminals: [a, b]}
connections:
  - [m1.b, m2.a]
  - [m1.a, k.a]
  - [k.b, m2.b]
"""


# A planar mass tied to a line mass along both of its axes by two transformers (a loop that
# closes a kinematic chain; with no force acting, a body that only coasts).
DIAGONAL = """\
format_version: 1
name: diagonal
components:
  m1: {type: mass, m: 1.0, dimension: 2, ports: [a, b]}
  m2: {type: mass, m: 2.0, ports: [a, b]}
  lx: {type: transformer, ratio: [[1.0, 0.0]]}
  ly: {type: transformer, ratio: [[0.0, 1.0]]}
connections:
  - [m1.a, lx.a]
  - [lx.b, m2.a]
  - [m2.b, ly.b]
  - [ly.a, m1.b]
"""
