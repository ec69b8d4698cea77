"""IDA through an isolated rank drop of the position constraints: a bridge by the midpoint rule.

At a singular configuration of a mechanism (the N four-bar with all bars horizontal) the
position constraints' gradients lose rank for an instant: the constraint forces lose a
direction, the motion does not. IDA's iteration matrix is conditioned like the distance to
that instant, and its Newton iteration fails on round-off before reaching it (the N = 1
four-bar at t = 0.708 s, docs/hard-cases.md). The fixed-step solvers pass such an instant
with the least-norm stage solve (:class:`phc.simulation.midpoint.StageSolver`) and tell a
pass from a motion that cannot continue by one step against two half steps
(:func:`phc.simulation.midpoint.finish_step`).

So when IDA stops at a rank drop of the position constraints (its failure diagnosed there,
or the singularity monitor's warning), phc bridges the singular window with that same
driver — :func:`phc.simulation.midpoint.integrate_fixed_step` with the midpoint rule's step
(:func:`phc.simulation.midpoint.midpoint_advance`), the code a `midpoint` run takes — from
the last state IDA reached with a normal step, in pieces of
:data:`PIECE_STEPS` steps, until the iteration matrix at IDA's step is conditioned again as
it was :data:`RECOVERY` times better than where the bridge began and the minimum lies
behind. The bridge's end is made consistent (:func:`phc.simulation.initial.
consistent_initial_conditions`: the configuration and the energy supplied held, the momenta
moved as little as the velocity constraints ask, in the energy norm — the midpoint rule meets
them at its step midpoints, not at the step ends) and IDA is restarted there (scikit-sundae's
``init_step``, which re-initializes the solver). The bridge's step is the one whose local error
in the configuration meets IDA's local tolerance (:func:`tolerance_step`, by step doubling at the
bridge's start), not IDA's recent step: near the passage IDA crawls, and at rtol 1e-6 a quarter
of its step there made a bridge of 58 000 steps of 1e-7 s (123 607 steps, 282 s CPU for the N = 1
four-bar to 10 s), while a quarter of its normal step (1.4e-3 to 1.9e-3 s) left crank 0 3.1e-4
rad off the exact motion, the midpoint rule's second-order error against IDA's. A motion the
fixed-step driver does not let
through (the folding slider–crank's rod perpendicular to its guide) stops the bridge, and the
run stops with IDA's diagnosis.

The midpoint rule imposes the position constraints at the step ends and integrates the energy
accumulator by the same rule, so the run's energy balance is that of the midpoint rule over
the window (docs/hard-cases.md has the measured figures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from phc.errors import InconsistentInitialError
from phc.simulation.guard import CATCH, ModelEvaluationError
from phc.simulation.initial import consistent_initial_conditions

PIECE_STEPS = 16
"""Midpoint steps between two looks at the conditioning (whether the bridge may end, where it is
lowest: the time and configuration the run reports)."""
RECOVERY = 2.0
"""The bridge ends once the conditioning of IDA's iteration matrix (σ_min/σ_max, equilibrated,
at IDA's recent step) has risen to this many times its value where the bridge began, past its
minimum, and it is as far past the minimum as it began before it. IDA began to fail on
round-off at that value on its way in; a decade lets it restart clear of it."""
STEP_FACTORS = (1.0, 2.0, 4.0)
"""The bridge's steps, as multiples of the step the run's tolerance asks (:func:`tolerance_step`),
tried in this order until one passes. A short step does not always pass: where the least-norm
step's error at the singular instant is not small against a short step's change, one step and
two half steps disagree (`midpoint` at h = 1e-4 stops at the four-bar's second passage,
docs/hard-cases.md), and a longer step then carries the motion through, less accurately."""
SAFETY = 0.5
"""The step the tolerance asks is the one whose estimated local error is this fraction of IDA's
local tolerance (the estimate is taken at the bridge's start, and the motion's rates change
over the bridge)."""
TRIALS = 6
"""Step-doubling estimates at most, from IDA's recent step to the step the tolerance asks."""
GROWTH = 100.0
"""The most one estimate moves the trial step by (up or down): from a crawl's step of 1e-8 s, whose
estimate is round-off, to a step of 1e-3 s takes three."""


