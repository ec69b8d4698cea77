"""Tests of `phc.simulation.midpoint` (implicit midpoint rule, structure preserving)."""

from pathlib import Path

import numpy as np
import pytest

import phc
import phc.simulation

MODELS = Path(__file__).resolve().parents[2] / "models"


def test_discrete_energy_balance_is_exact_for_any_step():
    """Quadratic H, constant Dirac structure: H(y_{n+1}) − H(y_n) + h·P(midpoint) = 0 to round-off,
    also with damping and for a step of a tenth of the period."""
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml")
    for step in (0.3, 0.05):
        result = phc.simulate(compiled, solver="midpoint", step=step, n_out=21)
        assert result.success
        assert result.energy_balance_relative < 1e-13
        assert result.H[-1] < result.H[0]  # the damper does dissipate


def test_second_order_convergence_to_the_closed_form():
    compiled = phc.compile_model(MODELS / "mass_spring_damper.yaml")
    m, k, c, x0 = 1.0, 4.0, 0.4, 0.5
    w = np.sqrt(k / m)
    z = c / (2 * np.sqrt(k * m))
    wd = w * np.sqrt(1 - z**2)
    errors = []
    for step in (0.04, 0.02, 0.01):
        r = phc.simulate(compiled, solver="midpoint", step=step, t_end=5.0, n_out=11)
        exact = np.exp(-z * w * r.t) * (x0 * np.cos(wd * r.t) + z * w * x0 / wd * np.sin(wd * r.t))
        errors.append(np.abs(r["x"] - exact).max())
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 2.0) < 0.15)  # 1.89, 2.0001 measured


def test_lossless_string_keeps_its_energy_over_many_periods():
    compiled = phc.compile_model(MODELS / "vibrating_string.yaml")
    result = phc.simulate(compiled, solver="midpoint")
    assert result.success
    assert result.energy_balance_relative < 1e-12


def test_flexible_slider_crank_energy_balance_to_round_off():
    """The moving-frame beam's modulation terms cancel exactly in the discrete balance."""
    compiled = phc.compile_model(MODELS / "flexible_slider_crank.yaml")
    result = phc.simulate(compiled, solver="midpoint", step=1e-5, t_end=0.002, n_out=21)
    assert result.success
    assert result.energy_balance_relative < 1e-12
    # positions are projected back onto the invariants at every step end
    assert result.constraint_drift < 1e-12


def test_cli_selects_the_solver(capsys):
    from phc.cli import main

    assert main(["simulate", str(MODELS / "mass_spring_damper.yaml"), "--solver", "midpoint", "--step", "0.1",
                 "--format", "json", "--quiet"]) == 0
    assert '"solver": "midpoint"' in capsys.readouterr().out


@pytest.mark.parametrize("solver", sorted(phc.simulation.BACKENDS))
def test_backends_share_the_result_contract(solver):
    compiled = phc.compile_model(MODELS / "rlc_circuit.yaml")
    step = 1e-3 if solver in phc.simulation.FIXED_STEP else None
    result = phc.simulate(compiled, solver=solver, t_end=0.2, n_out=11, step=step)
    assert result.success and len(result.t) == 11 and result.y.shape == (11, len(result.variables))
    assert set(result.summary()) >= {"success", "message", "steps", "cpu_time_s", "energy_balance_error"}


def test_newton_matrix_is_reused_across_steps():
    """Simplified Newton: far fewer factorizations than steps on a state-dependent Jacobian,
    with the discrete energy balance still at round-off."""
    compiled = phc.compile_model(MODELS / "flexible_slider_crank.yaml")
    result = phc.simulate(compiled, solver="midpoint", step=1e-5, t_end=0.002, n_out=3)
    assert result.success
    assert result.n_jacobian_evals < 0.5 * result.steps
    assert result.energy_balance_relative < 1e-13


def test_a_step_newton_cannot_do_from_the_predictor_is_solved_again_and_reported():
    """Steps of half a period of the Duffing oscillator: on some of them Newton fails from the
    extrapolated predictor; the driver solves them again (from the step's start, split in
    halves if need be: `_subdivide`), the run finishes, and the message says how many steps
    needed it (measured: 9 of the 60 on the NumPy backend, all by the restart). The discrete
    gradient's energy balance holds to round-off on every step."""
    import re

    compiled = phc.compile_model(MODELS.parent / "tests" / "hard" / "models" / "duffing.yaml")
    t = np.arange(0, 61) * 0.7
    result = phc.simulate(compiled, solver="discrete_gradient", t_eval=t)
    assert result.success, result.message
    reported = re.fullmatch(r"integration finished; (\d+) step\(s\) needed a restart or a split to be solved "
                            r"\(the step is long for the dynamics\)", result.message)
    assert reported, result.message
    assert 1 <= int(reported.group(1)) <= 60
    assert result.energy_balance_relative < 1e-13


