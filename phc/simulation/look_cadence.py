"""How often the singularity monitor looks inside IDA's step loop (:class:`phc.simulation.ida._StepHook`).

The monitor (:mod:`phc.simulation.monitor`) looks every `cadence` steps. What it finds sets the
cadence, as before: back to the base cadence (10 or 20 steps) as soon as the conditioning ratio
moves, stretched up to :data:`LOOK_STRETCH`-fold while it stays flat and far above the threshold.

What a look costs sets it too (issue 38). A look at a model above the monitor's dense size is a
sparse LU, a condition estimate and an inverse iteration; at the 1000-element Euler–Bernoulli beam
(8007 unknowns) one look cost what some 30 of IDA's steps cost, and looking every 20 steps more
than doubled the run. The hook measures the CPU time of its looks and of the integration between
them (:class:`LookBudget`) and looks no more often than keeps the looks at :data:`LOOK_SHARE` of the
integration — unless the ratio is falling toward the threshold: then it looks at least
:data:`APPROACH_LOOKS` times before the ratio, falling as fast as it fell since the last look,
would reach the threshold (but never more often than the base cadence), and within
:data:`NEAR_DECADES` of the threshold at the base cadence, whatever a look costs. The threshold
itself (what a look decides) does not change; only when looks happen. This applies to sparse looks
only (above the monitor's ``DENSE_SIZE`` unknowns): a dense look is cheap, and at those sizes when
the monitor looks stays independent of the machine's timing (on the N = 1 four-bar at
rtol = atol = 1e-6 a cadence stretched by timing moved the bridges and IDA's error from 6.2e-5 to
2.1e-4 rad).
"""

from __future__ import annotations

import math
import time
from typing import Optional

LOOK_STRETCH = 32
"""Most the singularity monitor's cadence is stretched where the conditioning is flat."""
FLAT_DECADES = 0.1
"""Change of the conditioning ratio between two looks (decades) below which it counts as flat."""
FAR_RATIO = 1e-6
"""Conditioning ratio above which the monitor may look less often (its threshold is 1e-11)."""
LOOK_SHARE = 0.1
"""Share of the integration's CPU time the monitor's looks may take where the conditioning ratio
is not falling toward the threshold."""
APPROACH_LOOKS = 4
"""Looks at least this many before a falling ratio, at the rate it fell since the last look, would
reach the threshold (a falling ratio brings the cadence back toward its base)."""
NEAR_DECADES = 2.0
"""Within this many decades of the threshold the monitor looks at the base cadence, whatever a
look costs."""


def next_cadence(cadence: int, base: int, before: Optional[float], ratio: Optional[float]) -> int:
    """Steps until the monitor's next look by what it found: 1.5× longer (up to
    :data:`LOOK_STRETCH`× `base`) when the ratio moved less than :data:`FLAT_DECADES` since the
    last look and stays above :data:`FAR_RATIO`, else back to `base` at once."""
    if before is None or ratio is None or not (ratio > FAR_RATIO and before > FAR_RATIO):
        return base
    if abs(math.log10(ratio / before)) >= FLAT_DECADES:
        return base
    return min(LOOK_STRETCH * base, max(cadence + 1, int(1.5 * cadence)))


def affordable_cadence(cadence: int, base: int, *, look_cpu: float, step_cpu: float, before: Optional[float],
                       ratio: Optional[float], steps: int, threshold: float) -> int:
    """`cadence` (from :func:`next_cadence`) lengthened so that a look costing `look_cpu` takes at
    most :data:`LOOK_SHARE` of the integration of the steps between two looks (`step_cpu` a step),
    while the ratio cannot reach `threshold` before the next look: at least
    :data:`APPROACH_LOOKS` looks before a ratio falling as from `before` to `ratio` over the last
    `steps` steps would reach it; none of this within :data:`NEAR_DECADES` of it, nor before the
    second look (`before` None)."""
    if ratio is None or before is None or not (look_cpu > 0 and step_cpu > 0) or not ratio > 0:
        return cadence  # (two looks at least: how the ratio moves is known)
    afford = math.ceil(look_cpu / (LOOK_SHARE * step_cpu))
    if afford <= cadence:
        return cadence
    decades = math.log10(ratio / threshold)  # how far the ratio is from the threshold
    if decades <= NEAR_DECADES:
        return cadence
    if before is not None and before > ratio and steps > 0:
        fall = math.log10(before / ratio) / steps  # decades a step, at the last interval's rate
        afford = min(afford, int(decades / (APPROACH_LOOKS * fall)))
    return max(cadence, base, afford)


def _cpu() -> float:
    """The process's CPU seconds (a module function: tests replace it by a counter)."""
    return time.process_time()


class LookBudget:
    """The CPU time of the monitor's looks and of the integration between them, over a run.

    ``start_look()`` and ``end_look(steps)`` bracket a look (`steps`: the steps since the last
    one); the means (:attr:`look_cpu`, :attr:`step_cpu`) are over the run so far, so one look that
    happened to be slow (the machine busy) does not swing the cadence. `clock` is the CPU clock
    (``time.process_time``; tests pass a counter to make the cadence deterministic)."""

    def __init__(self, clock=None):
        self.clock = clock or _cpu
        self.looks = 0
        self.steps = 0
        self.looking = 0.0      # CPU seconds spent in looks
        self.integrating = 0.0  # CPU seconds between looks
        self._mark = self.clock()
        self._look_start = None

    def restart(self) -> None:
        """The clock of the integration between looks starts now (a restart of IDA)."""
        self._mark = self.clock()

    def start_look(self) -> None:
        now = self.clock()
        self._look_start = now

    def end_look(self, steps: int) -> None:
        now = self.clock()
        if self._look_start is None:
            return
        self.integrating += max(0.0, self._look_start - self._mark)
        self.looking += max(0.0, now - self._look_start)
        self.steps += int(steps)
        self.looks += 1
        self._mark, self._look_start = now, None

    @property
    def look_cpu(self) -> float:
        """Mean CPU seconds of a look (0 before the first)."""
        return self.looking / self.looks if self.looks else 0.0

    @property
    def step_cpu(self) -> float:
        """Mean CPU seconds of an integration step between looks (0 before the first look)."""
        return self.integrating / self.steps if self.steps else 0.0
