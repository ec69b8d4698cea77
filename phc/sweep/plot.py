"""The plot of a sweep's results (``phc sweep --plot``)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from phc.errors import SweepSetupError
from phc.io import atomic_write
from phc.sweep.results import SweepReport, _kinds

INSTALL_PLOT = 'pip install "port-hamiltonian-compiler[plot]"'


def plot_sweep(report: SweepReport, path: Union[str, os.PathLike], column: Optional[str] = None,
               against: Optional[Sequence[str]] = None) -> str:
    """Draw `column` (default: the first output's maximum) against one swept parameter
    (a line) or two (a heat map on a grid, else coloured points); failed points are
    marked. Returns the column drawn.

    Raises
    ------
    SweepSetupError
        Unknown column or parameters, or matplotlib missing.
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.colors import LogNorm
        from matplotlib.figure import Figure
    except ImportError:
        raise SweepSetupError(f"--plot needs matplotlib: {INSTALL_PLOT}") from None
    design = report.design
    outputs = [c[: -len(".max")] for c in report.columns if c.endswith(".max")]
    column = column or (f"{outputs[0]}.max" if outputs else "energy_balance_relative")
    numeric = [c for c in report.columns if _kinds(report.columns)[c] in ("float", "int") and c != "point"]
    if column not in numeric:
        raise SweepSetupError(f"--plot-output `{column}` is not a column of the results; choose one of "
                              f"{', '.join(numeric)}")
    varying = [a.name for a in design.axes if (len(set(a.values)) if not a.sampled else design.samples or 0) > 1]
    against = list(against or varying[:2])
    if not against or len(against) > 2 or any(a not in [x.name for x in design.axes] for a in against):
        raise SweepSetupError(f"--plot-against takes one or two of the swept parameters "
                              f"({', '.join(varying) or 'none varies'})")
    log_axis = {a.name: a.log or (min(a.values, default=1) > 0 and max(a.values, default=1) / min(a.values, default=1)
                                  > 100) for a in design.axes}
    rows = report.ordered()
    ok = [r for r in rows if r["success"] and np.isfinite(r[column])]
    bad = [r for r in rows if not r["success"]]
    fig = Figure(figsize=(7, 5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    x = against[0]
    if len(against) == 1:
        others = [n for n in varying if n != x]
        groups: dict[tuple, list] = {}
        for r in ok:
            groups.setdefault(tuple(r[n] for n in others), []).append(r)
        for key, members in groups.items():
            members.sort(key=lambda r: r[x])
            label = ", ".join(f"{n} = {v:.4g}" for n, v in zip(others, key)) or None
            ax.plot([r[x] for r in members], [r[column] for r in members], "o-" if len(groups) < 8 else ".",
                    label=label, markersize=4)
        if bad:
            ymin = min((r[column] for r in ok), default=0.0)
            ax.plot([r[x] for r in bad], [ymin] * len(bad), "rx", label="failed", markersize=8)
        ax.set_ylabel(column + (f" [{report.units[column]}]" if column in report.units else ""))
        values = [r[column] for r in ok]
        if values and min(values) > 0 and max(values) / min(values) > 100:
            ax.set_yscale("log")
        if (len(groups) > 1 and len(groups) < 8) or bad:
            ax.legend(fontsize=8)
    else:
        y = against[1]
        xs = sorted({r[x] for r in rows})
        ys = sorted({r[y] for r in rows})
        values = [r[column] for r in ok]
        positive = bool(values) and min(values) > 0 and max(values) / min(values) > 100
        norm = LogNorm() if positive else None
        if len(xs) * len(ys) == len(rows):  # a full grid: heat map
            grid = np.full((len(ys), len(xs)), np.nan)
            for r in ok:
                grid[ys.index(r[y]), xs.index(r[x])] = r[column]
            mesh = ax.pcolormesh(_edges(xs, log_axis[x]), _edges(ys, log_axis[y]), np.ma.masked_invalid(grid),
                                 shading="flat", norm=norm)
        else:
            mesh = ax.scatter([r[x] for r in ok], [r[y] for r in ok], c=values, norm=norm, s=30)
        if bad:
            ax.plot([r[x] for r in bad], [r[y] for r in bad], "rx", label="failed", markersize=8)
            ax.legend(fontsize=8)
        fig.colorbar(mesh, ax=ax, label=column + (f" [{report.units[column]}]" if column in report.units else ""))
        ax.set_ylabel(y + (f" [{report.units[y]}]" if y in report.units else ""))
        if log_axis[y]:
            ax.set_yscale("log")
    ax.set_xlabel(x + (f" [{report.units[x]}]" if x in report.units else ""))
    if log_axis[x]:
        ax.set_xscale("log")
    ax.set_title(f"{report.name}: {column}" + (" (interrupted)" if report.interrupted else ""))
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    with atomic_write(path) as fh:
        fig.savefig(fh, format=Path(path).suffix.lstrip(".").lower() or "png", dpi=120)
    return column


def _edges(values: Sequence[float], log: bool) -> np.ndarray:
    v = np.log(values) if log else np.asarray(values, dtype=float)
    if len(v) == 1:
        e = np.array([v[0] - 0.5, v[0] + 0.5]) if not log else np.array([v[0] - 0.1, v[0] + 0.1])
    else:
        mid = (v[1:] + v[:-1]) / 2
        e = np.concatenate([[2 * v[0] - mid[0]], mid, [2 * v[-1] - mid[-1]]])
    return np.exp(e) if log else e


__all__ = ["INSTALL_PLOT", "plot_sweep"]
