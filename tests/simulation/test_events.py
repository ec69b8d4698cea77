"""Non-smooth laws and events (docs/events.md): almost-everywhere derivatives, switching
times of conditions in t as breakpoints, state events located by root finding with a
consistent restart, set-valued sign (sticking), all against closed forms or an independent
solution written here."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import phc
from phc.errors import ModelError

FIXED_STEP = ("midpoint", "discrete_gradient", "midpoint4")

RL = """\
format_version: 1
name: rl_switch
parameters:
  L: 0.2
  R: 2.0
  V0: 5.0
  T: 0.01
components:
  source: {{type: effort_source, domain: electrical, value: "{value}"}}
  coil: {{type: inductor, L: L}}
  res: {{type: resistor, R: R}}
  loop: {{type: junction, kind: common_flow, domain: electrical, ports: [s, l, r]}}
connections:
  - [loop.s, source.port]
  - [loop.l, coil.port]
  - [loop.r, res.port]
simulation:
  t_end: 0.3
  n_out: 61
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {{coil.phi: 0.0}}
  outputs: {{current: coil.phi / L}}
"""

FRICTION = """\
format_version: 1
name: coulomb_block
parameters:
  m: 1.0
  k: 4.0
  Fc: 1.0
components:
  block:
    type: phs
    states: [p, x]
    hamiltonian: p**2/(2*m) + k*x**2/2
    resistive:
      fr: {{law: ["{law}"]}}
    relations:
      - f_x = e_p
      - f_p = -e_x - e_fr
      - f_fr = e_p
simulation:
  t_end: 5.0
  n_out: 101
  rtol: 1.0e-8
  atol: 1.0e-10
  initial: {{block.x: 1.1, block.p: 0.0}}
  outputs: {{v: block.p / m}}
"""

PUSHED = """\
format_version: 1
name: pushed_block
parameters:
  m: 2.0
  Fc: 3.0
  c: 4.0
components:
  push: {{type: effort_source, domain: mechanical.translational, value: "{force}"}}
  block:
    type: phs
    states: [p]
    hamiltonian: p**2/(2*m)
    ports:
      a: {{domain: mechanical.translational}}
    resistive:
      fr: {{law: [e_fr = Fc*sign(f_fr)]}}
    relations:
      - f_p = -e_a - e_fr
      - f_fr = e_p
      - f_a = e_p
connections:
  - [push.port, block.a]
simulation:
  t_end: 2.0
  n_out: 201
  rtol: 1.0e-10
  atol: 1.0e-12
  initial: {{block.p: 0.0}}
  outputs: {{v: block.p / m}}
"""

RECTIFIER = """\
format_version: 1
name: half_wave_rectifier
parameters:
  V0: 10.0
  w: 314.1592653589793
  C: 1.0e-4
  RL: 1000.0
  Ron: 1.0
  Roff: 1.0e6
components:
  src: {type: effort_source, domain: electrical, value: V0*sin(w*t)}
  rect:
    type: phs
    states: [q]
    hamiltonian: q**2/(2*C)
    ports:
      a: {domain: electrical}
    resistive:
      D: {law: ["f_D = ifelse(e_D > 0, e_D/Ron, e_D/Roff)"]}
      L: {law: ["f_L = e_L/RL"]}
    relations:
      - f_q = f_D - f_L
      - e_L = e_q
      - e_D = -e_a - e_q
      - f_a = f_D
connections:
  - [src.port, rect.a]
simulation:
  t_end: 0.06
  n_out: 301
  rtol: 1.0e-9
  atol: 1.0e-12
  initial: {rect.q: 0.0}
  outputs:
    vC: rect.q / C
