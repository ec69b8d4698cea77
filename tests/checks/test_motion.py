"""`phc check` traces the position constraints from the initial configuration and reports
each rank drop (:mod:`phc.checks.motion`, PHC-W422).

The N four-bar mechanism with N = 1 (``models/n_four_bar.yaml``: cranks of length L hinged
at x = 0 and x = L, a coupler of length L between their tips, m = L = 1) moves on the
parallelogram branch θ₀ = θ₁ = θ, coupler centre (L/2 + L cos θ, L sin θ), φ = 0. Its
position constraints, written here independently of phc, are

    g = (L cos θ₀ − x + L/2 cos φ,  L sin θ₀ − y + L/2 sin φ,
         x + L/2 cos φ − L − L cos θ₁,  y + L/2 sin φ − L sin θ₁)

and on the branch the two x-rows of ∂g/∂(θ₀, θ₁, x, y, φ) are (−L sin θ, 0, −1, 0, 0) and
(0, L sin θ, 1, 0, 0): dependent exactly where sin θ = 0 — all bars horizontal, θ ≡ 0 or π
(mod 2π); the y-rows stay independent of them. The energy is E = ½ I θ̇² + g P sin θ with
I = (N+1) m L²/3 + N m L² = 5/3 and P = (N+1) m L/2 + N m L = 2 (as in
``tests/hard/test_n_four_bar.py``), so the kinetic energy at a horizontal configuration is
T* = T₀ + g P (sin θ₀ − 0).
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

import phc
from phc.checks.motion import survey
from phc.cli import main

ROOT = Path(__file__).resolve().parents[2]
G = 9.81
INERTIA, MOMENT = 5.0 / 3.0, 2.0  # N = 1, m = L = 1
CONNECTIONS = ("connection `crank0.right — coupler1.a`", "connection `coupler1.b — crank1.left`")


def _generator():
    spec = importlib.util.spec_from_file_location("n_four_bar", ROOT / "models" / "n_four_bar.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def constraint_jacobian(theta0, theta1, x, y, phi, L=1.0):
    """∂g/∂(θ₀, θ₁, x, y, φ) of the module doc's g."""
    return np.array([
        [-L * math.sin(theta0), 0.0, -1.0, 0.0, -L / 2 * math.sin(phi)],
        [L * math.cos(theta0), 0.0, 0.0, -1.0, L / 2 * math.cos(phi)],
        [0.0, L * math.sin(theta1), 1.0, 0.0, -L / 2 * math.sin(phi)],
        [0.0, -L * math.cos(theta1), 0.0, 1.0, L / 2 * math.cos(phi)]])


def test_the_closed_form_singular_set():
    """The hand-written Jacobian on the branch has rank 3 exactly at θ = 0 and π."""
    for theta in np.linspace(-math.pi, math.pi, 73):
        rank = np.linalg.matrix_rank(constraint_jacobian(theta, theta, 0.5 + math.cos(theta), math.sin(theta), 0.0))
        assert rank == (3 if abs(math.sin(theta)) < 1e-12 else 4), theta


def _crank_angle_mod(theta: float) -> float:
    """θ reduced to [−π/2, 3π/2)."""
    return (theta + math.pi / 2) % (2 * math.pi) - math.pi / 2


def _check_horizontal(drops):
    """Two rank drops, at θ ≡ 0 and θ ≡ π, on the parallelogram branch, naming both connections."""
    assert len(drops) == 2, [d.configuration for d in drops]
    angles = sorted(_crank_angle_mod(d.configuration["crank0.theta"]) for d in drops)
    # located to about √ε of the configuration where the branches cross (the module's doc): 1e-6
    assert angles == pytest.approx([0.0, math.pi], abs=1e-6)
    for d in drops:
        c = d.configuration
        theta = c["crank0.theta"]
        assert c["crank1.theta"] == pytest.approx(theta, abs=1e-6)
        assert c["coupler1.x"] == pytest.approx(0.5 + math.cos(theta), abs=1e-6)
        assert c["coupler1.y"] == pytest.approx(0.0, abs=1e-6)
        assert c["coupler1.phi"] == pytest.approx(0.0, abs=1e-6)
        assert (d.rank, d.full_rank) == (3, 4)
        # the x-rows of both connections become dependent (the module doc)
        assert sorted(d.rows) == ["connections[0].position[0]", "connections[1].position[0]"]
        assert all(any(name in where for where in d.connections) for name in CONNECTIONS), d.connections


def test_four_bar_reports_the_horizontal_configurations_and_that_the_motion_passes_them():
    compiled = phc.compile_model(ROOT / "models" / "n_four_bar.yaml", certify=False)
    s = survey(compiled)
    assert not s.skipped and s.closed and not s.cut_short
    assert s.energy_note == ""  # a lossless mechanism of one degree of freedom
    _check_horizontal(s.drops)
    # starts vertical (sin θ₀ = 1) with θ̇ = −1: T* = ½ I + g P
    expected = 0.5 * INERTIA + G * MOMENT
    for d in s.drops:
        assert d.verdict == "passes"
        # V is evaluated at a configuration located to ~1e-8 (slope g P): 1e-6 relative
        assert d.kinetic_energy == pytest.approx(expected, rel=1e-6)
    assert len(s.diagnostics) == 2
    assert all(x.code == "PHC-W422" and x.severity == "warning" for x in s.diagnostics)
    assert all("the motion passes it" in x.message for x in s.diagnostics)


