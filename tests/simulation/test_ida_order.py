"""phc's choice of IDA's maximum BDF order where the user sets none (phc/simulation/order.py).

BDF of order 3–5 keeps an undamped mode bounded only at steps that resolve it (BDF5: ωh <
0.7108), and IDA raises a step only by doubling it: on a model whose lightly damped modes
reach ω_max, IDA at order 5 is held where ``2·h·ω_max`` would pass 0.7108. phc looks at the
modes when a run has taken many steps, goes on at order 2 (A-stable) where they hold the
step, keeps order 2 only if its steps are longer, and says so once in the run's message; a
`max_order` the user sets is never changed.

References: the stability limit from the roots of BDF5's characteristic polynomial
(computed here); the choice's frequency against the dense QZ of the linearization; the
accuracy of a run at the chosen order against the exact solution of the same (linear)
discrete model, from its eigenvectors (computed here with scipy, not with IDA).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla

import phc
from phc.simulation import order as order_module
from phc.simulation import monitor, parameter_vector

MODELS = Path(__file__).resolve().parents[2] / "models"

SIMPLY_SUPPORTED = """\
format_version: 1
name: simply_supported
parameters: {{EI: 68.27, rhoA: 0.50368, L: 0.3, A: 1.0e-4}}
components:
  beam: {{type: euler_bernoulli_beam, length: L, elements: {elements}, rhoA: rhoA, EI: EI}}
  pin_a: {{type: zero_flow, domain: mechanical.translational}}
  pin_b: {{type: zero_flow, domain: mechanical.translational}}
  free_a: {{type: zero_effort, domain: mechanical.rotational}}
  free_b: {{type: zero_effort, domain: mechanical.rotational}}
connections:
  - [beam.a, pin_a.port]
  - [beam.b, pin_b.port]
  - [beam.a_rot, free_a.port]
  - [beam.b_rot, free_b.port]
simulation:
  t_end: {t_end}
  n_out: 41
  rtol: {rtol}
  atol: 1.0e-10
  initial:
    beam.w: A*sin(pi*xi/L)     # the first mode shape of the continuous beam, at rest
    beam.velocity: 0
  outputs:
    support_force: pin_a.port.e