def tolerance_step(advance, mod, t, y, yp, h0, rtol, atol, h_max) -> float:
    """The midpoint step whose local error in the configuration (:func:`configuration`: what the
    restart holds), estimated by step doubling at (t, y, ẏ), meets IDA's local tolerance
    (``rtol·|y_j| + atol_j``, in IDA's weighted root-mean-square) at :data:`SAFETY` of it, at most
    `h_max`.

    The midpoint rule is of order 2: its local error in the configuration is ``c h³`` (plus higher
    terms), that of two half steps ``c h³/4``, so one step and two half steps differ by
    ``(3/4) c h³``, the local error is 4/3 of that difference, and ``h (SAFETY/e)^{1/3}`` is the
    step the tolerance asks. The momenta are left out: the rule meets the velocity constraints at
    its step midpoints, and at the step ends the momenta carry an error of order h² along the
    constraint directions that alternates from step to step instead of accumulating (on the N = 1
    four-bar the momenta's step-doubling gap is 5e-8 at h = 1e-4 and 5e-6 at 1e-3, the crank
    angle's 4e-12 and 4e-9); the restart moves the momenta onto the velocity constraints
    (:func:`bridge`). Starting from `h0` (IDA's recent step, which may have shrunk to nothing as IDA
    crawled towards the singular configuration), at most :data:`TRIALS` estimates, each moving the
    step by at most :data:`GROWTH`; a trial step that does not converge is halved."""
    held = configuration(mod)
    weight = 1.0 / (rtol * np.abs(y) + np.broadcast_to(np.asarray(atol, dtype=float), y.shape))
    h = min(float(h0), h_max)
    for _ in range(TRIALS):
        y1, ok, _ = advance(t, h, y, y + h * yp)
        if ok:
            y_a, ok, _ = advance(t, 0.5 * h, y, 0.5 * (y + y1))
        if ok:
            y_b, ok, _ = advance(t + 0.5 * h, 0.5 * h, y_a, y1.copy())
        if not ok or not np.all(np.isfinite(y1)):
            h *= 0.5
            continue
        gap = ((y1 - y_b) * weight)[held]
        error = 4.0 / 3.0 * float(np.sqrt(np.mean(gap * gap))) if gap.size else 0.0
        factor = min(GROWTH, max(1.0 / GROWTH, (SAFETY / error) ** (1.0 / 3.0) if error > 0 else GROWTH))
        h_new = min(h * factor, h_max)
        if 0.8 <= h_new / h <= 1.25 or h_new == h == h_max:
            return h_new
        h = h_new
    return h


MIN_STEPS = 8
"""Fewest midpoint steps of a bridge beyond its lowest conditioning (a bridge that begins at the
singular instant, which the monitor located between two looks after IDA had passed it, still
carries IDA clear of it)."""
MAX_STEPS = 20000
"""Most midpoint steps of one bridge: a window that does not recover by then is not an
isolated rank drop."""
RETRIES = 3
"""Bridges in a row without IDA taking a normal step after the last one, before the run stops
(each doubles the bridge's minimum length and its step: IDA at rtol 1e-8, atol 1e-10 failed
restarting after bridges at 5e-5 s on the N = 1 four-bar, and went on after bridges at twice
that)."""


SAME_PASSAGE = 4.0
"""A bridge that sees no minimum of the conditioning, begun within this many of the last bridge's
lengths after IDA restarted from it, takes the last one's passage (:meth:`Bridges._same_passage`):
one event."""


NEAR_DROP = 1e-4
"""A failed IDA run whose iteration matrix at its last normal state is conditioned below this,
weakest in the position constraints, tries a bridge: the N = 1 four-bar failed at 2e-6, 0.03 s
before a passage, after the monitor's history was cleared by the restart after the one before."""


