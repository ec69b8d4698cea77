"""Switching conditions during a run: breakpoints in t, state events, sticking.

Input: a generated module with switches (``SWITCHES``, ``events()``; see
:mod:`phc.codegen.nonsmooth`), a backend, the output times and a consistent start.
Output: the run as the backends return it, plus the list of :class:`Event` s.

The rows of the generated module read the side of every switching condition from a mode
in the parameter vector; this driver sets the modes, so each integration piece is smooth:

* **Conditions in t only** (``ifelse(t < t_on, 0, V0)`` in a source, the ends of input
  pieces): their switching times are the sign changes of the boundary function g(t) on
  [t₀, t₁], found before the run (sampling, then Brent's method to full precision; an
  extremum between samples that crosses zero gives two roots). They are breakpoints like
  the ends of input pieces: the integrator stops exactly there, the modes of the next
  piece are set, and the run restarts from a consistent state.
* **Conditions on variables** (``sign(v)``, a stop ``ifelse(x > x_max, …)``, a diode
  ``ifelse(v > 0, …)``): the backend watches ``w = mode·g`` and stops where it falls
  through zero — IDA by its own root finding, the fixed-step solvers by regula falsi
  (Illinois) on the length of the last step. The mode flips and the run restarts from a
  consistent state at the event (differential states continuous, algebraic ones and the
  derivatives recomputed).
* **Set-valued sign** (:class:`~phc.codegen.nonsmooth.StickInfo`): where v crosses zero
  the driver tries to stick — the rows with ``v = 0`` and ``sign(v) = s`` — and keeps it if
  the consistent ``|s| ≤ 1``; otherwise v reverses. While sticking, ``1 ∓ s`` are watched;
  where ``|s|`` reaches 1 the body slips in the direction of s.
* **Impacts** of contacts (:mod:`phc.simulation.impacts`, several at once and with friction
  :mod:`phc.simulation.impact_law`), their closing and opening.

The module is over 800 lines because the driver's loop, its restarts and the handling of
every kind of event share the watch and its modes; the impact and friction laws live in
their own modules.

Every switch is reported as an :class:`Event` (time, condition, direction, kind). Many
events within a vanishing time (a discontinuous law that chatters around g = 0 with no
value holding it there) stop the run with a message instead of crawling on.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable, Optional

import numpy as np

from phc.errors import InconsistentInitialError, SwitchTimeError
from phc.simulation import friction, impact_law
from phc.simulation.backend import BackendRun
from phc.simulation.guard import CATCH, ModelEvaluationError
from phc.simulation.impacts import CLOSE, Contacts, has_contacts
from phc.simulation.initial import consistent_initial_conditions
from phc.simulation.order import carry as carry_order
from phc.simulation.scaling import mode_floor, tested_fraction

SAMPLES = 256
"""Equal intervals of [t₀, t₁] on which the switching functions in t are first sampled."""
MAX_SAMPLES = 1 << 16
"""Most equal intervals: a condition whose boundary function g moves across a quarter of
its range within 1/MAX_SAMPLES of the span (|g'| · span / range > MAX_SAMPLES / 4) changes
too fast to be located by sampling."""
MAX_SPLITS = 1 << 15
"""Most local refinements of that sampling (see :func:`switch_times`)."""
MAX_SWITCH_TIMES = 10_000
"""Most switching times in t of one run (each is a restart)."""
CHATTER_COUNT = 50
"""Events of one condition within :data:`CHATTER_SPAN` of the time span that stop the run."""
CHATTER_SPAN = 1e-6
MAX_EVENTS = 100_000
"""Most state events of one run."""
STICK_SLACK = 1e-9
"""A stick is accepted while the force it needs stays within (1 + slack) of the maximum."""


@dataclass(frozen=True)
class Event:
    """One switch of a run."""

    t: float
    condition: str
    """The condition as written in the model (model names), e.g. ``sign(block.fr.f)``."""
    direction: int
    """For a comparison (``a < b``): +1 it turned true, −1 false. For a function
    (``sign(x)``, ``heaviside(x)``, ``abs(x)``, ``min(a, b)``, ``max(a, b)``): +1 its argument
    (x, a − b) rose through 0, −1 it fell. For a set-valued sign: the sign it slips with,
    0 when sticking begins."""
    kind: str
    """``time`` (a condition in t, located before the run), ``state`` (located by root
    finding), ``stick`` or ``slip`` (a set-valued sign, or friction at the closed contact
    `condition`: :mod:`phc.simulation.friction`), ``impact`` (a contact's gap closed:
    `condition` and `equation` name the contact, direction −1), ``close`` (the contact
    closes: persistent contact, direction 0), ``open`` (its force fell to zero: it opens,
    direction +1) and ``passage`` (IDA passed a rank drop of the position constraints,
    bridged by the midpoint rule: `condition` names the connections, `equation` the
    constraint rows, direction 0; :mod:`phc.simulation.ida_bridge`)."""
    equation: str = ""
    """The residual row the condition occurs in."""
    comparison: bool = False
    """`condition` is a comparison (direction: turned true or false)."""

    def as_dict(self) -> dict:
        return asdict(self)


def has_switches(mod) -> bool:
    """Whether a run of `mod` needs this driver: switching conditions or contacts (impacts)."""
    return bool(len(getattr(mod, "SWITCHES", ()))) or has_contacts(mod)


class _ContactRest(Exception):
    """A contact cannot go on (:mod:`phc.simulation.impacts`): the run stops with this message."""


class Watch:
    """The switching functions of the current modes, as the backends watch them:
    ``w(t, y, ẏ)`` positive while every mode holds, one entry per switch (``mode·g``;
    +1 when not watched: conditions in t, a switch whose set-valued sign sticks) and two
    per set-valued sign (``1 − s`` and ``1 + s`` while sticking, else +1), then for every
    contact its gap while open, its force while closed (:mod:`phc.simulation.impacts`)."""

    def __init__(self, mod, p: np.ndarray):
        self.mod = mod
        self.p = np.array(p, dtype=float)
        self.n_sw, self.n_st = len(mod.SWITCHES), len(mod.STICKS)
        self.contacts = Contacts(mod)
        self.n_ct = self.contacts.n_watch
        self.n = self.n_sw + 2 * self.n_st + self.n_ct
        self.slots = np.asarray(mod.SWITCH_SLOTS, dtype=np.int64)
        self.time_only = np.asarray(mod.SWITCH_TIME_ONLY, dtype=bool)
        self.stick_slots = np.asarray(mod.STICK_SLOTS, dtype=np.int64)
        self.stick_switch = np.asarray(mod.STICK_SWITCH, dtype=np.int64)
        self.stick_orient = np.asarray(mod.STICK_ORIENT, dtype=float)
        self.sense = np.asarray(getattr(mod, "SWITCH_SENSE", np.ones(self.n_sw)), dtype=float)
        self.comparison = np.asarray(getattr(mod, "SWITCH_COMPARISON", np.zeros(self.n_sw)), dtype=bool)
        self.buf = np.zeros(self.n_sw + self.n_st)
        self.handled: list = []
        """Every mode change as (t, condition, equation), for the chatter test."""
        self.span = 0.0
        """The run's length (the contacts' accumulation test)."""
        self.refresh()

    # -- modes ---------------------------------------------------------------------------
    def refresh(self) -> None:
        modes = self.p[self.slots]
        self.stuck = self.p[self.stick_slots] > 0
        mask = ~self.time_only & (modes != 0)
        mask[self.stick_switch[self.stuck]] = False
        self.mask, self.sign = mask, np.where(mask, modes, 0.0)

    def mode(self, k: int) -> float:
        return float(self.p[self.slots[k]])

    def set_mode(self, k: int, value: float) -> None:
        self.p[self.slots[k]] = value
        self.refresh()

    def set_stick(self, j: int, stuck: bool) -> None:
        self.p[self.stick_slots[j]] = 1.0 if stuck else 0.0
        self.refresh()

    def event(self, t: float, k: int, side: float, kind: str = "state") -> Event:
        """The event of switch k whose boundary function is now on `side` (±1)."""
        return Event(t, self.mod.SWITCHES[k], int(self.sense[k] * side), kind, self.mod.SWITCH_EQUATIONS[k],
                     bool(self.comparison[k]))

    def stick_of(self, k: int) -> Optional[int]:
        hit = np.flatnonzero(self.stick_switch == k)
        return int(hit[0]) if len(hit) else None

    # -- values --------------------------------------------------------------------------
    def values(self, t, y, yp, p=None) -> np.ndarray:
        """g_k and s_j at (t, y, ẏ) (with the modes of `p`, default the current ones)."""
        try:
            self.mod.events(t, y, yp, self.p if p is None else p, self.buf)
        except CATCH as err:
            raise self._failure(t, np.arange(self.n_sw + self.n_st), str(err)) from None
        if not np.all(np.isfinite(self.buf)):
            raise self._failure(t, np.flatnonzero(~np.isfinite(self.buf)), "the value is not finite")
        return self.buf.copy()

    def __call__(self, t, y, yp) -> np.ndarray:
        v = self.values(t, y, yp)
        w = np.ones(self.n)
        w[:self.n_sw] = np.where(self.mask, self.sign * v[:self.n_sw], 1.0)
        s = v[self.n_sw:]
        w[self.n_sw:self.n_sw + 2 * self.n_st:2] = np.where(self.stuck, 1.0 - s, 1.0)
        w[self.n_sw + 1:self.n_sw + 2 * self.n_st:2] = np.where(self.stuck, 1.0 + s, 1.0)
        if self.n_ct:
            w[self.n_sw + 2 * self.n_st:] = self.contacts.watched(t, y, yp, self.p)
        return w

    def _failure(self, t, which, reason) -> ModelEvaluationError:
        i = int(which[0])
        label, eq = ((self.mod.SWITCHES[i], self.mod.SWITCH_EQUATIONS[i]) if i < self.n_sw else
                     (self.mod.STICKS[i - self.n_sw], self.mod.STICK_EQUATIONS[i - self.n_sw]))
        return ModelEvaluationError(f"the switching condition `{label}` (equation `{eq}`) cannot be evaluated at "
                                    f"t = {t:.6g}: {reason}", function="events", t=t, label=eq, reason=reason,
                                    subject=f"switching condition `{label}`")


# -- switching times of conditions in t --------------------------------------------------
def switch_times(mod, p, t0: float, t1: float, y, yp) -> list[tuple[float, int, int]]:
    """The switching times in (t0, t1) of the conditions in t only, as (time, switch,
    direction), sorted.

    Each boundary function g is sampled on an equal grid with intervals shorter than a
    quarter of its range over its largest slope, then refined where a root could hide:
    an interval without a sign change is split while g at its ends is within reach of zero
    at the slope there (``min |g| ≤ max |g'| · length``, g' by a forward difference), one
    with a sign change while the slope could have crossed zero several times
    (``max |g'| · length > 2 (|g(a)| + |g(b)|)``), down to a length of 1e-10 of the span (a
    root that only touches zero is no switch). Every sign change is then a bracket for
    Brent's method (roots to full precision). Raises
    :class:`SwitchTimeError` when a condition cannot be evaluated or needs more than
    :data:`MAX_SPLITS` refinements (it changes sign too often or too fast to be located)."""
    idx = np.flatnonzero(np.asarray(mod.SWITCH_TIME_ONLY, dtype=bool))
    if not len(idx):
        return []
    free = np.array(p, dtype=float)
    free[np.asarray(mod.SWITCH_SLOTS, dtype=np.int64)] = 0.0  # evaluate the conditions directly
    buf = np.zeros(len(mod.SWITCHES) + len(mod.STICKS))
    span = t1 - t0
    eps = 1e-7 * span
    shortest = 1e-10 * span

    def g(t):
        try:
            mod.events(float(t), y, yp, free, buf)
        except CATCH as err:
            raise SwitchTimeError(int(idx[0]), f"it cannot be evaluated at t = {t:.6g} ({err})") from None
        value = buf[idx].copy()
        bad = np.flatnonzero(~np.isfinite(value))
        if len(bad):
            raise SwitchTimeError(int(idx[bad[0]]), f"it is not finite at t = {t:.6g}")
        return value

    def sample(t):
        value = g(t)
        return value, np.abs(g(t + eps) - value) / eps

    n = SAMPLES
    while True:  # a grid fine enough that no sampling interval spans a large part of g's range
        ts = np.linspace(t0, t1, n + 1)
        points = [sample(t) for t in ts]
        values = np.array([v for v, _ in points])
        spread = values.max(axis=0) - values.min(axis=0)
        slope = np.array([d for _, d in points]).max(axis=0)
        need = np.where(spread > 0, 4.0 * span * slope / np.where(spread > 0, spread, 1.0), 0.0)
        if need.max() <= n:
            break
        if need.max() > MAX_SAMPLES:
            c = int(np.argmax(need))
            raise SwitchTimeError(int(idx[c]), f"it changes too fast: sampling it would take {need[c]:.3g} points "
                                  f"(at most {MAX_SAMPLES})")
        n = int(2 ** np.ceil(np.log2(need.max())))
    stack = [(ts[i], ts[i + 1], points[i], points[i + 1]) for i in range(n - 1, -1, -1)]
    brackets: list[tuple[int, float, float, float, float]] = []
    touching: list[tuple[int, float]] = []
    splits = 0
    while stack:
        a, b, (ga, da), (gb, db) = stack.pop()
        change = ga * gb < 0
        rise = np.maximum(da, db) * (b - a)
        # no sign change, but zero within reach at the slope there: two roots may hide; a
        # sign change that the slope could have crossed several times over: three may
        reach = np.where(change, rise > 2.0 * (np.abs(ga) + np.abs(gb)),
                         np.minimum(np.abs(ga), np.abs(gb)) <= rise)
        if reach.any() and b - a > shortest:
            splits += 1
            if splits > MAX_SPLITS:
                c = int(np.argmax(reach))
                raise SwitchTimeError(int(idx[c]), f"it changes sign too often or too fast (more than {MAX_SPLITS} "
                                      "refinements of the sampling)")
            m = 0.5 * (a + b)
            mid = sample(m)
            stack += [(m, b, mid, (gb, db)), (a, m, (ga, da), mid)]
            continue
        for c in np.flatnonzero(change):
            brackets.append((int(c), a, b, float(ga[c]), float(gb[c])))
        for c in np.flatnonzero((gb == 0) & (b < t1)):
            touching.append((int(c), b))
        if len(brackets) > MAX_SWITCH_TIMES:
            c = brackets[-1][0]
            raise SwitchTimeError(int(idx[c]), f"it switches more than {MAX_SWITCH_TIMES} times, and each switch is "
                                  "a restart of the integrator")
    from scipy.optimize import brentq  # only here: scipy.optimize costs 0.2 s to import

    found = []
    for c, a, b, fa, fb in brackets:
        root = float(brentq(lambda t, c=c: g(t)[c], a, b, xtol=1e-300, rtol=4 * np.finfo(float).eps, maxiter=200))
        found.append((root, int(idx[c]), 1 if fb > 0 else -1))
    for c, t in touching:  # a sample exactly on the boundary: a switch if the sign differs around it
        before, after = g(t - shortest)[c], g(t + shortest)[c]
        if before * after < 0:
            found.append((float(t), int(idx[c]), 1 if after > 0 else -1))
    return sorted(f for f in found if t0 < f[0] < t1)


def locate_switch_times(compiled) -> list:
    """Diagnostics (``PHC-E703``, located at the row) for conditions in t whose switching
    times cannot be located on the model's [t_start, t_end] with its default parameters —
    found at compile time rather than at the start of a run."""
    from phc.diagnostics import Diagnostic

    mod = getattr(compiled.module, "REFERENCE", compiled.module)
    if not np.asarray(getattr(mod, "SWITCH_TIME_ONLY", ()), dtype=bool).any():
        return []
    opts = compiled.options
    t0, t1 = float(opts.get("t_start", 0.0)), float(opts["t_end"])
    y = np.zeros(mod.N)
    try:
        switch_times(mod, mod.full_parameters(), t0, t1, y, y)
    except SwitchTimeError as err:
        eq = mod.SWITCH_EQUATIONS[err.k]
        owner = tuple(getattr(mod, "SWITCH_COMPONENTS", ("",) * len(mod.SWITCHES)))[err.k]
        span = next((e.span for e in compiled.dae.equations if e.label == eq and (not owner or e.component == owner)),
                    None)
        topology = compiled.dae.topology
        if span is None and owner and topology is not None:  # written in a component whose rows were merged
            span = next((d.span for d in topology.dirac if d.component == owner), None)
        span = span or next((e.span for e in compiled.dae.equations if e.label == eq), None)
        where = f"written in `{owner}`" if owner else f"in equation `{eq}`"
        return [Diagnostic("PHC-E703", f"the switching times of the condition `{mod.SWITCHES[err.k]}` ({where}) cannot "
                           f"be located on [{t0:g}, {t1:g}]: {err.message}", span=span,
                           hint="a condition in t must change sign at isolated times that can be found by sampling "
                           "(see docs/events.md); a fast periodic switch is better averaged, or given as a table")]
    return []


ROUNDOFF = 1e-12
"""Times closer than this (relative to ``max(1, |t|)``) are one time: a breakpoint at 0.3 and
``t_end = 0.1 + 0.2`` (0.30000000000000004) leave no piece of length 5e-17 to integrate."""


def breakpoints_within(points, t0: float, t1: float) -> list[float]:
    """Sorted times strictly inside (t0, t1), those within round-off of an end or of each
    other taken as one (:data:`ROUNDOFF`)."""
    out: list[float] = []
    for t in sorted(float(p) for p in points):
        tol = ROUNDOFF * max(1.0, abs(t))
        if t - t0 <= tol or t1 - t <= tol or (out and t - out[-1] <= tol):
            continue
        out.append(t)
    return out


def piece_grid(t_out: np.ndarray, start: float, end: float) -> np.ndarray:
    """The times a piece ``[start, end]`` between breakpoints is integrated to: its ends and
    the output times strictly inside that are farther than round-off from both (IDA refuses
    an output 5e-17 after its start; :func:`piece_outputs` gives such times the end's value)."""
    tol = ROUNDOFF * max(1.0, abs(start), abs(end))
    inside = t_out[(t_out > start + tol) & (t_out < end - tol)]
    return np.concatenate([[start], inside, [end]])


def piece_outputs(out: BackendRun, t_out: np.ndarray, start: float, end: float):
    """``(t, y, yp)`` of a piece's run (on :func:`piece_grid`) at the output times it covers:
    those it reached, an output time within round-off of the piece's start or (reached) end
    taking that end's value. An output time equal to a breakpoint belongs to both pieces
    around it; the caller keeps the first (the value before the restart)."""
    t = np.asarray(out.t, dtype=float)
    y, yp = np.atleast_2d(out.y), np.atleast_2d(out.yp)
    last = t[-1]
    tol = ROUNDOFF * max(1.0, abs(start), abs(end))
    want = t_out[(t_out >= start) & (t_out <= last)]
    pos = np.minimum(np.searchsorted(t, want), len(t) - 1)
    exact = t[pos] == want
    near_start = ~exact & (want - start <= tol)
    near_end = ~exact & ~near_start & (last - want <= tol) & (last == end)
    take = exact | near_start | near_end
    index = np.where(exact, pos, np.where(near_start, 0, len(t) - 1))[take]
    return want[take], y[index], yp[index]


# -- the driver --------------------------------------------------------------------------
def integrate_switched(backend: Callable, mod, p, t_out, init, fixed: set, keywords: dict,
                       progress=None) -> BackendRun:
    """Integrate a model with switches (see the module docstring).

    Parameters
    ----------
    backend : callable
        ``backend(mod, p, t_out, y0, yp0, **keywords, events=watch)`` (a
        :class:`~phc.simulation.backend.Backend`; `keywords` hold the run's ``options``,
        a :class:`~phc.options.RunOptions`, and the backend's other keywords).
    init : InitialResult
        The consistent start with every condition evaluated directly.
    fixed : set of int
        Indices of the initial values that are fixed (not guesses).
    """
    t_out = np.asarray(t_out, dtype=float)
    t0, t1 = float(t_out[0]), float(t_out[-1])
    watch = Watch(mod, p)
    watch.span = t1 - t0
    energy = [j for j, r in enumerate(mod.ROLES) if r == "energy"]
    dif = set(np.flatnonzero(np.asarray(mod.DIFFERENTIAL)).tolist())
    stats = dict(steps=0, nfev=0, njev=0)
    events: list[Event] = []
    y, yp = np.array(init.y0, dtype=float), np.array(init.yp0, dtype=float)
    try:
        timed = switch_times(mod, p, t0, t1, y, yp)
    except SwitchTimeError as err:
        return _stopped(t_out, y, yp, stats, events,
                        f"cannot locate the switching times of `{mod.SWITCHES[err.k]}` (equation "
                        f"`{mod.SWITCH_EQUATIONS[err.k]}`) on [{t0:g}, {t1:g}]: {err.message}")
    breaks = breakpoints_within([t for t, _, _ in timed] + list(getattr(mod, "BREAKPOINTS", ())), t0, t1)
    ends = breaks + [t1]
    _time_modes(watch, t0, ends[0], y, yp)
    try:
        y, yp = _start(watch, t0, y, yp, fixed | set(energy), events, t1 - t0)
    except InconsistentInitialError as err:
        return _stopped(t_out, y, yp, stats, events, "no consistent start with the switching conditions at t0: "
                        + "; ".join(err.problems))
    if watch.n_ct:  # a contact must start open (or touching: then watched from just below zero)
        gaps = watch.contacts.gaps(t0, y, yp, watch.p)
        scale = 1e-12 * (1.0 + float(np.abs(y).max(initial=0.0)))
        for k in np.flatnonzero(gaps < -scale):
            return _stopped(t_out, y, yp, stats, events,
                            f"contact `{watch.contacts.names[k]}` starts penetrated: its gap is {gaps[k]:.6g} < 0 at "
                            f"t = {t0:g}; give initial positions where the gap is ≥ 0")
        watch.contacts.offset[:] = np.where(gaps <= scale, scale, 0.0)
        try:
            y, yp = _close_resting(watch, t0, y, yp, gaps <= scale, events, dif, energy)
        except _ContactRest as err:
            return _stopped(t_out, y, yp, stats, events, str(err))
    pieces = [(t_out[:1], y[None, :], yp[None, :])]
    modes = [watch.p.copy()]  # the parameter vector (with the modes) of each piece
    t, seg = t0, 0
    floors: dict = {}  # the scales' round-off floor per mode (parameter vector with the modes)
    out: Optional[BackendRun] = None
    stop: dict = {}  # success, message, interrupted of a stop between the backend's runs
    note = None
    while True:
        end = ends[seg]
        try:
            if end - t > ROUNDOFF * max(1.0, abs(t)):
                grid = piece_grid(t_out, t, end)
                active = watch if watch.mask.any() or watch.stuck.any() or watch.n_ct else None
                seg_keywords = keywords
                options = keywords["options"]
                if keywords.get("nominal") is not None:
                    # the round-off floor of the scales in this segment's mode (scaling.mode_floor),
                    # once per mode: a stick-slip run returns to the same few modes many times
                    mode = watch.p.tobytes()
                    if mode not in floors:
                        tested = options.atol * tested_fraction(options.solver, options.rtol)
                        floors[mode] = mode_floor(mod, watch.p, keywords["nominal"], y, yp, t0=t, span=t1 - t,
                                                  atol=tested)
                    seg_keywords = dict(keywords, nominal=floors[mode])
                try:
                    out = backend(mod, watch.p.copy(), grid, y, yp, **seg_keywords, events=active)
                except (ModelEvaluationError, KeyboardInterrupt) as err:
                    interrupted = isinstance(err, KeyboardInterrupt)
                    out = BackendRun(t=grid[:1], y=y[None, :], yp=yp[None, :], steps=0, success=False,
                                     interrupted=interrupted,
                                     message=f"interrupted at t = {t:.6g}" if interrupted else str(err))
                for key in stats:
                    stats[key] += int(getattr(out, key) or 0)
                events.extend(out.events)  # the piece's own (IDA's `passage` events), before its switch
                note = out.extra.get("order_note") or note  # IDA's maximum order phc chose (simulation/order.py)
                keywords = carry_order(keywords, out)
                # an output time equal to a restart time keeps its first value (np.unique below)
                pieces.append(piece_outputs(out, t_out, t, end))
                modes.append(watch.p.copy())
                if not out.success:
                    break
                event, out = out.event, out.replace(event=None)
                if event is not None:
                    t = float(event["t"])
                    y, yp = _handle(watch, t, np.asarray(event["y"], dtype=float),
                                    np.asarray(event["yp"], dtype=float), event["which"], events, dif, energy)
                    chatter = _chatter(watch.handled, t1 - t0)
                    if chatter or len(watch.handled) > MAX_EVENTS:
                        stop = dict(success=False, message=chatter or f"more than {MAX_EVENTS} events; stopped "
                                    f"at t = {t:.6g}")
                        break
                    continue
                y, yp = np.atleast_2d(out.y)[-1], np.atleast_2d(out.yp)[-1]
            if seg == len(ends) - 1:
                break
            # a breakpoint: the switches in t that change here, the modes of the next piece, a restart
            t = end
            for tb, k, direction in timed:
                if abs(tb - t) <= ROUNDOFF * max(1.0, abs(t)):
                    events.append(watch.event(t, k, direction, "time"))
            seg += 1
            before = _residual(watch, t, y, yp)
            _time_modes(watch, t, ends[seg], y, yp)
            if not _continuous(watch, t, y, yp, before):
                # the rows change at the switch: restart from a consistent state (a switch
                # that the residual does not feel, such as a source ramp that ends with
                # matching value, needs none: the integrator goes on from its state)
                y, yp = _restart(watch, t, y, dif | set(energy))
            y, yp = _settle(watch, t, y, yp, events, dif, energy)
        except _ContactRest as rest:
            stop = dict(success=False, message=str(rest))
            break
        except InconsistentInitialError as err:
            stop = dict(success=False, message=f"cannot restart after the switch at t = {t:.6g}: {'; '.join(err.problems)}")
            break
        except ModelEvaluationError as err:
            stop = dict(success=False, message=f"cannot restart after the switch at t = {t:.6g}: {err}")
            break
        except KeyboardInterrupt:
            stop = dict(success=False, interrupted=True, message=f"interrupted at t = {t:.6g}")
            break
    merged = {k: np.concatenate([pc[i] for pc in pieces]) for i, k in enumerate(("t", "y", "yp"))}
    # the modes at each output time, for recomputing the algebraic variables there (polish.py)
    merged["modes"] = np.concatenate([np.repeat(m[None, :], len(pc[0]), axis=0) for m, pc in zip(modes, pieces)])
    _, first = np.unique(merged["t"], return_index=True)
    merged = {k: v[np.sort(first)] for k, v in merged.items()}
    if out is None:  # no piece ran (the run ended at a breakpoint at its start)
        out = BackendRun(t=merged["t"], y=merged["y"], yp=merged["yp"], steps=0, success=True,
                         message="integration finished")
    return out.replace(**merged, **stats, **stop, event=None, events=events, order_note=note)


def _stopped(t_out, y, yp, stats, events, message) -> BackendRun:
    return BackendRun(t=t_out[:1], y=y[None, :], yp=yp[None, :], success=False, message=message, events=events,
                      **stats)


def _time_modes(watch: Watch, a: float, b: float, y, yp) -> None:
    """Modes of the conditions in t for the piece (a, b): no switch lies inside, so the side
    at its midpoint is the side throughout."""
    if not watch.time_only.any():
        return
    free = watch.p.copy()
    free[watch.slots] = 0.0
    v = watch.values(0.5 * (a + b), y, yp, free)
    for k in np.flatnonzero(watch.time_only):
        watch.p[watch.slots[k]] = 1.0 if v[k] >= 0 else -1.0
    watch.refresh()


def _zero(value: float, y) -> bool:
    """On the boundary at the start, as far as the start can tell: the side is then decided
    a little later (the probe is right for a value just off the boundary too)."""
    return abs(value) <= 1e-9 * (1.0 + float(np.abs(y).max(initial=0.0)))


def _start(watch: Watch, t0, y, yp, fixed, events, span) -> tuple[np.ndarray, np.ndarray]:
    """Modes of the conditions on variables at the start, then a consistent start with them.
    A condition exactly on its boundary takes the side the motion goes to (its value at a
    consistent state a little later); a set-valued sign at zero sticks if it can."""
    mod = watch.mod
    free = watch.p.copy()
    free[watch.slots] = 0.0
    free[watch.stick_slots] = 0.0
    v = watch.values(t0, y, yp, free)
    state = np.flatnonzero(~watch.time_only)
    ahead = v
    if len(state):
        # the value a little later, at a consistent state: a condition whose value at the start
        # is no larger than its change over that instant is on its boundary as far as the start
        # can tell (a diode at a source's zero crossing starts at -1.4e-9 V of solver round-off,
        # a millionth of the 2e-5 V it rises by), whatever the units
        delta = 1e-7 * span
        try:
            r = consistent_initial_conditions(mod, free, t0 + delta, dict(enumerate(y + delta * yp)), set(fixed),
                                              initial_relations=False)
            ahead = watch.values(t0 + delta, r.y0, r.yp0, free)
        except (InconsistentInitialError, ModelEvaluationError, *CATCH):
            pass
    ties = [k for k in state if _zero(v[k], y) or abs(v[k]) <= abs(ahead[k] - v[k])]
    for k in state:
        side = ahead[k] if k in ties else v[k]
        watch.p[watch.slots[k]] = 1.0 if side >= 0 else -1.0
    watch.refresh()
    values = dict(enumerate(y))
    for j in range(watch.n_st):
        k = int(watch.stick_switch[j])
        if k in ties:
            trial = _try_stick(watch, j, t0, y, fixed, initial=True)
            if trial is not None:
                y, yp = trial
                events.append(Event(t0, mod.STICKS[j], 0, "stick", mod.STICK_EQUATIONS[j]))
                values = dict(enumerate(y))
    r = consistent_initial_conditions(mod, watch.p, t0, values, set(fixed))
    return r.y0, r.yp0


def _try_stick(watch: Watch, j: int, t, y, fixed, initial=False):
    """Stick set-valued sign j at (t, y) if the force it needs is within the bound: sets the
    modes and returns the consistent state, else sets the slip mode the force points to and
    returns None. On the bound the rule of the contacts' friction decides
    (:func:`phc.simulation.friction.slides_on`): a body sliding the way the force points
    slides on, one at rest (`initial`) or sliding the other way sticks."""
    mod = watch.mod
    k = int(watch.stick_switch[j])
    trial = watch.p.copy()
    trial[watch.stick_slots[j]] = 1.0
    try:
        r = consistent_initial_conditions(mod, trial, t, dict(enumerate(y)), set(fixed),
                                          initial_relations=initial)
    except InconsistentInitialError:
        return None
    s = watch.values(t, r.y0, r.yp0, trial)[watch.n_sw + j]
    way = friction.slides_on(float(s), 1.0, 0.0 if initial else watch.mode(k), float(watch.stick_orient[j]))
    if way == 0:
        watch.p = trial
        watch.refresh()
        return r.y0, r.yp0
    watch.set_mode(k, way)
    return None


def _residual(watch: Watch, t, y, yp) -> np.ndarray:
    r = np.zeros(watch.mod.N)
    watch.mod.residual(t, y, yp, watch.p, r)
    return r


def _continuous(watch: Watch, t, y, yp, before: np.ndarray, rtol: float = 1e-12) -> bool:
    """Whether the residual at (t, y, ẏ) is the same (to round-off, relative to the size
    of each row's terms) with the new modes as with the old ones."""
    mod = watch.mod
    after = _residual(watch, t, y, yp)
    data = np.zeros(len(mod.JAC_ROWS))
    mod.jacobian(t, y, yp, watch.p, 1.0, data)
    size = (np.abs(y) + np.abs(yp) + 1.0)[mod.JAC_COLS]
    scale = np.bincount(mod.JAC_ROWS, weights=np.abs(data) * size, minlength=mod.N)
    scale = np.maximum(scale, np.abs(before))
    return bool(np.all(np.abs(after - before) <= rtol * np.maximum(scale, 1e-300)))


def _restart(watch: Watch, t, y, fixed) -> tuple[np.ndarray, np.ndarray]:
    r = consistent_initial_conditions(watch.mod, watch.p, t, dict(enumerate(y)), set(fixed),
                                      initial_relations=False)
    return r.y0, r.yp0


def _handle(watch: Watch, t, y, yp, which, events, dif, energy) -> tuple[np.ndarray, np.ndarray]:
    """New modes for the functions in `which` that fell to zero at t, and the consistent
    state to restart from."""
    mod = watch.mod
    candidates = []
    impacts = []
    for i in sorted(int(i) for i in which):
        if i >= watch.n_sw + 2 * watch.n_st:
            impacts.append(i - watch.n_sw - 2 * watch.n_st)
        elif i < watch.n_sw:
            j = watch.stick_of(i)
            if j is not None and not watch.stuck[j]:
                candidates.append(j)
                continue
            new = -watch.mode(i)
            watch.set_mode(i, new)
            watch.handled.append((t, mod.SWITCHES[i], mod.SWITCH_EQUATIONS[i]))
            events.append(watch.event(t, i, new))
        else:
            j, bound = (i - watch.n_sw) // 2, (1 if (i - watch.n_sw) % 2 == 0 else -1)
            if not watch.stuck[j]:
                continue
            watch.set_stick(j, False)
            watch.set_mode(int(watch.stick_switch[j]), float(watch.stick_orient[j] * bound))
            watch.handled.append((t, mod.STICKS[j], mod.STICK_EQUATIONS[j]))
            events.append(Event(t, mod.STICKS[j], bound, "slip", mod.STICK_EQUATIONS[j]))
    state = None
    before = {j: watch.mode(int(watch.stick_switch[j])) for j in candidates}
    for j in candidates:
        watch.handled.append((t, mod.STICKS[j], mod.STICK_EQUATIONS[j]))
        trial = _try_stick(watch, j, t, y, set(energy))
        if trial is not None:
            state = trial
            events.append(Event(t, mod.STICKS[j], 0, "stick", mod.STICK_EQUATIONS[j]))
        elif watch.mode(int(watch.stick_switch[j])) != before[j]:
            k = int(watch.stick_switch[j])
            events.append(Event(t, mod.STICKS[j], int(watch.mode(k) * watch.stick_orient[j]), "slip",
                                mod.STICK_EQUATIONS[j]))
        # else: the trial failed the way it was sliding: no new slip, it slides on
    if impacts and (candidates or len(impacts) < len(which)):
        y, yp = _restart(watch, t, state[0] if state is not None else y, dif | set(energy))
        state = None
    hits = [k for k in impacts if k < watch.contacts.n and not watch.contacts.closed(k, watch.p)]
    joint = bool(hits) and impact_law.wanted(watch, hits)  # frictional, or with other contacts
    if joint:
        state = y, yp = impact_law.joint_impact(watch, hits, t, y, yp, events, dif, energy)
    for k in (k for k in impacts if not (joint and k in hits)):
        if k >= watch.contacts.n:  # friction at a closed contact: stick or slip
            state = y, yp = friction.on_event(watch, k - watch.contacts.n, t, y, yp, events, dif, energy)
            continue
        name = watch.contacts.names[k]
        if watch.contacts.closed(k, watch.p):  # its force fell to zero: it opens
            y, yp = _open(watch, k, t, y, events, dif, energy)
            state = (y, yp)
            continue
        y, yp, outcome, before = watch.contacts.impact(k, t, y, yp, watch.p,
                                                       lambda z: _restart(watch, t, z, dif | set(energy)),
                                                       span=watch.span)
        if before < 0:
            watch.handled.append((t, name, "contact"))
            events.append(Event(t, name, -1, "impact", name))
        if outcome == CLOSE:
            y, yp, _ = _close(watch, k, t, y, yp, events, dif, energy)
        elif outcome is not None:
            raise _ContactRest(outcome)
        state = (y, yp)
    if impacts and not candidates and len(impacts) == len(which):
        return _settle(watch, t, state[0], state[1], events, dif, energy)
    if state is None or len(candidates) > 1 or len(candidates) < len(which):
        state = _restart(watch, t, state[0] if state is not None else y, dif | set(energy))
    return _settle(watch, t, state[0], state[1], events, dif, energy)


def _close(watch: Watch, k: int, t, y, yp, events, dif, energy):
    """Close contact k at (t, y) where its gap rate is zero (persistent contact): its row
    then holds ġ = 0 and its force λ is the multiplier. Returns ``(y, ẏ, closed)``: it stays
    open where the consistent force pulls (λ < 0)."""
    contacts = watch.contacts
    name = contacts.names[k]
    watch.p[contacts.mode[k]], contacts.consistent[k] = 1.0, None
    try:  # with friction: sliding, or sticking where it can (events of the mode: phc.simulation.friction)
        y1, yp1, modes = friction.on_close(watch, k, t, y, yp, dif, energy)
    except InconsistentInitialError as err:
        raise _ContactRest(f"contact `{name}` cannot close at t = {t:.6g}: " + "; ".join(err.problems)) from None
    if y1[contacts.force[k]] < 0:
        watch.p[contacts.mode[k]] = 0.0
        return y, yp, False
    # the impacts that accumulated here are over (the chatter test counts what follows)
    watch.handled[:] = [h for h in watch.handled if h[1] != name]
    watch.handled.append((t, name, "contact"))
    events += [Event(t, name, 0, "close", name), *modes]
    return y1, yp1, True


def _open(watch: Watch, k: int, t, y, events, dif, energy):
    """Open closed contact k at t (its force fell to zero); its gap, zero to the event's
    location error, is watched from just below its value. The force λ is a multiplier,
    outside IDA's error test: where it is still positive at the consistent state the contact
    stays closed, its force watched on consistent states until it falls to zero."""
    contacts = watch.contacts
    name = contacts.names[k]
    fixed = dif | set(energy)
    y1, yp1 = _restart(watch, t, y, fixed)
    if y1[contacts.force[k]] > 1e-9 * (1.0 + float(np.abs(y1).max(initial=0.0))):
        contacts.consistent[k] = lambda tt, z: _restart(watch, tt, z, fixed)
        watch.handled.append((t, name, "contact"))
        return y1, yp1
    contacts.consistent[k] = None
    watch.p[contacts.mode[k]] = 0.0
    y, yp = _restart(watch, t, y, dif | set(energy))
    gap = float(contacts.outputs(t, y, yp, watch.p)[contacts.gap[k]])
    contacts.offset[k] = max(0.0, -gap) + 1e-12 * (1.0 + float(np.abs(y).max(initial=0.0)))
    watch.handled.append((t, name, "contact"))
    events.append(Event(t, name, 1, "open", name))
    return y, yp


def _close_resting(watch: Watch, t0, y, yp, touching, events, dif, energy):
    """At the start: close each contact that touches (gap 0) with its gap rate zero, where
    the load presses the masses onto it (a ball lying on the floor)."""
    contacts = watch.contacts
    restart = (lambda z: _restart(watch, t0, z, dif | set(energy)))
    for k in np.flatnonzero(touching):
        if contacts.mode[k] is None:
            continue
        rate = contacts.rate_of(t0, y, yp, watch.p, int(k))
        if abs(rate) > 1e-12 * (1.0 + float(np.abs(yp).max(initial=0.0))):
            continue  # approaching (an impact at once) or leaving
        y1, yp1, fault = contacts.plastic(int(k), t0, y, yp, watch.p, restart)
        if fault is not None:
            raise _ContactRest(fault)
        y1, yp1, closed = _close(watch, int(k), t0, y1, yp1, events, dif, energy)
        if closed:
            y, yp = y1, yp1
    return y, yp


def _settle(watch: Watch, t, y, yp, events, dif, energy, rounds: int = 4):
    """After a restart every watched function must be ≥ 0 (the modes hold): a condition the
    consistent state puts on its other side flips at once, and a stick whose force now
    exceeds the bound (a force that jumped at a breakpoint) slips at once."""
    mod = watch.mod
    for _ in range(rounds):
        w = watch(t, y, yp)
        v = watch.values(t, y, yp)
        scale = 1e-9 * (1.0 + float(np.abs(v).max(initial=0.0)))
        wrong = np.flatnonzero(w[:watch.n_sw] < -scale)
        loose = [j for j in np.flatnonzero(watch.stuck) if abs(v[watch.n_sw + j]) > 1.0 + STICK_SLACK]
        if not len(wrong) and not loose and not friction.settle(watch, t, y, yp, events):
            break
        for k in wrong:
            new = -watch.mode(int(k))
            watch.set_mode(int(k), new)
            watch.handled.append((t, mod.SWITCHES[k], mod.SWITCH_EQUATIONS[k]))
            last = next((i for i in range(len(events) - 1, -1, -1) if events[i].t == t
                         and events[i].condition == mod.SWITCHES[k] and events[i].kind == "state"), None)
            if last is not None:
                # the event just handled did not happen: located on interpolated algebraic values, its
                # condition is back on the old side at the consistent state (the crossing follows)
                del events[last]
            else:
                events.append(watch.event(t, int(k), new))
        for j in loose:
            direction = 1 if v[watch.n_sw + j] > 0 else -1
            watch.set_stick(int(j), False)
            watch.set_mode(int(watch.stick_switch[j]), float(watch.stick_orient[j] * direction))
            watch.handled.append((t, mod.STICKS[j], mod.STICK_EQUATIONS[j]))
            events.append(Event(t, mod.STICKS[j], direction, "slip", mod.STICK_EQUATIONS[j]))
        y, yp = _restart(watch, t, y, dif | set(energy))
    return y, yp


def _chatter(handled, span) -> Optional[str]:
    """A message when one condition switched CHATTER_COUNT times within CHATTER_SPAN of the
    run: it slides along its boundary with no value of the law holding it there."""
    if len(handled) < CHATTER_COUNT:
        return None
    t_last, condition, equation = handled[-1]
    times = [t for t, c, _ in handled[-4 * CHATTER_COUNT:] if c == condition][-CHATTER_COUNT:]
    if len(times) == CHATTER_COUNT and times[-1] - times[0] <= CHATTER_SPAN * span:
        if equation == "friction":
            return (f"the friction at contact `{condition}` switched between sticking and sliding {CHATTER_COUNT} "
                    f"times within {times[-1] - times[0]:.3g} at t = {t_last:.6g}: neither mode holds there "
                    "(phc.simulation.friction; docs/events.md); a fixed-step solver (`midpoint4`) may step over it")
        if equation == "contact":
            return (f"contact `{condition}` switched {CHATTER_COUNT} times within {times[-1] - times[0]:.3g} at "
                    f"t = {t_last:.6g} (impacts, closing, opening): neither its gap nor its force keeps a sign "
                    "(docs/events.md)")
        return (f"the switching condition `{condition}` (equation `{equation}`) switched {CHATTER_COUNT} "
                f"times within {times[-1] - times[0]:.3g} at t = {t_last:.6g}: the solution slides along its "
                "boundary and no branch holds it there. A Coulomb law written `F*sign(v)` in a row it enters "
                "affinely sticks (set-valued, docs/events.md); otherwise regularize the law (e.g. "
                "`F*tanh(v/v0)`) or give it a value on the boundary")
    return None


__all__ = ["Event", "Watch", "SwitchTimeError", "has_switches", "integrate_switched", "locate_switch_times",
           "switch_times"]
