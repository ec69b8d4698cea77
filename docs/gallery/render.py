"""Render the pictures of the gallery (docs/gallery.md) into docs/gallery/*.png.

    python -m pip install ".[plot]"
    python docs/gallery/render.py            # all models
    python docs/gallery/render.py quarter_car rlc_filter

Each picture is drawn from a phc run of the shipped model (and, where it says so, from
`phc linearize`); tests/test_gallery.py checks the same runs against independent solutions.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import phc  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
MODELS = ROOT / "models"
OUT = Path(__file__).resolve().parent


def simulate(name: str) -> phc.SimResult:
    result = phc.simulate(phc.compile_model(MODELS / f"{name}.yaml", backend="numpy"))
    assert result.success, result.message
    return result


def dc_motor_gear(ax):
    r = simulate("dc_motor_gear")
    a, b = ax
    a.plot(r.t, r.outputs["current"], color="C3")
    a.set(xlabel="t [s]", ylabel="armature current [A]", title="current (load torque on at 0.5 s)")
    b.plot(r.t, r.outputs["motor_speed"] * 0.1, label="motor speed × N")
    b.plot(r.t, r.outputs["load_speed"], label="load speed", ls="--")
    b.set(xlabel="t [s]", ylabel="[rad/s]", title="speeds: the elastic shaft rings")
    b.legend()


def dc_motor_pi(ax):
    r = simulate("dc_motor_pi")
    a, b = ax
    a.plot(r.t, r.outputs["load_speed"], label="load speed")
    a.axhline(10.0, color="0.6", ls=":", label="reference")
    a.set(xlabel="t [s]", ylabel="[rad/s]", title="PI speed control (load torque on at 1 s)")
    a.legend()
    b.plot(r.t, r.outputs["voltage"], color="C3")
    b.set(xlabel="t [s]", ylabel="supply voltage [V]", title="the controller's output")


def two_mass_cubic_spring(ax):
    r = simulate("two_mass_cubic_spring")
    a, b = ax
    a.plot(r.t, r.outputs["x1"], label="x1")
    a.plot(r.t, r.outputs["x2"], label="x2")
    a.set(xlabel="t [s]", ylabel="displacement [m]", title="two masses, hardening coupling")
    a.legend()
    s = r.outputs["x1"] - r.outputs["x2"]
    grid = np.linspace(s.min(), s.max(), 200)
    b.plot(grid, 5.0 * grid + 50.0 * grid**3, color="C2", label="k s + k3 s³")
    b.plot(grid, 5.0 * grid, color="0.5", ls=":", label="linear part")
    b.set(xlabel="elongation s [m]", ylabel="spring force [N]", title="the cubic spring law")
    b.legend()


def quarter_car(ax):
    r = simulate("quarter_car")
    a, b = ax
    for name, label in (("road", "road"), ("wheel_displacement", "wheel"), ("body_displacement", "body")):
        a.plot(r.t, 1000 * r.outputs[name], label=label)
    a.set(xlabel="t [s]", ylabel="[mm]", title="driving over a 50 mm bump")
    a.legend()
    b.plot(r.t, r.outputs["tyre_force"] / 1000, color="C3")
    b.set(xlabel="t [s]", ylabel="[kN]", title="dynamic tyre load")


def hydraulic_cylinder(ax):
    r = simulate("hydraulic_cylinder")
    a, b = ax
    a.plot(1000 * r.t, 10 * r.outputs["pressure"], color="C0")
    a.axhline(10.0, color="0.5", ls=":", label="supply")
    a.set(xlabel="t [ms]", ylabel="chamber pressure [bar]", title="pressure")
    a.legend()
    b.plot(1000 * r.t, 1000 * r.outputs["position"], color="C1")
    b.axhline(10.0, color="0.5", ls=":", label="A P_s / k")
    b.set(xlabel="t [ms]", ylabel="stroke [mm]", title="piston stroke")
    b.legend()


def thermal_ladder(ax):
    r = simulate("thermal_ladder")
    a, b = ax
    for k, steady in zip((1, 2, 3), (35.0, 30.0, 20.0)):
        line, = a.plot(r.t / 60, r.outputs[f"T{k}"], label=f"T{k}")
        a.axhline(steady, color=line.get_color(), ls=":")
    a.set(xlabel="t [min]", ylabel="temperature rise [K]", title="heating up (dotted: steady state)")
    a.legend()
    lin = phc.linearize_model(MODELS / "thermal_ladder.yaml")
    taus = sorted(-1 / m.eigenvalue.real for m in lin.modes)
    b.bar(range(1, len(taus) + 1), taus, color="C2")
    for k, tau in enumerate(taus, 1):
        b.annotate(f"{tau:.0f} s", (k, tau), ha="center", va="bottom")
    b.set(xlabel="mode", ylabel="time constant [s]", title="phc linearize: time constants", yscale="log",
          xticks=range(1, len(taus) + 1), ylim=(5, 3000))


def rlc_filter(ax):
    r = simulate("rlc_filter")
    a, b = ax
    a.plot(r.t, r.outputs["v_in"], lw=0.8, label="v_in")
    a.plot(r.t, r.outputs["v_out"], lw=1.5, label="v_out")
    a.set(xlabel="t [s]", ylabel="[V]", title="1 Hz signal, 20 Hz disturbance")
    a.legend()
    lin = phc.linearize_model(MODELS / "rlc_filter.yaml")
    row = lin.outputs.index("v_out")
    f = np.logspace(-1, 2, 300)
    G = [abs((lin.C @ np.linalg.solve(2j * math.pi * x * lin.E - lin.A, lin.B) + lin.D)[row, 0]) for x in f]
    b.loglog(f, G)
    for x in (1.0, 20.0):
        b.axvline(x, color="0.5", ls=":")
    b.set(xlabel="f [Hz]", ylabel="|v_out / v_in|", title="phc linearize: transfer function")


def double_pendulum(ax):
    r = simulate("double_pendulum")
    a, b = ax
    a.plot(r["bobs.x2"], r["bobs.y2"], lw=0.8, color="C1", label="lower bob")
    a.plot(r["bobs.x1"], r["bobs.y1"], lw=1.5, color="C0", label="upper bob")
    a.plot([0, r["bobs.x1"][0], r["bobs.x2"][0]], [0, r["bobs.y1"][0], r["bobs.y2"][0]], "k-o", ms=4)
    a.set(xlabel="x [m]", ylabel="y [m]", title="paths (rods at release)", aspect="equal")
    a.legend(loc="lower left")
    b.plot(r.t, r.outputs["theta1"], label="θ1")
    b.plot(r.t, r.outputs["theta2"], label="θ2")
    b.set(xlabel="t [s]", ylabel="[rad]", title="angles")
    b.legend()


def controlled_beam(ax):
    r = simulate("controlled_beam")
    a, b = ax
    a.semilogy(1000 * r.t, r.H, color="C0")
    a.set(xlabel="t [ms]", ylabel="energy H [J]", title="a tap, then tip-velocity feedback", ylim=(1e-6, 2e-3))
    lin = phc.linearize_model(MODELS / "controlled_beam.yaml")
    for k, m in enumerate(lin.modes[:3]):
        shape = m.shapes["beam"]
        b.plot(shape["xi_over_L"], shape["deflection"], "-o", ms=3,
               label=f"{m.frequency_hz:.0f} Hz, ζ = {100 * m.damping_ratio:.2f} %")
    b.axhline(0, color="0.7", lw=0.5)
    b.set(xlabel="ξ / L", ylabel="deflection at the nodes", title="phc linearize: closed-loop modes")
    b.legend()


PICTURES = {f.__name__: f for f in (dc_motor_gear, dc_motor_pi, two_mass_cubic_spring, quarter_car, hydraulic_cylinder,
                                    thermal_ladder, rlc_filter, double_pendulum, controlled_beam)}


def main(names) -> None:
    for name in names or PICTURES:
        fig, ax = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
        PICTURES[name](ax)
        fig.suptitle(f"models/{name}.yaml")
        path = OUT / f"{name}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        print(f"wrote {path.relative_to(ROOT)}")


if __name__ == "__main__":
    main(sys.argv[1:])