def near_rank_drop(monitor, t, y, yp, h) -> bool:
    """Whether (t, y, ẏ) lies near a rank drop of the position constraints: the iteration matrix
    at the step h conditioned below :data:`NEAR_DROP`, its weakest direction mostly in two or
    more position-constraint rows. What lets a failed IDA run try a bridge
    (:func:`bridge`), whose own check decides whether the motion passes."""
    if not monitor.enabled or not h > 0:
        return False
    look = monitor.weakest(t, y, yp, max(h, monitor.h_floor), NEAR_DROP)
    if look is None or look[1] is None:
        return False
    u = look[1]
    rows, _ = monitor.dependent(u)
    return len(set(rows) & set(getattr(monitor.mod, "INVARIANTS", ()))) >= 2


@dataclass
class Bridge:
    """What one bridge did: ``ok``; its outputs (``t``, ``y``, ``yp`` at the run's output times
    it covered); the consistent state ``(t_end, y_end, yp_end)`` IDA restarts from; the steps
    and residual evaluations; the passage times the fixed-step driver checked (``passages``);
    ``event`` (a switching function that fell to zero inside, as the fixed-step driver reports
    it) and, when not ``ok``, ``message``."""

    ok: bool
    t: list = field(default_factory=list)
    y: list = field(default_factory=list)
    yp: list = field(default_factory=list)
    t_end: float = 0.0
    y_end: Optional[np.ndarray] = None
    yp_end: Optional[np.ndarray] = None
    steps: int = 0
    nfev: int = 0
    passages: list = field(default_factory=list)
    event: Optional[dict] = None
    message: str = ""
    t_lowest: float = 0.0
    y_lowest: Optional[np.ndarray] = None
    """Where the conditioning was lowest among the looks (the configuration the run reports)."""
    ratio_lowest: float = math.inf
    """The lowest conditioning itself (σ_min/σ_max at IDA's step)."""


def configuration(mod) -> np.ndarray:
    """Indices of the differential variables the position constraints depend on (their
    Jacobian's pattern), and of the energy accumulator: what the restart holds."""
    from phc.simulation.midpoint import constraint_rows

    rows = set(constraint_rows(mod).tolist())
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    held = {int(c) for r, c in zip(mod.JAC_ROWS, mod.JAC_COLS) if int(r) in rows and diff[int(c)]}
    names = list(mod.VARIABLES)
    if "energy.supplied" in names:
        held.add(names.index("energy.supplied"))
    return np.array(sorted(held), dtype=int)