"""
"""A simply supported beam (the paper's slider–crank rod data) released from its first mode
shape: undamped, its highest discrete modes grow like N², and the projection of the shape
onto the mesh leaves them a little excited."""


def _simply_supported(tmp_path, elements: int, t_end: float = 2e-3, rtol: float = 1e-6):
    path = tmp_path / f"ss{elements}.yaml"
    path.write_text(SIMPLY_SUPPORTED.format(elements=elements, t_end=t_end, rtol=rtol))
    return phc.compile_model(path, certify=False)


def _bdf_spectral_radius(k: int, z: complex) -> float:
    """Largest |ζ| among the roots of BDF-k's characteristic polynomial at z = hλ:
    ``Σ_{j≤k} (1/j)(ζ − 1)^j ζ^(k−j) = z ζ^k``."""
    poly = np.zeros(k + 1, dtype=complex)  # highest power first
    for j in range(1, k + 1):
        term = np.polymul(np.poly1d([1.0, -1.0]) ** j, np.poly1d([1.0] + [0.0] * (k - j))).coeffs / j
        poly[k + 1 - len(term):] += term
    poly[0] -= z
    return float(np.abs(np.roots(poly)).max())


def test_the_stability_limit_is_bdf5s_on_the_imaginary_axis():
    """BDF1–2 damp an undamped mode at every step, BDF3–4 amplify it at every ωh of interest,
    BDF5 keeps it bounded exactly up to ωh = BDF5_IMAGINARY (bisection on the roots, to 1e-4)."""
    for x in (0.05, 0.3, 0.7, 2.0, 20.0):
        assert _bdf_spectral_radius(1, 1j * x) < 1 and _bdf_spectral_radius(2, 1j * x) < 1
    for x in (0.1, 0.3, 0.6):
        assert _bdf_spectral_radius(3, 1j * x) > 1 and _bdf_spectral_radius(4, 1j * x) > 1
    lo, hi = 0.3, 1.0
    assert _bdf_spectral_radius(5, 1j * lo) < 1 < _bdf_spectral_radius(5, 1j * hi)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _bdf_spectral_radius(5, 1j * mid) < 1 else (lo, mid)
    assert abs(lo - order_module.BDF5_IMAGINARY) < 1e-4
    assert order_module.HELD == pytest.approx(order_module.BDF5_IMAGINARY / 2)


def _exact_output(compiled, run, name: str) -> np.ndarray:
    """Output `name` at the run's output times along the exact solution of the linear
    discrete model from the run's start: y(t) = Σ c_j v_j e^{λ_j t} over the finite
    eigenvalues of ``F_ẏ λ v = −F_y v`` (dense QZ), ẏ(t) = Σ c_j λ_j v_j e^{λ_j t}."""
    mod = compiled.module
    p = parameter_vector(mod)
    Fy, Fyp = monitor._dense_split(mod, p, 0.0, run.y[0], run.yp[0])
    lam, V = sla.eig(-Fy, Fyp)
    finite = np.isfinite(lam) & (np.abs(lam) < 1e12)
    lam, V = lam[finite], V[:, finite]
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    diff[list(mod.VARIABLES).index("energy.supplied")] = False
    c, *_ = np.linalg.lstsq(V[diff], run.y[0][diff].astype(complex), rcond=None)
    k = list(mod.OUTPUTS).index(name)
    out = []
    for t in run.t:
        y, yp = (V @ (c * np.exp(lam * t))).real, (V @ (c * lam * np.exp(lam * t))).real
        out.append(np.asarray(mod.outputs(t, y, yp, p))[k])
    return np.array(out)


def test_a_fine_undamped_beam_runs_at_order_2_and_stays_accurate(tmp_path):
    """24 simply supported elements at rtol 1e-6: order 5 is held by the top modes (the dense
    QZ's ω_max times the held step is above HELD), phc runs it at order 2, whose steps are
    longer, and says so once. The run at the chosen order meets rtol against the exact
    solution of the discrete model (the tolerance phc promises for outputs, docs/tolerances.md,
    here on the differential states relative to their largest value)."""
    compiled = _simply_supported(tmp_path, 24)
    run = phc.simulate(compiled)
    assert run.success, run.message
    assert run.message.count("max_order 2") == 1 and "phc ran it at max_order 2" in run.message, run.message
    held = float(run.message.split("held at h ≈ ")[1].split(" s")[0])
    omega = float(run.message.split("up to ω ≈ ")[1].split(" rad/s")[0])
    mod = compiled.module
    dense = monitor.undamped_modes(mod, parameter_vector(mod), 0.0, run.y[0], run.yp[0])
    assert abs(omega - dense[0]) <= 0.05 * 10.0 ** np.floor(np.log10(omega))  # the fastest mode, to its 2 digits
    assert dense[0] * held > order_module.HELD
    trial = float(run.message.split("(steps of ")[1].split(" s)")[0])
    assert trial > held
    exact = _exact_output(compiled, run, "support_force")
    err = np.abs(run["support_force"] - exact).max() / np.abs(exact).max()
    assert err < 1e-4, err
    # and the error follows the tolerance: BDF2's global error goes like its local
    # tolerance to the 2/3 (local error ~h³, global ~h²), 4.6 times smaller for a tenth
    tighter = phc.simulate(compiled, rtol=1e-7)
    assert tighter.success and "phc ran it at max_order 2" in tighter.message, tighter.message
    err_tighter = np.abs(tighter["support_force"] - exact).max() / np.abs(exact).max()
    assert err_tighter < err / 2, (err, err_tighter)


def test_the_users_max_order_is_never_changed(tmp_path):
    """A run that phc takes to order 2 (checked) with `max_order` 5 or 3 set: no look, no
    switch, no note."""
    compiled = _simply_supported(tmp_path, 24, t_end=2e-4)
    assert "phc ran it at max_order 2" in phc.simulate(compiled).message
    for k in (5, 3):
        run = phc.simulate(compiled, max_order=k)
        assert "max_order 2" not in run.message and "phc ran" not in run.message, run.message


def test_later_pieces_of_a_run_keep_the_order_phc_settled_on():
    """After an input breakpoint or an event the next piece runs at the order the trial kept
    (it does not look again); a piece where phc settled nothing leaves the options alone."""
    from phc.options import RunOptions
    from phc.simulation.backend import BackendRun

    piece = BackendRun(t=np.zeros(1), y=np.zeros((1, 1)), yp=np.zeros((1, 1)), steps=1, success=True, message="")
    keywords = {"options": RunOptions(), "names": {}}
    assert order_module.carry(keywords, piece) is keywords
    settled = piece.replace(max_order_chosen=2)
    carried = order_module.carry(keywords, settled)
    assert carried["options"].max_order == 2 and carried["names"] is keywords["names"]
    assert RunOptions().max_order is None  # unset by default: phc chooses


def test_a_coarse_beam_whose_steps_are_the_tolerances_keeps_order_5():
    """The shipped 6-element cantilever at rtol 1e-6: its fastest mode times IDA's step stays
    below HELD (the steps are the error test's, ωh ≈ 0.15), so order 5 stays."""
    compiled = phc.compile_model(MODELS / "euler_bernoulli_beam.yaml", certify=False)
    run = phc.simulate(compiled, solver="ida", rtol=1e-6, t_end=2e-3)
    assert run.success and run.steps > order_module.CHECK_STEPS, (run.steps, run.message)
    assert "max_order" not in run.message, run.message


def test_a_damped_model_keeps_order_5():
    """The loudspeaker's modes are damped (ζ 0.78 and 1): nothing holds order 5."""
    run = phc.simulate(phc.compile_model(MODELS / "loudspeaker.yaml", certify=False), rtol=1e-6)
    assert run.steps > order_module.CHECK_STEPS
    assert "max_order" not in run.message, run.message


def test_order_2_is_dropped_when_its_steps_are_not_longer(tmp_path, monkeypatch):
    """The trial decides: with the held step made to look 10⁶ times longer than it was, order
    2's steps are not longer, and the run goes on at order 5 (and says so)."""
    compiled = _simply_supported(tmp_path, 24)
    original = order_module.after_step

    def inflated(choice, *args, **kwargs):
        try:
            original(choice, *args, **kwargs)
        except order_module.Switch:
            if choice.order == order_module.A_STABLE_ORDER:
                choice.h_held *= 1e6
            raise

    monkeypatch.setattr(phc.simulation.ida, "after_step", inflated)
    run = phc.simulate(compiled)
    assert run.success, run.message
    assert "went on at max_order 5" in run.message, run.message


def _trial(held: float, window_steps, t_end: float = 1.0):
    """Drive the trial at order 2 (after a switch with order 5 held at `held`) through
    windows of CHECK_STEPS equal steps of the sizes in `window_steps`; the choice and the
    window at which a Switch back to order 5 came (None: none came)."""
    choice = order_module.OrderChoice(order=order_module.A_STABLE_ORDER, t=0.0, h_held=held, omega=1.0)
    t, steps = 0.0, 1000
    order_module.after_step(choice, None, None, t, None, None, steps=steps, recent=[held], t_end=t_end)
    for k, h in enumerate(window_steps):
        for _ in range(order_module.CHECK_STEPS):
            t, steps = t + h, steps + 1
            try:
                order_module.after_step(choice, None, None, t, np.zeros(1), np.zeros(1), steps=steps, recent=[h],
                                        t_end=t_end)
            except order_module.Switch:
                return choice, k
        if choice.final:
            break
    return choice, None


def test_the_trial_judges_order_2_after_its_start_up_not_by_its_first_steps():
    """Order 2 starting far below the held step and lengthening its steps window after window
    (as on the flexible slider–crank at 150 rad/s, rtol 1e-5: 0.43, 0.48, 0.58, 0.76, then 1.3
    times order 5's held step) is kept once a window's mean step passes the held one — where
    a judgement by its first steps would have gone back to order 5. Steps that stop
    lengthening below the held step, or a trial that lengthens too slowly to pay back within
    TRIAL_BUDGET of the run, go back to order 5 (from where the trial is, not from the
    start)."""
    held = 1e-6
    choice, back = _trial(held, [0.43 * held, 0.48 * held, 0.58 * held, 0.76 * held, 1.3 * held, 2 * held])
    assert back is None and choice.final and choice.order == order_module.A_STABLE_ORDER
    assert choice.h_trial == pytest.approx(1.3 * held) and math.isnan(choice.t_back)
    assert choice.decided and "so phc ran it at max_order 2" in choice.note()
    # a plateau below the held step: back to order 5 at the first window less than TRIAL_GROWTH
    # times as long as the one before (1.02 < 1.05)
    choice, back = _trial(held, [0.4 * held, 0.6 * held, 0.612 * held, 2 * held])
    assert back == 2 and choice.order == order_module.DEFAULT_ORDER and choice.final and choice.t_back > 0
    assert "went on at max_order 5" in choice.note()
    # lengthening by 6 % a window from 1 % of the held step (it would pass the held step after
    # 80 windows): the trial's cost (its steps beyond the held ones) passes TRIAL_BUDGET of the
    # run's held steps (1e5 for t_end = 0.1 s) first, and the run goes back to order 5 there
    choice, back = _trial(held, [0.01 * held * 1.06 ** k for k in range(100)], t_end=0.1)
    assert back is not None and back < 80 and choice.order == order_module.DEFAULT_ORDER
    cost = [(k + 1 - sum(0.01 * 1.06 ** j for j in range(k + 1))) * order_module.CHECK_STEPS for k in range(back + 1)]
    assert cost[-1] > order_module.TRIAL_BUDGET * 0.1 / held >= cost[-2]


def test_the_flexible_slider_crank_runs_at_order_2(tmp_path):
    """The 150 rad/s crank (models/scenes/slider_crank_150rad.yaml) without its model's
    `max_order: 2`, with IDA at rtol 1e-5: the rod's undamped modes (up to 4.2e5 rad/s) hold
    order 5's steps, and order 2, after a start-up of some 2 000 steps shorter than the held
    step, takes steps about twice as long (docs/tolerances.md). phc chooses order 2, and the
    run takes fewer steps than at max_order 5."""
    source = (MODELS / "flexible_slider_crank.yaml").read_text()
    assert "\n  max_order: 2" in source
    (tmp_path / "crank.yaml").write_text(
        "\n".join(line for line in source.splitlines() if not line.startswith("  max_order:")) + "\n")
    scene = (MODELS / "scenes" / "slider_crank_150rad.yaml").read_text()
    (tmp_path / "scene.yaml").write_text(scene.replace("model: ../flexible_slider_crank.yaml", "model: crank.yaml"))
    compiled = phc.compile_model(tmp_path / "scene.yaml", certify=False)
    chosen = phc.simulate(compiled, solver="ida", rtol=1e-5)
    assert chosen.success and "so phc ran it at max_order 2" in chosen.message, chosen.message
    held = phc.simulate(compiled, solver="ida", rtol=1e-5, max_order=5)
    assert held.success, held.message
    assert chosen.steps < held.steps, (chosen.steps, held.steps)