@pytest.mark.parametrize("v0", [1.0, 6.0])
def test_four_bar_hanging_down_reaches_the_horizontal_only_with_enough_energy(tmp_path, v0):
    """Started at the bottom (θ = −π/2) with the tip at v0: it reaches the horizontal iff
    T₀ = ½ I v0² exceeds g P (closed-form threshold v0 = √(2 g P / I) = 4.85 m/s)."""
    model = _generator().n_four_bar(1)
    initial = model["simulation"]["initial"]
    initial.update({"crank0.theta": "-pi/2", "crank1.theta": "-pi/2", "crank0.p_w": "m*L**2/3*v0/L",
                    "crank1.p_w": "m*L**2/3*v0/L", "coupler1.y": "-L"})
    model["parameters"]["v0"]["value"] = v0
    path = tmp_path / "hanging.yaml"
    path.write_text(yaml.safe_dump(model, sort_keys=False))
    s = survey(phc.compile_model(path, certify=False))
    _check_horizontal(s.drops)
    kinetic = 0.5 * INERTIA * v0**2 - G * MOMENT
    for d in s.drops:
        # T = H₀ − V at the located configuration: located to 1e-6 in θ (_check_horizontal: where
        # the branches cross, to about √ε), where V = g P sin θ has the slope g P
        assert d.kinetic_energy == pytest.approx(kinetic, abs=G * MOMENT * 1e-6)
        assert d.verdict == ("passes" if kinetic > 0 else "not reached")


def test_pendulum_has_no_singular_configuration():
    """A Cartesian pendulum: ∂g/∂(x, y) = 2(x, y) never vanishes on the circle."""
    s = survey(phc.compile_model(ROOT / "models" / "pendulum.yaml", certify=False))
    assert not s.skipped and s.closed
    assert s.drops == [] and len(s.diagnostics) == 0
    assert s.summary().startswith("none found")


def test_a_model_without_constraints_is_skipped_saying_so_once(capsys):
    path = ROOT / "models" / "mass_spring_damper.yaml"
    s = survey(phc.compile_model(path, certify=False))
    assert s.skipped == "the model has no position constraints" and s.steps == 0
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.count("no position constraints") == 1


def test_phc_check_reports_the_four_bar_as_warnings_and_certifies_it(capsys):
    """A report, not a refusal: certified, exit 0, one located warning per rank drop."""
    assert main(["check", str(ROOT / "models" / "n_four_bar.yaml")]) == 0
    out = capsys.readouterr().out
    assert "n_four_bar: certified" in out
    lines = [line for line in out.splitlines() if "[PHC-W422]" in line]
    assert len(lines) == 2
    assert all(line.startswith("models/n_four_bar.yaml:11") or "n_four_bar.yaml:11" in line for line in lines)
    assert "singular configurations along the motion\n  2 rank drop(s)" in out


CUSP = """\
format_version: 1
name: cusp
parameters:
  m: {value: 1.0, unit: kg}
components:
  bead:
    type: rigid
    q: [x, y, z]
    v: [vx, vy, vz]
    M: [[m, 0, 0], [0, m, 0], [0, 0, m]]
    constraints:
      - x**2 + y**2 - 1
      - y - 1 + z**3
simulation:
  t_end: 1.0
  initial:
    bead.x: 1.0
    bead.y: 0.0
    bead.z: 1.0
    bead.p_vx: 0.0
    bead.p_vy: 3.0
    bead.p_vz: -1.0
"""


def test_a_bead_that_reaches_a_cusp_cannot_continue(tmp_path):
    """A bead on the curve y = 1 − z³, x² = 1 − y² = 2z³ − z⁶ (z ≥ 0): the branches x = ±√(2z³ − z⁶)
    meet at (0, 1, 0) with a common tangent (a cusp), where the constraint gradients (2x, 2y, 0)
    and (0, 1, 3z²) become parallel. Started at (1, 0, 1) moving toward the cusp with no force
    (T = ½|p|²/m = 5 throughout), it arrives there and cannot go on along the constraints."""
    path = tmp_path / "cusp.yaml"
    path.write_text(CUSP)
    s = survey(phc.compile_model(path, certify=False))
    assert len(s.drops) == 1, [d.configuration for d in s.drops]
    d = s.drops[0]
    # located to the continuation's last step near the cusp (its smallest step is 1e-7 of the
    # size, z there ~ its cube root): 1e-3
    assert [d.configuration[k] for k in ("bead.x", "bead.y", "bead.z")] == pytest.approx([0.0, 1.0, 0.0], abs=1e-3)
    assert (d.rank, d.full_rank) == (1, 2)
    assert d.verdict == "cannot continue"
    assert d.kinetic_energy == pytest.approx(5.0, rel=1e-9)  # no potential: T = T₀ to round-off
    assert d.connections == ["the constraints of `bead`"]
    (w,) = s.diagnostics
    assert w.code == "PHC-W422" and "cannot continue" in w.message and w.path == "bead"
