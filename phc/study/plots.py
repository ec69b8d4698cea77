"""Outputs over time, and what phc's pictures share (the palette, matplotlib on demand).

* :func:`plot_outputs` — the requested outputs of a run over time, one panel each;
  :func:`outputs_figure` is its matplotlib Figure.
* :func:`_require_matplotlib`, :func:`_new_figure` — matplotlib imported on first use
  (:class:`PlotUnavailable` without it, its message saying how to install it), figures on
  an Agg canvas (no pyplot state, no display needed); the colours of the pictures.

Moved out of :mod:`phc.study.viz` (the planar mechanism frame by frame), which uses these and
keeps every name importable.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from phc.errors import PlotUnavailable, SimulationSetupError

_COLORS = {
    "link": "#1f4e79",
    "beam": "#c0392b",
    "chord": "#999999",
    "wheel": "#d6e4f0",
    "wheel_edge": "#1f4e79",
    "guide": "#555555",
    "slider": "#f0b429",
    "ground": "#333333",
    "trail": "#7f8c8d",
}
_LINK_COLORS = ("#1f4e79", "#2e86c1", "#117a65", "#6c3483", "#a04000")


def _require_matplotlib(what: str = "drawing"):
    """Import matplotlib (Agg canvas only) or raise :class:`PlotUnavailable`."""
    try:
        import matplotlib  # noqa: F401
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise PlotUnavailable(what) from None
    return Figure, FigureCanvasAgg


def _new_figure(figsize):
    Figure, FigureCanvasAgg = _require_matplotlib()
    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig


# --------------------------------------------------------------------------------------
# Outputs over time
# --------------------------------------------------------------------------------------

def plot_outputs(result, path, names: Optional[Sequence[str]] = None, title: Optional[str] = None,
                 *, dpi: int = 120):
    """Draw outputs of a run over time, one panel per output on a shared time axis.

    Parameters
    ----------
    result : SimResult
        From :func:`phc.simulate`. A failed run (``success`` False) is drawn up to where
        it stopped; the stop time is marked and the solver's message is in the title.
    path : str or Path
        Where to write; the format follows the extension (``.png``, ``.pdf``, ``.svg``).
    names : sequence of str, optional
        Outputs to draw (any name ``result[name]`` knows: outputs, ``H``, variables).
        Default: all of ``result.outputs`` (``H`` when there are none).
    title : str, optional
        Figure title (e.g. the model name).

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    PlotUnavailable
        matplotlib is not installed.
    SimulationSetupError
        A requested name is not an output or variable of the run.
    """
    from phc.io import atomic_write

    fig = outputs_figure(result, names, title)
    path = Path(path)
    with atomic_write(path) as fh:  # a killed process leaves no truncated picture
        fig.savefig(fh, format=path.suffix.lstrip(".").lower() or "png", dpi=dpi)
    return path


def outputs_figure(result, names: Optional[Sequence[str]] = None, title: Optional[str] = None):
    """The matplotlib Figure that :func:`plot_outputs` writes (Agg canvas)."""
    _require_matplotlib("plotting")
    if names is None:
        names = list(result.outputs) or ["H"]
    names = list(names)
    if not names:
        raise SimulationSetupError("nothing to plot: no outputs were requested")
    series = []
    for name in names:
        try:
            series.append(np.asarray(result[name], dtype=float))
        except KeyError:
            known = ", ".join(list(result.outputs) + ["H"])
            raise SimulationSetupError(f"cannot plot `{name}`: no output or variable of that name; "
                                       f"outputs: {known}") from None
    t = np.asarray(result.t, dtype=float)
    n = len(names)
    fig = _new_figure((7.0, min(2.0 + 1.7 * n, 14.0)))
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    stop = float(t[-1]) if len(t) else None
    for ax, name, y in zip(axes, names, series):
        m = min(len(t), len(y))
        ax.plot(t[:m], y[:m], lw=1.3, color=_COLORS["link"])
        unit = (getattr(result, "units", None) or {}).get(name)
        ax.set_ylabel(f"{name} [{unit}]" if unit else name)
        ax.grid(True, alpha=0.3)
        if not result.success and stop is not None:
            ax.axvline(stop, color="#c0392b", ls="--", lw=1.2, label="stopped")
    axes[-1].set_xlabel("t [s]")
    if not result.success and stop is not None:
        axes[0].annotate(f"stopped at t = {stop:.6g}", xy=(stop, 1.0), xycoords=("data", "axes fraction"),
                         xytext=(-4, -4), textcoords="offset points", ha="right", va="top", fontsize=8,
                         color="#c0392b")
    heading = title or ""
    if not result.success:
        heading = f"{heading}\n" if heading else ""
        heading += "FAILED: " + _shorten(str(result.message), 110)
    if heading:
        fig.suptitle(heading, fontsize=10, color="#c0392b" if not result.success else "black")
    fig.tight_layout()
    return fig


def _shorten(text: str, n: int) -> str:
    text = " ".join(text.split())
    return text if len(text) <= n else text[: n - 1] + "…"
