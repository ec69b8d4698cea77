"""IDA's maximum BDF order where the user has not set `max_order`.

Orders 3–5 of BDF are not stable on the whole imaginary axis (the roots ζ of
``Σ_{j≤k} (1 − 1/ζ)^j / j = z`` leave the unit disc for z = iωh): BDF3 and BDF4 amplify an
undamped mode at every ωh > 0 (slowly while ωh is small), BDF5 for ωh between
:data:`BDF5_IMAGINARY` (0.7108) and 9.39. BDF1 and BDF2 are A-stable. IDA changes its step
only by doubling it, keeping it, or cutting it (SUNDIALS' ``IDACompleteStep``), and raises its
order to 5 on smooth solutions; on a model with undamped oscillations up to ω_max it then
cannot double a step h with ``2·h·ω_max > 0.7108`` without the fastest mode growing until
the error test cuts the step again: the step is held by stability, not by the tolerances.
Measured on the Euler–Bernoulli beam (issue 38): ω_max·h = 0.56, 0.50, 0.58 with 30, 100 and
1 000 elements, whatever the tolerances (6.2e-11 s at rtol 1e-5, 7.5e-11 s at 1e-8 on
1 000 elements); 0.14 on the shipped 6 elements, where the steps are the tolerances' and
order 5 takes 5.4 times fewer steps than order 2.

So when the user has not set `max_order`, the run starts at IDA's default (5); at
:data:`CHECK_STEPS` steps and each time its step count doubles, while at least
:data:`CHECK_STEPS` steps remain at the current step size, phc looks at the modes of the
linearization at the current state (:func:`held_by_stability`). When the fastest lightly
damped one has ``2·h·ω > 0.7108``, the run starts again at max_order 2 (a new IDA through
scikit-sundae's public interface; why from the start: :func:`after_step`). Whether that
pays — BDF2's steps are limited by its own accuracy, which may ask for shorter steps than
the held BDF5 step on a coarse model at tight tolerances — is measured, not assumed, and
measured past order 2's start-up: IDA starts each run with tiny steps and lengthens them as
the start's fast transients die out under BDF2's damping, which on the flexible slider–crank
at 150 rad/s (rtol 1e-5) takes ~2 000 steps (its mean step over successive windows of 500
steps: 4.2e-7, 4.7e-7, 5.7e-7, 7.4e-7, then 1.3e-6 s against order 5's held 9.7e-7 s, and
2.3e-6 s over the whole run). So the trial compares order 2's progress — simulated time per
step, the mean step over a window of :data:`CHECK_STEPS` steps — with the held step, window
after window: order 2 is kept once a window's mean step is longer; the run goes on at order
5 for good when a window's mean step has stopped growing (less than :data:`TRIAL_GROWTH`
times the window's before) while not longer than the held one, or when the trial has cost order 5's steps
:data:`TRIAL_BUDGET` of the rest of the run. What was chosen is said once in the run's
message (:meth:`OrderChoice.note`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from phc.errors import ModelEvaluationError
from phc.simulation.monitor import undamped_modes, undamped_modes_near

BDF5_IMAGINARY = 0.7108
"""ωh up to which BDF5 keeps an undamped mode (y' = iωy) bounded: the largest root of its
characteristic polynomial reaches modulus 1 at z = 0.7108i (tests/simulation/
test_ida_order.py computes it from the polynomial)."""
STEP_RAISE = 2.0
"""The factor by which IDA raises a step (it only doubles)."""
HELD = BDF5_IMAGINARY / STEP_RAISE
"""ω_max·h above which IDA at order 5 cannot raise its step: the step is held by the
fastest undamped mode's stability."""
A_STABLE_ORDER = 2
"""The highest A-stable BDF order (what phc switches to)."""
DEFAULT_ORDER = 5
"""IDA's default maximum order (what a run starts with)."""
CHECK_STEPS = 500
"""Steps before the first look at the modes (IDA has reached its order and step by then:
the 1 000-element beam is held from step ~300), and the length of the trial at order 2.
Looks follow at each doubling of the step count, so a run of n steps looks ~log₂(n/500)
times; a look costs one dense QZ (up to :data:`DENSE_MODES` unknowns) or one sparse LU and
a shift-invert Arnoldi search (under a second on 8 007 unknowns)."""
TRIAL_GROWTH = 1.05
"""A window of the trial whose mean step is less than this many times the window's before
has ended order 2's start-up (at 5 % a window its step would take 14 windows to double);
the crank at rtol 1e-5 lengthens by 11–71 % a window during its start-up."""
TRIAL_BUDGET = 0.1
"""The most the trial at order 2 may cost beyond order 5, as a fraction of the steps order 5
would take for the rest of the run at its held step: the trial's steps less the held steps
that would have covered the same time. A trial whose windows keep lengthening but stay
shorter than the held step ends there (at order 5)."""
DENSE_MODES = 120
"""Systems up to this size have all their modes computed (dense QZ); larger ones are
searched near ``iω = i·BDF5_IMAGINARY/h`` (:func:`phc.simulation.monitor.undamped_modes_near`):
the fastest modes that hold a step h lie within ``HELD/h`` of it."""


def held_by_stability(mod, p, t, y, yp, h: float) -> Optional[float]:
    """ω of the fastest lightly damped mode of the linearization at (t, y, ẏ) when it holds
    BDF5's step `h` (``ω·h > HELD``), else None (also when no mode could be computed)."""
    if not h > 0:
        return None
    try:
        if mod.N <= DENSE_MODES:
            omegas = undamped_modes(mod, p, t, y, yp)
        else:
            omegas = undamped_modes_near(mod, p, t, y, yp, BDF5_IMAGINARY / h)
    except (ArithmeticError, ValueError, TypeError, np.linalg.LinAlgError, ModelEvaluationError):
        return None  # no modes to judge by: the order stays
    if omegas is None or not len(omegas):
        return None
    w = float(omegas[0])
    return w if math.isfinite(w) and w * h > HELD else None


@dataclass
class OrderChoice:
    """What phc decided about IDA's maximum order in one run (None fields: not yet)."""

    order: int = DEFAULT_ORDER
    """The maximum order IDA runs with now."""
    final: bool = False
    """No further looks (the user set `max_order`, or the trial at order 2 decided)."""
    t: float = math.nan
    """Time of the switch to order 2."""
    h_held: float = math.nan
    """The step order 5 was held at."""
    omega: float = math.nan
    """The fastest undamped mode's angular frequency there."""
    steps_at_switch: int = 0
    h_trial: float = math.nan
    """Order 2's mean step over the last window of its trial."""
    trial_mark: Optional[tuple] = None
    """(t, steps) where the trial's current window began."""
    trial_start: Optional[tuple] = None
    """(t, steps) of the trial's first step."""
    t_back: float = math.nan
    """Time of the return to order 5 (when order 2 did not pay)."""
    next_look: int = CHECK_STEPS

    @property
    def decided(self) -> bool:
        """phc switched the order and the trial settled it (what later pieces of the run keep)."""
        return self.final and not math.isnan(self.t)

    @classmethod
    def fixed(cls, max_order: int) -> "OrderChoice":
        return cls(order=int(max_order), final=True)

    def note(self) -> Optional[str]:
        """The run's one sentence about the choice (None when phc changed nothing)."""
        if math.isnan(self.t):
            return None
        why = (f"IDA's steps at BDF order 5 were held at h ≈ {self.h_held:.2g} s by undamped oscillations up to "
               f"ω ≈ {self.omega:.2g} rad/s (ωh ≈ {self.omega * self.h_held:.2g}: BDF5 keeps an undamped mode "
               f"bounded only for ωh < {BDF5_IMAGINARY:g}, and IDA raises a step only by doubling it; BDF of order "
               "1–2 is stable for any ωh)")
        if not math.isnan(self.t_back):
            return (f"{why} (at t = {self.t:.3g} s); phc tried max_order 2 from the start, but its steps "
                    "stopped lengthening (or too slowly to pay) before they were longer: a mean of "
                    f"{self.h_trial:.2g} s over its last {CHECK_STEPS} steps, so the run went on at max_order 5 "
                    f"from t = {self.t_back:.3g} s; set `max_order` to choose yourself (docs/how-to/solvers.md)")
        return (f"{why} (at t = {self.t:.3g} s), so phc ran it at max_order 2"
                + (f" (steps of {self.h_trial:.2g} s)" if not math.isnan(self.h_trial) else "")
                + "; set `max_order` to choose yourself (docs/how-to/solvers.md)")


class Switch(Exception):
    """Raised by the step hook to change the maximum order: from the run's start again
    (`rewind`), or on from (t, y, ẏ) with a first step `h`."""

    def __init__(self, t: float, y, yp, h: float, rewind: bool = False):
        super().__init__("order switch")
        self.t, self.y, self.yp, self.h = float(t), np.array(y, dtype=float), np.array(yp, dtype=float), float(h)
        self.rewind = rewind


RECENT_STEPS = 16
"""Steps whose largest is the step IDA is taking (it cuts a step now and then, by 0.5–0.9)."""


def after_step(choice: OrderChoice, mod, p, t, y, yp, *, steps: int, recent, t_end: float) -> None:
    """At the end of IDA's step number `steps` (`recent`: the sizes of the last
    :data:`RECENT_STEPS` steps): look at the modes when it is time, or judge the trial at
    order 2 at the end of each of its windows; raises :class:`Switch` to change the order
    (`choice` records why).

    Order 2 starts the run again from its start: held at the edge of its stability, order 5
    leaves the fastest modes as large as its error test allows; at that step (ωh ≈ 0.58)
    BDF2's error estimate of them is 10 times larger (error constants 1/3 and 1/6 times
    (ωh)³ and (ωh)⁶), so BDF2 must resolve them, at ωh ≈ 0.2–0.3 where it damps them by
    0.04–0.17 % a step: on the 1 000-element beam, going on from the held state at order 2
    kept the held step for 10⁴ steps, where order 2 from the start takes steps 100 times
    longer. The steps order 5 took are wasted: :data:`CHECK_STEPS` at the first look, and as
    the looks come at doublings of the step count, never more than the run's work so far.
    Order 2's progress is then judged window by window (:data:`CHECK_STEPS` steps each) by its
    mean step, simulated time over steps, against the held step: a single step early in the
    trial is still order 2's start-up (module docstring). Where order 2 does not pay, the run
    goes on from there at order 5."""
    if choice.final:
        return
    if choice.order == DEFAULT_ORDER:
        if steps < choice.next_look:
            return
        h = max(recent, default=0.0)
        remaining = (t_end - t) / h if h > 0 else 0.0
        choice.next_look = 2 * steps
        if remaining < CHECK_STEPS:
            return
        omega = held_by_stability(mod, p, t, y, yp, h)
        if omega is None:
            return
        choice.order, choice.t, choice.h_held, choice.omega = A_STABLE_ORDER, float(t), float(h), omega
        choice.steps_at_switch = steps
        choice.trial_mark = choice.trial_start = None
        raise Switch(t, y, yp, h, rewind=True)
    if choice.trial_mark is None:  # the trial's first step
        choice.trial_mark = choice.trial_start = (float(t), steps)
        return
    t_mark, s_mark = choice.trial_mark
    if steps - s_mark < CHECK_STEPS:
        return
    rate = (t - t_mark) / (steps - s_mark)  # order 2's mean step over this window
    before, choice.h_trial, choice.trial_mark = choice.h_trial, rate, (float(t), steps)
    if rate > choice.h_held:
        choice.final = True  # order 2 pays
        return
    t_start, s_start = choice.trial_start
    cost = (steps - s_start) - (t - t_start) / choice.h_held  # the trial's steps beyond the held ones
    stalled = not math.isnan(before) and rate < TRIAL_GROWTH * before
    if stalled or cost > TRIAL_BUDGET * (t_end - t_start) / choice.h_held:
        choice.final = True
        choice.order, choice.t_back = DEFAULT_ORDER, float(t)
        raise Switch(t, y, yp, max(recent, default=rate))


__all__ = ["BDF5_IMAGINARY", "HELD", "CHECK_STEPS", "TRIAL_BUDGET", "TRIAL_GROWTH", "OrderChoice", "Switch",
           "after_step", "carry", "held_by_stability"]


def carry(keywords: dict, out) -> dict:
    """The backend keywords for the next piece of a run (after an input breakpoint or an
    event): the maximum order phc settled on in this piece (`out`, a BackendRun), so the next
    piece does not start over at order 5."""
    chosen = out.extra.get("max_order_chosen") if out is not None else None
    if chosen is None or "options" not in keywords:
        return keywords
    return dict(keywords, options=keywords["options"].replace(max_order=int(chosen)))
