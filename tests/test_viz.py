"""Pictures (issue 6, item 7): outputs over time and frames of the planar mechanism."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")

import phc  # noqa: E402
from phc.study import viz  # noqa: E402

MODELS = Path(__file__).resolve().parents[1] / "models"


def _run(model, **kw):
    compiled = phc.compile_model(MODELS / f"{model}.yaml")
    result = phc.simulate(compiled, **kw)
    assert result.success, result.message
    return compiled, result


@pytest.fixture(scope="module")
def msd():
    return _run("mass_spring_damper", t_end=2.0, n_out=81)


@pytest.fixture(scope="module")
def flexible():
    return _run("flexible_slider_crank", t_end=0.002, n_out=3)  # the model's midpoint rule, 200 steps


@pytest.fixture(scope="module")
def rigid():
    return _run("rigid_slider_crank", t_end=0.02, n_out=11)


@pytest.fixture(scope="module")
def pendulum():
    return _run("pendulum", t_end=1.0, n_out=21)


def _axes():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.0, 3.0), dpi=60)
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot(1, 1, 1)


def _drawn_fraction(fig) -> float:
    """Fraction of pixels inside the axes that differ from the axes background."""
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)
    ax = fig.axes[0]
    x0, y0, x1, y1 = (int(round(v)) for v in ax.get_window_extent().extents)
    h = img.shape[0]
    inner = img[h - y1 + 2: h - y0 - 2, x0 + 2: x1 - 2]
    return float(np.mean(np.any(inner < 235, axis=-1)))


def _labels(ax) -> set[str]:
    return {a.get_label() for a in [*ax.lines, *ax.patches] if a.get_label()}


def test_plot_outputs_writes_a_picture(msd, tmp_path):
    import matplotlib.image as mpimg

    _, result = msd
    path = viz.plot_outputs(result, tmp_path / "msd.png", title="mass_spring_damper")
    assert path.is_file() and path.stat().st_size > 0
    img = mpimg.imread(path)
    assert img.ndim == 3 and img[..., :3].var() > 0
    assert np.mean(np.any(img[..., :3] < 0.9, axis=-1)) > 0.01  # curves and text, not a blank page


def test_plot_outputs_marks_a_failed_run(msd, tmp_path):
    _, result = msd
    failed = dataclasses.replace(result, success=False, message="IDA: error test failed repeatedly")
    fig = viz.outputs_figure(failed, names=["x", "H"], title="msd")
    assert len(fig.axes) == 2
    assert "FAILED: IDA: error test failed repeatedly" in fig._suptitle.get_text()
    for ax in fig.axes:
        (stop,) = [a for a in ax.lines if a.get_label() == "stopped"]
        assert stop.get_xdata()[0] == pytest.approx(result.t[-1])
    assert viz.plot_outputs(failed, tmp_path / "failed.svg", names=["x"]).stat().st_size > 0


def test_plot_outputs_unknown_name_is_one_line(msd, tmp_path):
    _, result = msd
    with pytest.raises(phc.errors.SimulationSetupError, match="cannot plot `nope`") as err:
        viz.plot_outputs(result, tmp_path / "bad.png", names=["nope"])
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("model, expected", [
    ("flexible", {"wheel: wheel", "wheel: crank", "rod: centerline", "guide: guide", "guide: slider"}),
    ("rigid", {"crank: crank circle", "crank: crank", "rod: link", "slider: guide", "slider: slider"}),
    ("pendulum", {"pendulum: body", "pendulum: rod"}),
])
def test_frame_draws_the_mechanism(model, expected, request):
    compiled, result = request.getfixturevalue(model)
    fig, ax = _axes()
    artists = viz.frame(compiled, result, len(result.t) - 1, ax, magnify=20.0)
    assert artists
    assert expected <= _labels(ax)
    assert _drawn_fraction(fig) > 0.005
    assert ax.get_aspect() == 1.0


def test_beam_centerline_is_the_seed_centerline(flexible):
    """r(ξ) = q0 + ξ t + w(ξ) n with w'' = κ, w(0) = w(L) = 0 (seed eq. flexbeam-centerline):
    curvature κ = a + bξ gives w = a ξ(ξ − L)/2 + b (ξ³ − L²ξ)/6, magnified for display."""
    compiled, result = flexible
    L, a, b, magnify, n_el = 0.30, 0.2, -3.0, 10.0, 8
    y = result.y[:1].copy()
    idx = {n: i for i, n in enumerate(result.variables)}
    for name, value in {"rod.q0[0]": 1.0, "rod.q0[1]": 2.0, "rod.qf[0]": 1.0, "rod.qf[1]": 2.0 + L}.items():
        y[0, idx[name]] = value  # chord along +y: t = (0, 1), n = (−1, 0)
    nodes = np.linspace(0.0, L, n_el + 1)
    for e in range(n_el):  # discontinuous P1: left and right value of each element
        y[0, idx[f"rod.kappa[{2 * e}]"]] = a + b * nodes[e]
        y[0, idx[f"rod.kappa[{2 * e + 1}]"]] = a + b * nodes[e + 1]
    fake = dataclasses.replace(result, t=result.t[:1], y=y)
    fig, ax = _axes()
    viz.frame(compiled, fake, 0, ax, magnify=magnify)
    (line,) = [art for art in ax.lines if art.get_label() == "rod: centerline"]
    x, yy = (np.asarray(v) for v in line.get_data())
    xi = yy - 2.0
    w = magnify * (a * xi * (xi - L) / 2 + b * (xi**3 - L**2 * xi) / 6)
    np.testing.assert_allclose(x, 1.0 - w, atol=1e-12)
    assert xi[0] == pytest.approx(0.0) and xi[-1] == pytest.approx(L) and len(xi) > 4 * n_el


def test_animate_writes_a_gif_with_fixed_limits(rigid, tmp_path):
    from PIL import Image

    compiled, result = rigid
    path = viz.animate(compiled, result, tmp_path / "crank.gif", fps=10, max_frames=3, dpi=50)
    with Image.open(path) as im:
        assert im.format == "GIF" and im.n_frames == 3
        frames = []
        for i in range(3):
            im.seek(i)
            frames.append(np.asarray(im.convert("RGB")))
    assert all(f.var() > 0 for f in frames)
    assert not np.array_equal(frames[0], frames[-1])  # the crank moved


def test_model_without_a_mechanism_is_a_clear_error(msd, tmp_path):
    compiled, result = msd
    with pytest.raises(viz.NothingToAnimate, match="nothing planar"):
        viz.animate(compiled, result, tmp_path / "x.gif")


def test_without_matplotlib_the_message_says_how_to_install(msd, monkeypatch, tmp_path):
    for mod in [m for m in list(sys.modules) if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.setitem(sys.modules, mod, None)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    compiled, result = msd
    for call in (lambda: viz.plot_outputs(result, tmp_path / "a.png"),
                 lambda: viz.animate(compiled, result, tmp_path / "a.gif")):
        with pytest.raises(viz.PlotUnavailable) as err:
            call()
        message = str(err.value)
        assert 'pip install "port-hamiltonian-compiler[plot]"' in message and "\n" not in message
        assert isinstance(err.value, phc.errors.PhcError)