"""


def _compile(tmp_path, text, name="model.yaml", **kw):
    path = tmp_path / name
    path.write_text(text)
    return phc.compile_model(path, **kw)


def _step_kw(solver, h):
    return {} if solver == "ida" else {"solver": solver, "step": h}


# -- almost-everywhere derivatives -------------------------------------------------------
@pytest.mark.parametrize("value, sign_after", [("V0*heaviside(T - t)", 0.0), ("V0*sign(T - t)", -1.0)])
def test_heaviside_and_sign_compile_and_simulate(tmp_path, value, sign_after):
    compiled = _compile(tmp_path, RL.format(value=value), certify=False)
    assert "DiracDelta" not in compiled.source
    r = phc.simulate(compiled)
    assert r.success, r.message
    L, R, V0, T = 0.2, 2.0, 5.0, 0.01
    tau = L / R
    i_T = V0 / R * (1 - math.exp(-T / tau))
    after = sign_after * V0 / R + (i_T - sign_after * V0 / R) * np.exp(-(r.t - T) / tau)
    expected = np.where(r.t <= T, V0 / R * (1 - np.exp(-r.t / tau)), after)
    assert np.abs(r["current"] - expected).max() < 1e-8
    assert [(e.kind, e.t) for e in r.events] == [("time", T)]


def test_abs_of_a_state_is_differentiated_where_it_is_smooth(tmp_path):
    """Quadratic drag c|v|v: the Jacobian entry is 2c|v|, v(t) = v0 / (1 + c v0 t / m)."""
    text = FRICTION.replace("block.x: 1.1, block.p: 0.0", "block.x: 0.0, block.p: 2.0").replace("k: 4.0", "k: 0.0")
    compiled = _compile(tmp_path, text.format(law="e_fr = 0.5*abs(f_fr)*f_fr"), certify=False)
    assert "DiracDelta" not in compiled.source
    r = phc.simulate(compiled, t_end=2.0)
    assert r.success, r.message
    assert np.abs(r["v"] - 2.0 / (1 + 0.5 * 2.0 * r.t)).max() < 1e-7
    assert r.events == []  # v never crosses 0


# -- conditions in t: breakpoints --------------------------------------------------------
@pytest.mark.parametrize("solver", ["ida", "midpoint"])
@pytest.mark.parametrize("T", [0.01, 0.0123456789012])
def test_a_step_inside_a_source_expression_is_located_exactly(tmp_path, solver, T):
    """`ifelse(t < T, 0, V0)` in a component's own expression (not an exposed input): the
    switching time is found before the run (for the run's T) and is a breakpoint."""
    compiled = _compile(tmp_path, RL.format(value="ifelse(t < T, 0, V0)"), certify=False)
    r = phc.simulate(compiled, params={"T": T}, **_step_kw(solver, 1e-4))
    assert r.success, r.message
    (event,) = r.events
    assert event.kind == "time" and event.condition in ("t < T", "T > t") and event.comparison
    assert event.direction == -1  # `t < T` turns false
    assert abs(event.t - T) <= 1e-10
    tau = 0.2 / 2.0
    expected = np.where(r.t <= T, 0.0, 2.5 * (1 - np.exp(-(r.t - T) / tau)))
    assert np.abs(r["current"] - expected).max() < (1e-8 if solver == "ida" else 1e-6)


def test_switching_times_of_a_fast_square_wave_are_all_found(tmp_path):
    compiled = _compile(tmp_path, RL.format(value="ifelse(sin(2000*pi*t) > 0, V0, 0)"), certify=False)
    from phc.simulation.events import switch_times

    mod = compiled.module
    y = np.zeros(mod.N)
    found = switch_times(mod, mod.full_parameters(), 0.0, 0.3, y, y)
    expected = np.arange(1, 600) * 5e-4
    assert len(found) == len(expected)
    assert np.abs(np.array([t for t, _, _ in found]) - expected).max() < 1e-15


def test_unlocatable_switching_times_are_a_located_error(tmp_path):
    with pytest.raises(ModelError) as err:
        _compile(tmp_path, RL.format(value="ifelse(sin(1.0e6*t) > 0, V0, 0)"), certify=False)
    text = str(err.value)
    # located at the source that holds the condition, not the junction row it was merged into
    assert "PHC-E703" in text and "model.yaml:9:" in text and "sin(1000000.0*t) > 0" in text
    assert "written in `source`" in text and "changes too fast" in text


# -- set-valued sign: Coulomb friction ---------------------------------------------------
def _coulomb_closed_form(t):
    """m = 1, k = 4, F_c = 1, x0 = 1.1: slides left about x = +1/4 until π/2 (x = −0.6),
    right about −1/4 until π (x = 0.1), then sticks (k·0.1 < F_c)."""
    return np.where(t <= math.pi / 2, 0.25 + 0.85 * np.cos(2 * t),
                    np.where(t <= math.pi, -0.25 + 0.35 * np.cos(2 * t), 0.1))


# IDA at rtol 1e-8: event times to ~1e-7 (the stick time moves between 1e-8 and 2.2e-7 with the
# nominal scales of the states, docs/tolerances.md: the step sequence before it decides)
@pytest.mark.parametrize("solver, h, tol_t, tol_x", [("ida", None, 3e-7, 5e-7), ("midpoint", 1e-3, 2e-6, 2e-6),
                                                     ("discrete_gradient", 1e-3, 2e-6, 2e-6),
                                                     ("midpoint4", 2e-3, 1e-9, 1e-9)])
def test_coulomb_block_slips_reverses_and_sticks(tmp_path, solver, h, tol_t, tol_x):
    compiled = _compile(tmp_path, FRICTION.format(law="e_fr = Fc*sign(f_fr)"))
    r = phc.simulate(compiled, **_step_kw(solver, h))
    assert r.success, r.message
    assert np.array_equal(r.t, np.linspace(0.0, 5.0, 101))  # every output time, once
    # exactly two switches, no chattering: the reversal at π/2, sticking at π
    assert [(e.kind, e.direction) for e in r.events] == [("slip", 1), ("stick", 0)]
    assert abs(r.events[0].t - math.pi / 2) < tol_t and abs(r.events[1].t - math.pi) < tol_t
    assert np.abs(r["block.x"] - _coulomb_closed_form(r.t)).max() < tol_x
    stuck = r.t > math.pi + 1e-3
    assert np.abs(r["v"][stuck]).max() < 1e-12  # sticking is exact, not an oscillation
    assert r.energy_balance_relative < (1e-6 if solver == "ida" else 1e-12)


@pytest.mark.parametrize("solver", ["ida", "midpoint"])
def test_a_pushed_block_sticks_until_the_force_exceeds_friction(tmp_path, solver):
    """Force c·t against F_c: stuck until t* = F_c/c, then v = c (t − t*)² / 2m."""
    compiled = _compile(tmp_path, PUSHED.format(force="c*t"))
    r = phc.simulate(compiled, **_step_kw(solver, 1e-3))
    assert r.success, r.message
    assert [(e.kind, e.direction) for e in r.events] == [("stick", 0), ("slip", 1)]
    t_star = 3.0 / 4.0
    assert abs(r.events[1].t - t_star) < 1e-9
    expected = np.where(r.t < t_star, 0.0, 4.0 * (r.t - t_star) ** 2 / 4.0)
    assert np.abs(r["v"] - expected).max() < (1e-9 if solver == "ida" else 1e-5)


@pytest.mark.parametrize("way", [1.0, -1.0], ids=["along", "against"])
def test_a_stick_trial_on_the_bound_follows_the_slide(tmp_path, way):
    """Force c·t against F_c, the block at rest at t* = F_c/c, where c·t* = F_c exactly (3.0 =
    4.0 · 0.75 in binary): a stick trial there needs s = 1, on the bound, pointing the +
    way. Sliding + (it began to slip at t*; round-off of v, 0 with zero slope, fell through
    zero) it slides on — no event, the mode unchanged; sliding − (the force points against
    the slide) it sticks, as Karnopp's model keeps an admissible force (friction.slides_on).
    Before, both stuck: s was within the stick test's slack."""
    from phc.simulation import parameter_vector
    from phc.simulation.events import Watch, _handle

    mod = _compile(tmp_path, PUSHED.format(force="c*t")).module
    watch = Watch(mod, np.array(parameter_vector(mod), dtype=float))
    k = list(mod.SWITCHES).index("sign(block.fr.f)")
    watch.set_mode(k, way)
    dif = set(np.flatnonzero(np.asarray(mod.DIFFERENTIAL)).tolist())
    energy = [j for j, r in enumerate(mod.ROLES) if r == "energy"]
    events: list = []
    y, yp = _handle(watch, 0.75, np.zeros(mod.N), np.zeros(mod.N), [k], events, dif, energy)
    s = watch.values(0.75, y, yp)[watch.n_sw + watch.stick_of(k)]
    if way > 0:
        assert events == [] and watch.mode(k) == 1.0 and not watch.stuck.any()
        assert 0.0 <= s <= 1.0  # the friction force slides on at +F_c
        assert yp[list(mod.VARIABLES).index("block.p")] == pytest.approx(0.0, abs=1e-12)  # ṗ = c t* − F_c = 0
    else:
        assert [(e.kind, e.direction) for e in events] == [("stick", 0)] and watch.stuck.all()
        assert s == pytest.approx(1.0, abs=1e-12)


def test_the_rule_of_a_stick_trial():
    """friction.slides_on (λ_t against the slide: σ = −sign λ_t): clearly inside the bound it
    sticks, clearly outside it slides the way the force points; on the bound (within the 1e-9
    slack) it slides on only the way it was sliding, else (against, at rest) it sticks."""
    from phc.simulation.friction import STICK_SLACK, slides_on

    on = 1.0 + 0.5 * STICK_SLACK
    assert slides_on(0.5, 1.0, -1.0) == 0.0 and slides_on(-0.5, 1.0, 1.0) == 0.0  # inside
    assert slides_on(2.0, 1.0, 1.0) == -1.0 and slides_on(-2.0, 1.0, 0.0) == 1.0  # outside
    assert slides_on(on, 1.0, -1.0) == -1.0 and slides_on(-on, 1.0, 1.0) == 1.0  # on it, along
    assert slides_on(on, 1.0, 1.0) == 0.0 and slides_on(-1.0, 1.0, 0.0) == 0.0  # on it, against / at rest
    assert slides_on(1.0, 1.0, 1.0, orient=1.0) == 1.0  # a set-valued sign's orientation


def test_the_pushed_block_slips_at_the_closed_form_time_once(tmp_path):
    """The run through t*: one stick (from rest at t = 0) and one slip, at t* = F_c/c to IDA's
    event location at rtol 1e-10 (1e-9 s, as above) — no stick/slip pair at the same instant
    where the force reaches the bound."""
    r = phc.simulate(_compile(tmp_path, PUSHED.format(force="c*t")), solver="ida")
    assert r.success, r.message
    assert [(e.kind, e.direction) for e in r.events] == [("stick", 0), ("slip", 1)]
    assert r.events[0].t == 0.0 and abs(r.events[1].t - 0.75) < 1e-9


def test_a_force_step_beyond_friction_breaks_the_stick_at_the_breakpoint(tmp_path):
    compiled = _compile(tmp_path, PUSHED.format(force="ifelse(t < 0.5, 0.5*Fc, 2*Fc)"))
    r = phc.simulate(compiled)
    assert r.success, r.message
    assert [(e.kind, e.t) for e in r.events] == [("stick", 0.0), ("time", 0.5), ("slip", 0.5)]
    expected = np.where(r.t < 0.5, 0.0, 3.0 * (r.t - 0.5) / 2.0)
    assert np.abs(r["v"] - expected).max() < 1e-10


def test_a_law_that_chatters_stops_with_a_message(tmp_path):
    """Friction written with heaviside has no value that holds v = 0: the run would slide
    along v = 0 by ever shorter switches; it stops and says what to write instead."""
    compiled = _compile(tmp_path, FRICTION.format(law="e_fr = Fc*(2*heaviside(f_fr) - 1)"), certify=False)
    r = phc.simulate(compiled)
    assert not r.success
    assert "heaviside(block.fr.f)" in r.message and "switched 50 times" in r.message and "sign(v)" in r.message
    assert abs(r.t[-1] - math.pi) < 0.05  # results up to the sliding point are kept


# -- state events on an algebraic variable: a half-wave rectifier ------------------------
def _rectifier_reference(t_eval, RL=1000.0, Ron=1.0):
    """scipy Radau on C v' = i_D(V0 sin ωt − v) − v/R_L with the diode's two branches,
    restarted at each switch (its own event location)."""
    V0, w, C, Roff = 10.0, 100 * math.pi, 1e-4, 1e6
    t, v, on, switches, out = 0.0, [0.0], True, [], []

    def rhs(on):
        return lambda t, v: [((V0 * math.sin(w * t) - v[0]) / (Ron if on else Roff) - v[0] / RL) / C]

    while True:
        def boundary(t, v):
            return V0 * math.sin(w * t) - v[0]
        boundary.terminal, boundary.direction = True, (-1 if on else 1)
        sol = solve_ivp(rhs(on), (t, t_eval[-1]), v, method="Radau", rtol=1e-12, atol=1e-14, events=boundary,
                        dense_output=True)
        stop = sol.t_events[0][0] if len(sol.t_events[0]) else t_eval[-1]
        mask = (t_eval >= t) & (t_eval <= stop)
        out.append((t_eval[mask], sol.sol(t_eval[mask])[0]))
        if stop >= t_eval[-1]:
            break
        switches.append(stop)
        t, v, on = stop, sol.sol(stop), not on
    times = np.concatenate([a for a, _ in out])
    values = np.concatenate([b for _, b in out])
    _, first = np.unique(times, return_index=True)
    return values[first], switches


@pytest.mark.parametrize("solver, h, tol_t, tol_v", [("ida", None, 1e-10, 1e-7), ("midpoint", 1e-5, 3e-7, 2e-4),
                                                     ("midpoint4", 1e-5, 5e-9, 2e-6)])
def test_half_wave_rectifier_matches_an_independent_solution(tmp_path, solver, h, tol_t, tol_v):
    compiled = _compile(tmp_path, RECTIFIER)
    r = phc.simulate(compiled, **_step_kw(solver, h))
    assert r.success, r.message
    reference, switches = _rectifier_reference(r.t)
    assert len(r.events) == len(switches) == 5
    assert [e.direction for e in r.events] == [-1, 1, -1, 1, -1]  # `e_D > 0` turns false, true, ...
    assert max(abs(e.t - s) for e, s in zip(r.events, switches)) < tol_t
    assert np.abs(r["vC"] - reference).max() < tol_v


def test_rectifier_half_periods_cost_alike(tmp_path):
    """The diode's current follows the source through Ron = 1 Ω, and the source
    V0 sin(ω t) is known only to ε·t·V0·ω (~2e-14 V at t = 0.045 s): its absolute tolerance
    may not go below that (the round-off floor of the nominal scales, in the mode of each
    segment, with the time argument's round-off). It went to 5e-14 A, and IDA failed its
    error test on every step of the conducting half-period 0.0431–0.0452 s: 15 000 steps,
    where the same half-period one cycle earlier took 500. Five events, six segments of a
    few hundred steps each."""
    compiled = _compile(tmp_path, RECTIFIER)
    r = phc.simulate(compiled)
    assert r.success, r.message
    assert len(r.events) == 5
    assert r.steps < 6 * 1000


def test_time_roundoff_of_a_source_row(tmp_path):
    """ε · T · |∂F_i/∂t| for the row the source V0 sin(ω t) enters, zero for every other."""
    import math

    import numpy as np

    from phc.simulation.scaling import time_roundoff

    compiled = _compile(tmp_path, RECTIFIER)
    mod, p = compiled.module, compiled.module.full_parameters()
    n = mod.N
    rho = time_roundoff(mod, p, 0.0, np.zeros(n), np.zeros(n), 0.06, None, len(mod.EQUATIONS))
    bound = np.finfo(float).eps * 0.06 * 10.0 * 314.1592653589793
    assert np.count_nonzero(rho) == 1
    # nine samples over 0.06 s (almost two periods) find |cos ω t| ≥ cos(π/8) at one at least
    assert math.cos(math.pi / 8) * bound <= rho.max() <= bound * (1 + 1e-12)


def test_events_are_in_the_summary(tmp_path):
    compiled = _compile(tmp_path, PUSHED.format(force="c*t"), certify=False)
    summary = phc.simulate(compiled).summary()
    assert [e["kind"] for e in summary["events"]] == ["stick", "slip"]
    assert summary["events"][1]["condition"] == "sign(block.fr.f)"


def test_check_certifies_a_coulomb_law(tmp_path):
    """`phc check` differentiates sign almost everywhere too (no Dirac delta), and its
    comparison of rows with the description steps across the jump of the law."""
    path = tmp_path / "model.yaml"
    path.write_text(FRICTION.format(law="e_fr = Fc*sign(f_fr)"))
    from phc.checks import certify_model

    report = certify_model(path)
    assert report.certified, report.render_text()


def test_cli_prints_the_events(tmp_path, capsys):
    from phc.cli import main

    path = tmp_path / "model.yaml"
    path.write_text(PUSHED.format(force="c*t"))
    assert main(["simulate", str(path), "--no-certify"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.strip().startswith("events"))
    assert "2: t = 0 `sign(block.fr.f)` sticks; t = 0.75 `sign(block.fr.f)` slips +" in line


RECTIFIER_NETWORK = """\
format_version: 1
name: rectifier_network
parameters: {V0: 10.0, w: 314.1592653589793, C: 1.0e-4, RL: 200.0, Ron: 0.5, Roff: 1.0e6}
components:
  src: {type: effort_source, domain: electrical, value: V0*sin(w*t)}
  diode:
    type: phs
    states: []
    ports:
      a: {domain: electrical}
    resistive:
      D: {law: ["f_D = ifelse(e_D > 0, e_D/Ron, e_D/Roff)"]}
    relations:
      - f_D = f_a
      - e_a = -e_D
  loop: {type: junction, kind: common_flow, domain: electrical, ports: [s, d, n]}
  node: {type: junction, kind: common_effort, domain: electrical, ports: [i, c, r]}
  cap: {type: capacitor, C: C}
  load: {type: resistor, R: RL}
connections:
  - [src.port, loop.s]
  - [loop.d, diode.a]
  - [loop.n, node.i]
  - [node.c, cap.port]
  - [node.r, load.port]
simulation:
  t_end: 0.06
  n_out: 301
  rtol: 1.0e-9
  atol: 1.0e-12
  outputs: {vC: cap.q/C}
"""


def test_a_condition_on_its_boundary_at_the_start_takes_the_side_the_motion_goes_to(tmp_path):
    """The same rectifier as separate components: the diode's e_D at t = 0 comes out of the
    consistent initialization as round-off of either sign (it was -1.4e-9 V), not 0. It must
    count as on the boundary — the source rises, so the diode conducts — and not start the
    diode blocking, which missed the whole first half-wave (vC(5 ms) = -3e-4 V, not 9.97)."""
    compiled = _compile(tmp_path, RECTIFIER_NETWORK)
    r = phc.simulate(compiled)
    assert r.success, r.message
    reference, switches = _rectifier_reference(r.t, RL=200.0, Ron=0.5)
    assert len(r.events) == len(switches) == 5
    assert max(abs(e.t - s) for e, s in zip(r.events, switches)) < 1e-10
    # the capacitor hangs off the series junction through a node, so its charge reads negated
    # (docs/signs.md, "Series chains and the sign of a node": common-flow junctions read the
    # voltage as their equations say)
    assert np.abs(-r["vC"] - reference).max() < 1e-7