def bridge(mod, p, start, t_out, first: int, h: float, *, names=None, nominal=None, events=None,
           max_steps: int, ratio, min_length: float = 0.0) -> Bridge:
    """Bridge from `start` = (t, y, ẏ) (IDA's last state reached with a normal step) with the
    midpoint rule at steps of at most `h`, writing the output times ``t_out[first:]`` it passes.
    `ratio(t, y, ẏ)`: the conditioning of IDA's iteration matrix there (σ_min/σ_max at IDA's
    step). Ends as the module docstring says, and not before ``start[0] + min_length``."""
    from phc.simulation.midpoint import integrate_fixed_step, midpoint_advance

    t, y, yp = float(start[0]), np.array(start[1], dtype=float), np.array(start[2], dtype=float)
    t_end = float(t_out[-1])
    out = Bridge(ok=False)
    try:
        r_start = ratio(t, y, yp)
    except (ModelEvaluationError, *CATCH, np.linalg.LinAlgError) as err:
        out.message = f"the bridge could not look at its start: {err}"
        return out
    lowest, rising = r_start, False
    out.t_lowest, out.y_lowest, out.ratio_lowest = t, y, r_start
    advance = midpoint_advance(mod, p, nominal)
    advance.stage.restart_near = True  # the least-norm retry from a stagnated iterate, as `midpoint` runs
    j = first
    while True:
        t_b = min(t + PIECE_STEPS * h, t_end)
        if t_end - t_b < 0.5 * h:
            t_b = t_end
        outs = [float(s) for s in t_out[j:] if t < s <= t_b]
        grid = np.array([t, *outs] if outs and outs[-1] == t_b else [t, *outs, t_b])
        piece = integrate_fixed_step(mod, p, grid, y, yp, max_steps=max(1, max_steps - out.steps), progress=None,
                                     step=h, advance=advance, name="IDA's bridge (implicit midpoint)", names=names,
                                     events=events, scales=nominal)
        out.steps += piece.steps
        out.passages += list(piece.extra.get("rank_drops", ()))
        for i in range(1, min(len(piece.t) - 1, len(outs)) + 1):  # the output times it reached
            out.t.append(float(piece.t[i]))
            out.y.append(np.array(piece.y[i]))
            out.yp.append(np.array(piece.yp[i]))
        if piece.event is not None:
            out.event, out.nfev = piece.event, advance.stage.nfev
            out.ok = True
            return out
        if not piece.success:
            out.nfev = advance.stage.nfev
            out.message = piece.message
            return out
        j += len(outs)
        t, y, yp = t_b, np.array(piece.y[-1]), np.array(piece.yp[-1])
        if t >= t_end:
            break
        try:
            r = ratio(t, y, yp)
        except (ModelEvaluationError, *CATCH, np.linalg.LinAlgError):
            r = 0.0
        rising = rising or r > lowest
        if r < lowest:
            lowest, out.t_lowest, out.y_lowest, out.ratio_lowest = r, t, y, r
        if rising and r >= RECOVERY * r_start and t >= float(start[0]) + min_length \
                and t - out.t_lowest >= max(out.t_lowest - float(start[0]), MIN_STEPS * h * (1 - 1e-9)):
            break
        if out.steps >= MAX_STEPS:
            out.nfev = advance.stage.nfev
            out.message = (f"the bridge by the midpoint rule did not leave the singular configuration within "
                           f"{MAX_STEPS} steps (to t = {t:.6g})")
            return out
    out.nfev = advance.stage.nfev
    held = configuration(mod)
    try:
        init = restart_state(mod, p, t, y, held)
    except (InconsistentInitialError, ModelEvaluationError) as err:
        why = "; ".join(err.problems) if isinstance(err, InconsistentInitialError) else str(err)
        out.message = f"IDA could not restart after the bridge at t = {t:.6g}: {why}"
        return out
    out.ok, out.t_end, out.y_end, out.yp_end = True, t, init.y0, init.yp0
    return out


RESTART_TOL = 1e-11
"""The restart's equations are solved to this, absolute (rows equilibrated): IDA's local tolerance
is far below the start's (1e-11 relative to the largest variable, :func:`phc.simulation.initial.
consistent_initial_conditions`)."""


def restart_state(mod, p, t, y, held):
    """IDA's consistent restart at the bridge's end (t, y): the configuration `held`, the rest
    solved to :data:`RESTART_TOL` absolute — else, where that is below what the solve reaches, to
    the start's relative tolerance.

    Why absolute: the start's tolerance is relative to the largest variable, and near a passage
    that is a constraint force (9.2e3 N at the end of the N = 10 four-bar's first bridge, which
    let the velocity constraints' rows keep a residual of 1.6e-6; IDA, whose local tolerance is
    1e-8/200, then failed at each restart with steps of 1e-22 s, at a regular configuration
    0.25 s past the passage; solved to round-off, 7e-15, it went on)."""
    values, fixed = dict(enumerate(y)), set(held.tolist())
    scale = max(1.0, float(np.abs(y).max(initial=0.0)))
    try:
        return consistent_initial_conditions(mod, p, t, values, fixed, tol=RESTART_TOL / scale,
                                             initial_relations=False, rescue=False)
    except InconsistentInitialError:
        return consistent_initial_conditions(mod, p, t, values, fixed, initial_relations=False)