def test_a_step_that_fails_from_its_start_too_is_split_in_halves():
    """`_subdivide`: a step Newton cannot do even from its start is done as two half steps,
    recursively (here the full and the half step fail, the quarter steps converge)."""
    from phc.simulation.midpoint import MAX_SPLIT, _subdivide

    tried = []

    def advance(t, h, y, guess):
        tried.append((t, h))
        if h > 0.3:
            return guess, False, "Newton did not converge"
        return y + h, True, ""  # y' = 1

    y1, ok, reason = _subdivide(advance, 2.0, 1.0, np.zeros(1), MAX_SPLIT)
    assert ok and reason == "" and y1.tolist() == [1.0]
    assert tried == [(2.0, 1.0), (2.0, 0.5), (2.0, 0.25), (2.25, 0.25), (2.5, 0.5), (2.5, 0.25), (2.75, 0.25)]
    # deeper than MAX_SPLIT halvings it gives up, with the reason of the step that failed
    tried.clear()
    y1, ok, reason = _subdivide(advance, 0.0, 2.0 ** (MAX_SPLIT + 1), np.zeros(1), MAX_SPLIT)
    assert not ok and reason == "Newton did not converge"
    assert min(h for _, h in tried) == 2.0


def test_a_step_whose_halvings_all_fail_is_taken_in_unequal_pieces():
    """`finish_step`: where every halving of a failed step fails too (here any substep whose
    midpoint is within 1e-3 of a dyadic point of the step, as the substeps of a halving all are),
    the step is taken as the pieces 1/3 and 2/3 of it (midpoints at 1/6 and 2/3: off that grid),
    and counts as split; where those fail as well, the run stops with the reason."""
    from types import SimpleNamespace

    from phc.simulation.midpoint import MAX_SPLIT, finish_step

    def on_dyadic_grid(x):
        scaled = x * 2.0 ** (MAX_SPLIT + 1)
        return abs(scaled - round(scaled)) < 1e-3 * 2.0 ** (MAX_SPLIT + 1)

    def advance(t, h, y, guess):
        if on_dyadic_grid(t + 0.5 * h):
            return guess, False, "Newton did not converge"
        return y + h, True, ""  # y' = 1

    mod = SimpleNamespace(DIFFERENTIAL=[True], VARIABLES=["x"])
    y_new, retried, failure, passed = finish_step(advance, None, mod, "rule", 0.0, 1.0, np.zeros(1), np.zeros(1),
                                                  False, "Newton did not converge", False, False, None, [])
    assert failure is None and retried and not passed and y_new.tolist() == [1.0]

    def never(t, h, y, guess):
        return guess, False, "Newton did not converge"

    never.stage = None
    monitor = SimpleNamespace(start=None, scales=None)
    _, retried, failure, _ = finish_step(never, monitor, mod, "rule", 0.0, 1.0, np.zeros(1), np.zeros(1), False,
                                         "Newton did not converge", False, False, np.zeros(1), [])
    assert not retried and failure == "rule: Newton did not converge at t = 0; results up to this time are kept"


def test_the_midpoint_predictor_is_the_lagrange_extrapolation():
    """predict_midpoint: a parabola through three midpoints at unequal times is reproduced at a
    new time (to round-off); the prediction error of a smooth function falls like h^(p+1)
    with the degree p (the compiled loop's _predict does the same arithmetic)."""
    from phc.simulation.midpoint import predict_midpoint

    times = [0.1, 0.25, 0.32]
    mids = [np.array([1.0 + 2.0 * t - 3.0 * t * t, t * t]) for t in times]
    got = predict_midpoint(times, mids, 0.4, order=2)
    assert np.allclose(got, [1.0 + 0.8 - 0.48, 0.16], rtol=0, atol=1e-14)
    # degree 1 uses the last two midpoints only
    line = predict_midpoint(times, mids, 0.4, order=1)
    slope = (mids[2] - mids[1]) / (times[2] - times[1])
    assert np.allclose(line, mids[2] + 0.08 * slope, rtol=0, atol=1e-14)
    for order in (1, 2, 3):
        errors = []
        for h in (1e-2, 5e-3):
            ts = [0.3 + h * (k + 0.5) for k in range(order + 1)]
            errors.append(abs(predict_midpoint(ts, [np.sin(t) for t in ts], ts[-1] + h, order) - np.sin(ts[-1] + h)))
        assert abs(np.log2(errors[0] / errors[1]) - (order + 1)) < 0.2, (order, errors)