class Bridges:
    """The bridges of one IDA run (:func:`phc.simulation.ida.integrate_ida`): where to start
    (the step hook's last normal state), at what step (IDA's recent one), how long at least
    (:data:`RETRIES`), and what the run reports — a ``passage`` event per bridge
    (:class:`phc.simulation.events.Event`: the time, the connections whose position constraints
    became dependent, the constraint rows) and a note in its message."""

    def __init__(self, mod, p, t_out, *, names=None, nominal=None, events=None, hook, monitor, rtol, atol):
        self.mod, self.p, self.t_out = mod, p, np.asarray(t_out, dtype=float)
        self.rtol, self.atol = float(rtol), atol
        """IDA's local tolerances (relative; absolute, per variable or one): what a bridge's step meets."""
        self.names, self.nominal, self.watch = names, nominal, events
        self.hook, self.monitor = hook, monitor
        self.records: list = []
        """(event, configuration text, t_start, t_end, steps, t_lowest, the event it handed on) of each
        bridge (event None: one of a passage another bridge reports, :meth:`_same_passage`)."""
        self.steps = self.nfev = 0
        self.event: Optional[dict] = None
        self.note: Optional[str] = None
        self.last_outputs: tuple = ([], [], [])
        self._last_end: Optional[float] = None
        self._last_length = 0.0
        self._last_lowest = math.inf  # the last passage's lowest conditioning (_same_passage)
        self._in_a_row = 0
        self._origin, self._streak = None, 0
        self.h_ida = 0.0
        """IDA's recent step at the last bridge."""
        self.h_largest = 0.0
        """IDA's largest step so far (the hook's): no bridge step is longer at first."""
        self.h_bridge = 0.0
        """The step the tolerance asked at the last bridge (:func:`tolerance_step`)."""

    def forget(self) -> None:
        """The run starts again from its start (another maximum order): no bridge was taken."""
        self.records, self._last_end, self._in_a_row = [], None, 0
        self._last_lowest = math.inf

    def restarted_at(self, t: float) -> bool:
        """Whether `t` (IDA's last normal state) is the last bridge's end: IDA took no normal step
        after it, and the bridge is tried again longer (:data:`RETRIES`)."""
        return self._last_end is not None and t <= self._last_end

    def with_note(self, message: Optional[str]) -> Optional[str]:
        """`message` with why the last bridge failed, if one was tried."""
        if self.note is None:
            return message
        return f"{message}; {self.note}" if message else self.note

    def give_up(self, k: int, message: str) -> tuple[int, str]:
        """(output index, message) of a run that stops: where bridges in a row did not let IDA go
        on, the stop where the first of them began — its outputs and diagnosis; the passage
        is not reported as passed — with why; else `k` and `message` with the last bridge's note."""
        if self._in_a_row and self._origin is not None:
            (k0, message0), self.records = self._origin, self.records[:self._streak]
            return k0, self.with_note(message0)
        return k, self.with_note(message)

    def cross(self, steps_left: int, before: Optional[float] = None, origin=None):
        """Bridge from the hook's last normal state (or, where that is past `before`, the time of
        the singular configuration the monitor located between its looks, from its last look
        before it): ``(k_next, t, y, ẏ)`` — the next output index and IDA's consistent restart —
        with the outputs written (:attr:`last_outputs`), or None with :attr:`note` saying why not."""
        hook, monitor = self.hook, self.monitor
        t_n, y_n, yp_n = hook.normal
        if before is not None and t_n >= before:
            earlier = [look for look in monitor.history if look[0] < before]
            if earlier:
                t_n, y_n, yp_n = earlier[-1]
        self.h_ida = hook.h_ref or self.h_ida  # (0 when IDA failed right after a restart: the last bridge's)
        self.h_largest = max(self.h_largest, getattr(hook, "h_largest", 0.0))
        self.note, self.event = None, None
        if not self.h_ida > 0 or steps_left <= 0:
            return None
        min_length = 0.0
        if self._last_end is not None and t_n <= self._last_end:  # IDA took no normal step after the last one
            self._in_a_row += 1
            if self._in_a_row > RETRIES:
                self.note = (f"IDA could not go on after {RETRIES + 1} bridges by the midpoint rule in a row "
                             f"(the last to t = {self._last_end:.6g})")
                return None
            min_length = 2.0 ** self._in_a_row * self._last_length
            t_n, y_n, yp_n = self._last_start
            self.records.pop()  # the same passage, bridged again longer
            if self.records and self.records[-1][6] is not None:  # the bridge it took the event from: back
                self.records[-1] = (self.records[-1][6], *self.records[-1][1:6], None)
        else:
            self._in_a_row = 0
            self._origin, self._streak = origin, len(self.records)  # what stops the run if IDA cannot go on
        h_look = max(self.h_ida, monitor.h_floor)
        culprits, connections = self._dependent(t_n, y_n, yp_n, h_look)
        first = int(np.searchsorted(self.t_out, t_n, side="right"))
        from phc.simulation.midpoint import midpoint_advance

        probe = midpoint_advance(self.mod, self.p, self.nominal)
        probe.stage.restart_near = True
        try:
            # from IDA's recent step, or the last bridge's where IDA's collapsed below it (crawling
            # into a passage right after a restart: estimates at its 1e-12 s steps found 9e-9 s on the
            # N = 1 four-bar, too short for the step-doubling check to pass the rank drop)
            h_tol = tolerance_step(probe, self.mod, t_n, y_n, yp_n, max(self.h_ida, self.h_bridge), self.rtol,
                                   self.atol, max(self.h_largest, self.h_ida))
        except (ModelEvaluationError, *CATCH, np.linalg.LinAlgError):
            h_tol = self.h_ida
        self.nfev += probe.stage.nfev
        h_tol *= 2.0 ** self._in_a_row  # IDA failed restarting after the last: longer steps (RETRIES)
        self.h_bridge = h_tol
        used = 0
        for factor in STEP_FACTORS:
            h = factor * h_tol
            done = bridge(self.mod, self.p, (t_n, y_n, yp_n), self.t_out, first, h, names=self.names,
                          nominal=self.nominal, events=self.watch, max_steps=steps_left - used,
                          ratio=lambda t, y, yp: monitor.ratio(t, y, yp, h_look)[0], min_length=min_length)
            used += done.steps
            self.steps += done.steps
            hook.steps += done.steps
            self.nfev += done.nfev
            if done.ok:
                break
        if not done.ok:
            self.note = (f"bridges by the midpoint rule from t = {t_n:.6g} at {', '.join(f'{f:g}' for f in STEP_FACTORS)} "
                         f"times the step the tolerance asks ({h_tol:.2g} s; their rank-drop check, one step against "
                         f"two half steps, as `--solver midpoint` runs it) did not pass either; at the last: {done.message}")
            return None
        self.last_outputs = (done.t, done.y, done.yp)
        k_next = first + len(done.t)
        if done.event is not None:
            self.event = done.event
            return k_next, float(done.event["t"]), done.event["y"], done.event["yp"]
        from phc.simulation.events import Event

        t_pass = float(done.t_lowest)
        where = ", ".join(connections) if connections else "the position constraints"
        event = Event(t_pass, f"rank drop of the position constraints at {where}", 0, "passage",
                      ", ".join(culprits))
        held = [j for j in configuration(self.mod) if self.mod.VARIABLES[j] != "energy.supplied"]
        shown = ", ".join(f"{self.mod.VARIABLES[j]} = {done.y_lowest[j]:.6g}" for j in held[:4])
        same = self._same_passage(t_n, done.t_lowest, done.ratio_lowest)
        if same:  # one passage, reported once
            last = self.records[-1]
            if last[0] is None or last[5] > last[2] or done.ratio_lowest >= self._last_lowest:
                # the last bridge located the singular instant (a minimum inside, or conditioned
                # lower than this one), or was merged into one before it that did: that event
                event = None
            else:  # it ended short of the instant: this one's (the last's kept, should this be retried)
                self.records[-1] = (None, *last[1:6], last[0])
        self.records.append((event, shown + (", …" if len(held) > 4 else ""), t_n, done.t_end, done.steps,
                             done.t_lowest, None))
        self._last_start, self._last_end, self._last_length = (t_n, y_n, yp_n), done.t_end, done.t_end - t_n
        self._last_lowest = min(done.ratio_lowest, self._last_lowest) if same else done.ratio_lowest
        return k_next, done.t_end, done.y_end, done.yp_end

    def _same_passage(self, t_start: float, t_lowest: float, ratio_lowest: float = math.inf) -> bool:
        """Whether a bridge from `t_start`, its conditioning lowest at `t_lowest` (`ratio_lowest`
        there), takes the passage the last bridge took: IDA failed again within
        :data:`SAME_PASSAGE` times the last bridge's length after it, and the bridge saw no
        minimum of the conditioning (lowest at its start: the singular instant is behind it or
        at its start, where IDA failed again on its way out) or none below the last bridge's
        lowest (a wobble on the passage's flank, not a rank drop of its own). On the N = 1
        four-bar at the model's tolerances two of the ten passes were bridged twice the first
        way (IDA failing again 1.5 and 1.9 bridge lengths after bridges that ended 2.4e-3 s
        before the singular instant); at rtol = atol = 2e-9 one pass the second way (a bridge
        from the last one's end at t = 6.4809, its conditioning 2.7e-8 at its lowest, the last
        one's 4.8e-9 at the singular instant 6.4790), and each was reported twice; the passes
        are 0.5 s, some 100 such lengths, apart, and a bridge towards the next one sees its
        own minimum. The last bridge's length counts only up to twice the way to its minimum, where
        it has one inside (a bridge ends when the conditioning has doubled, which can take long)."""
        if not self.records:
            return False
        _, _, t0, t1, _, t_low, _ = self.records[-1]
        length = t1 - t0
        if t0 < t_low < t1:
            # it located its instant: the passage is as wide as twice the way there, what lies
            # beyond is the conditioning's slow recovery (N = 10: a first bridge of 0.27 s, its
            # minimum 0.023 s in, took the next pass 0.27 s after its end as this one, 9 events)
            length = min(length, 2.0 * (t_low - t0))
        if not 0.0 <= t_start - t1 <= SAME_PASSAGE * length:
            return False
        return t_lowest <= t_start or ratio_lowest >= self._last_lowest

    def _dependent(self, t, y, yp, h):
        """(constraint rows, connections) that become dependent near (t, y, ẏ): the left singular
        vector of the smallest singular value of IDA's iteration matrix there
        (:meth:`phc.simulation.monitor.SingularityMonitor.dependent`)."""
        monitor = self.monitor
        saved, monitor.threshold = monitor.threshold, 1.0
        try:
            _, u = monitor._ratio_at(t, y, yp, h)
        except (ModelEvaluationError, *CATCH, np.linalg.LinAlgError):
            return [], []
        finally:
            monitor.threshold = saved
        if u is None:
            return [], []
        culprits, connections = monitor.dependent(u)
        invariants = set(getattr(self.mod, "INVARIANTS", ()))
        return [c for c in culprits if c in invariants], connections

    def events(self) -> list:
        """One ``passage`` event per passage (a bridge that took the last one again adds none)."""
        return [r[0] for r in self.records if r[0] is not None]

    def notice(self) -> str:
        """The run message's note on the bridges ('' without any)."""
        passed = [r for r in self.records if r[0] is not None]
        if not passed:
            return ""
        listed = "; ".join(f"t = {e.t:.6g} ({e.condition[len('rank drop of the position constraints at '):]}; "
                           f"{shown})" for e, shown, *_ in passed[:4])
        more = f"; … {len(passed) - 4} more" if len(passed) > 4 else ""
        again = len(self.records) - len(passed)
        return (f"IDA passed {len(passed)} rank drop(s) of the position constraints' Jacobian, each bridged "
                f"by the implicit midpoint rule ({self.steps} steps in all, at {', '.join(f'{f:g}' for f in STEP_FACTORS)} "
                f"times the step whose local error meets the run's tolerance, the first that passed; the motion through it checked by one step against "
                f"two half steps, as `--solver midpoint` does) and restarted after it"
                + (f" ({again} bridged again after IDA failed on its way out)" if again else "") + f": {listed}{more}")
