"""Singular configurations along the motion: where the position constraints lose rank.

Input: a compiled model (:class:`~phc.pipeline.CompiledModel`) and its consistent initial
state. Output: a :class:`MotionSurvey` — the rank drops of the position constraints'
Jacobian ``G = ∂g/∂q`` found on the configurations reachable from the initial one by
moving along the constraints, each with its configuration, the connections whose rows
become dependent and whether the motion passes it; and one located warning (PHC-W422)
per rank drop.

The coupling certificate (:mod:`phc.checks.certify`) tests surjectivity at the initial
state and at random states, which a singular set of measure zero escapes (the N four-bar
mechanism: all bars horizontal). Here the configuration manifold ``{q : g(q) = 0}`` is
traced from the initial configuration by pseudo-arclength continuation (E. L. Allgower,
K. Georg, "Introduction to Numerical Continuation Methods", SIAM 2003, chapter 2): a
predictor along the tangent (the kernel of G, the previous tangent projected on it, so
the curve keeps its branch through a crossing of branches) and a corrector, phc's
minimum-norm Gauss–Newton projection onto the invariants
(:class:`phc.simulation.midpoint.Projector`, the one the fixed-step solvers use). Along
the curve the conditioning σ_r/σ_max of G is watched, its rows and columns scaled once, at
the start, by LAPACK's equilibration (as the singularity monitor scales its matrix, but
fixed, so that a row or column that vanishes stays visible); at each local minimum the
configuration is located along the curve (golden section to round-off, scipy). A minimum is
a rank drop when the ratio is below the certificate's rank threshold
(:data:`phc.checks.certify.RANK_RTOL`) or falls to zero like the distance to it
(:func:`_falls_linearly`: where branches cross, the crossing is located only to about √ε);
a curve that ends where the ratio is below :data:`phc.checks.certify.WARN_RTOL` is a rank
drop no motion passes (a cusp). The rows that become dependent are the large entries of the
left singular vectors of the singular values lost (:func:`_lost`).

Whether the motion passes it is decided by energy where that is exact: a lossless
mechanism with one degree of freedom (G of rank n − 1, every other state a momentum, no
ports, nothing depends on time) moves along the traced curve with kinetic energy
``T(q) = H₀ − V(q)`` (``V`` the Hamiltonian with every momentum zero). It reaches the
configurations around the start where T stays positive; a rank drop it reaches with
T > 0 it passes when the curve continues through it (the constraint forces lose a
direction for an instant, the motion does not — as the fixed-step solvers find,
:func:`phc.simulation.midpoint.passes_rank_drop`), and it cannot continue there when the
curve ends or turns back at it. For other models the survey lists the rank drops on the
curve without a verdict on the motion.

The cost is bounded: at most :data:`MAX_STEPS` continuation steps and :data:`SECONDS`
seconds; a survey cut short says so.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from phc.checks.certify import RANK_RTOL, WARN_RTOL
from phc.diagnostics import Diagnostic, DiagnosticList

MAX_STEPS = 1000
"""Continuation steps of one survey (all curves together)."""
SECONDS = 10.0
"""Time box of one survey."""
MAX_TURN = 0.1
"""Largest angle (rad) between consecutive tangents of an accepted step; a longer step is halved."""
FIRST_STEP = 0.02
"""First arclength step, relative to the configuration's size max(1, ‖q₀‖∞)."""
MAX_STEP = 0.1
"""Longest arclength step, relative to the configuration's size."""
MIN_STEP = 1e-7
"""A curve on which no step of this relative length is accepted ends there."""
MAX_LENGTH = 200.0
"""Longest curve traced in one direction, relative to the configuration's size."""
PROJECTION_RTOL = 1e-12
"""A projected point is on the constraints when max |g| is below this times the size of g's terms."""
LOST = 1e-4
"""At a rank drop, singular values of the scaled Jacobian below this fraction of the largest
count as lost (:func:`_lost`)."""
SAME = 1e-3
"""Rank drops closer than this fraction of the configuration's size are one (a curve that
ends at one is traced to it from both sides, each located to its last step)."""
ENERGY_RTOL = 1e-9
"""Kinetic energies below this fraction of the energy scale count as zero (a turning point)."""


@dataclass
class RankDrop:
    """One configuration where the position constraints' Jacobian loses rank."""

    configuration: dict[str, float]
    ratio: float
    """σ_min/σ_max of the equilibrated constraint Jacobian there."""
    rank: int
    full_rank: int
    rows: list[str]
    """The invariants (equation labels) whose rows become dependent."""
    connections: list[str]
    """Where those rows come from (``connection `a — b` (file:line)``, or the row's label)."""
    verdict: str
    """"passes", "cannot continue", "not reached" or "undecided"."""
    kinetic_energy: Optional[float] = None
    why: str = ""
    span: object = None
    path: Optional[str] = None

    def to_dict(self) -> dict:
        return {"configuration": dict(self.configuration), "sigma_ratio": self.ratio, "rank": self.rank,
                "rank_needed": self.full_rank, "rows": list(self.rows), "connections": list(self.connections),
                "verdict": self.verdict, "kinetic_energy": self.kinetic_energy, "why": self.why}


@dataclass
class MotionSurvey:
    """What the continuation along the constraints found."""

    drops: list[RankDrop] = field(default_factory=list)
    skipped: str = ""
    steps: int = 0
    length: float = 0.0
    closed: bool = False
    cut_short: str = ""
    energy_note: str = ""
    """Why the energy argument does not apply ("" when it does)."""
    seconds: float = 0.0
    diagnostics: DiagnosticList = field(default_factory=DiagnosticList)

    def summary(self) -> str:
        if self.skipped:
            return f"not looked for: {self.skipped}"
        how = (f"{self.steps} continuation steps along the constraints from the initial configuration, "
               + ("the curve closes" if self.closed else f"arclength {self.length:.3g}")
               + (f"; {self.cut_short}" if self.cut_short else "") + f"; {self.seconds:.2f} s")
        if not self.drops:
            return f"none found ({how})"
        verdicts = ", ".join(f"{sum(d.verdict == v for d in self.drops)} {v}" for v in
                             ("passes", "cannot continue", "not reached", "undecided")
                             if any(d.verdict == v for d in self.drops))
        return f"{len(self.drops)} rank drop(s) of the position constraints ({verdicts}; each a PHC-W422 warning; {how})"

    def to_dict(self) -> dict:
        return {"skipped": self.skipped or None, "steps": self.steps, "length": self.length, "closed": self.closed,
                "cut_short": self.cut_short or None, "energy_argument": self.energy_note or "applies",
                "seconds": self.seconds, "rank_drops": [d.to_dict() for d in self.drops]}


class _Manifold:
    """The position constraints g(t₀, y) = 0 of a compiled module as functions of the
    configuration q = y[cols] (the other unknowns held at the initial state's values)."""

    def __init__(self, compiled, p, t0, y0):
        from phc.simulation.midpoint import Projector, constraint_rows

        mod = compiled.module
        self.mod, self.p, self.t0, self.y0 = mod, p, t0, np.array(y0, dtype=float)
        self.projector = Projector(mod, p, self.y0, t0)
        self.cols = self.projector.cols
        self.rows = constraint_rows(mod)
        self.labels = list(mod.INVARIANTS)
        if len(self.rows):
            self.jac_rows, self.jac_cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
            self.buf = np.zeros(len(self.jac_rows))
            self.zeros = np.zeros(mod.N)

    def state(self, q) -> np.ndarray:
        y = self.y0.copy()
        y[self.cols] = q
        return y

    def g(self, q) -> np.ndarray:
        return np.asarray(self.mod.invariants(self.t0, self.state(q), self.p), dtype=float)

    def G(self, q) -> np.ndarray:
        """∂g/∂q: the compiled Jacobian's rows of the invariants when they are rows of F (the
        GGL formulation), else finite differences (:meth:`Projector._jacobian`)."""
        y = self.state(q)
        if not len(self.rows):
            return self.projector._jacobian(self.t0, y, q, None)
        self.mod.jacobian(self.t0, y, self.zeros, self.p, 0.0, self.buf)
        full = np.zeros((len(self.mod.EQUATIONS), self.mod.N))
        full[self.jac_rows, self.jac_cols] = self.buf
        return full[np.ix_(self.rows, self.cols)]

    def project(self, q) -> Optional[np.ndarray]:
        """The point of the constraints the minimum-norm projection reaches from q, or None."""
        y = self.projector.project(self.t0, self.state(q))
        out = y[self.cols]
        g = self.g(out)
        if len(self.rows):  # Newton steps with the exact Jacobian to round-off (the projector's is
            for _ in range(4):  # a finite-difference one, good to ~1e-8 of the configuration)
                step = np.linalg.lstsq(self.G(out), g, rcond=None)[0]
                trial = out - step
                g_trial = self.g(trial)
                if not np.all(np.isfinite(g_trial)) or np.abs(g_trial).max() >= np.abs(g).max():
                    break
                out, g = trial, g_trial
        size = float(np.abs(self.G(out)).max(initial=0.0)) * (1.0 + float(np.abs(out).max(initial=0.0)))
        if not np.all(np.isfinite(out)) or float(np.abs(g).max(initial=0.0)) > PROJECTION_RTOL * max(size, 1.0):
            return None
        return out


def _scales(G0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column scales that equilibrate G at the start (one round of
    :func:`phc.simulation.equilibrate.equilibrate`, LAPACK's ``dgeequ``, as the singularity
    monitor scales its matrix; 1 for a zero row or column), kept fixed along the curve: a
    change of units of the constraints and the coordinates. Equilibrating at each point
    instead would rescale a row or a column that vanishes at a rank drop (a cusp of the
    curve) back to size one and hide it."""
    from phc.simulation.equilibrate import equilibrate

    _, r, c = equilibrate(G0, rounds=1)
    return r, c


def _conditioning(G: np.ndarray, full_rank: int, scales):
    """(σ_r/σ_max of G scaled by `scales` (:func:`_scales`) with r the rank at the start,
    rank, left singular vector of σ_r, right singular vectors)."""
    from phc.checks.certify import _rank

    E = (scales[0][:, None] * G) * scales[1][None, :]
    u, s, vh = np.linalg.svd(E, full_matrices=True)
    if not len(s) or s[0] <= 0:
        return 0.0, 0, u[:, 0] if u.size else u, vh
    k = min(full_rank, len(s)) - 1
    return float(s[k] / s[0]), _rank(s), u[:, k], vh


def _tangent(G: np.ndarray, full_rank: int, previous: np.ndarray) -> Optional[np.ndarray]:
    """The unit tangent of the constraints closest to `previous`: `previous` projected on the
    kernel of G (the last n − full_rank right singular vectors). None when it is (nearly)
    orthogonal to the kernel: the curve turns back (a cusp) or ends."""
    _, _, vh = np.linalg.svd(G, full_matrices=True)
    N = vh[full_rank:].T
    t = N @ (N.T @ previous)
    norm = float(np.linalg.norm(t))
    if norm < 0.5 * float(np.linalg.norm(previous)):
        return None
    return t / norm


def _same_configuration(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Equal up to whole turns: every coordinate differs by a multiple of 2π (to `tol`); an
    angle that went round once is the same configuration (the caller also compares g and
    its Jacobian, which a translation by 2π would change)."""
    d = a - b
    k = np.round(d / (2 * math.pi))
    return bool(np.abs(d - 2 * math.pi * k).max(initial=0.0) <= tol)


class _Energy:
    """T(q) = H₀ − V(q) when the model is a lossless one-degree-of-freedom mechanism, else
    the reason it is not (`note`)."""

    def __init__(self, compiled, man: _Manifold, full_rank: int):
        import sympy as sp

        mod, dae = compiled.module, compiled.dae
        self.note = ""
        self.mod, self.man = mod, man
        n_q = len(man.cols)
        diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
        roles = list(mod.ROLES)
        others = [j for j in np.flatnonzero(diff) if roles[j] != "energy" and j not in set(man.cols.tolist())]
        self.others = np.array([j for j in range(mod.N) if roles[j] != "energy" and j not in set(man.cols.tolist())],
                               dtype=int)
        t = sp.Symbol("t", real=True)
        y0 = man.y0
        if n_q - full_rank != 1:
            self.note = f"the constrained configurations have {n_q - full_rank} degrees of freedom, not 1"
        elif len(others) != n_q:
            self.note = (f"{len(others)} states besides the {n_q} constrained coordinates (a mechanism of rigid "
                         f"bodies alone has one momentum per coordinate): other energy stores take part")
        elif dae.dissipation_terms and any(term != 0 for _, term, _ in dae.dissipation_terms):
            self.note = "the model dissipates energy"
        elif isinstance(dae.port_power, sp.Basic) and dae.port_power != 0:
            self.note = "energy enters through ports or sources"
        elif t in dae.hamiltonian.free_symbols or any(t in getattr(e, "free_symbols", ()) for e in dae.invariants):
            self.note = "the energy or the constraints depend on time"
        if self.note:
            return
        self.H0 = float(mod.hamiltonian(man.t0, y0, man.p))
        # the kinetic part is a quadratic form of the momenta (and the velocities they determine)
        rest = self._H(y0, 0.0)
        t1, t2 = self.H0 - rest, self._H(y0, 2.0) - rest
        self.scale = max(abs(self.H0), abs(rest), float(mod.energy_scale(man.t0, y0, man.p)))
        if t1 < -ENERGY_RTOL * self.scale or abs(t2 - 4 * t1) > 1e-6 * max(self.scale, 1e-300):
            self.note = "the energy is not a kinetic energy quadratic in the momenta plus a potential"

    def _H(self, y, factor: float) -> float:
        z = y.copy()
        z[self.others] *= factor
        return float(self.mod.hamiltonian(self.man.t0, z, self.man.p))

    def kinetic(self, q) -> float:
        """H₀ − V(q): the kinetic energy the motion has at q."""
        return self.H0 - self._H(self.man.state(q), 0.0)


@dataclass
class _Point:
    s: float
    q: np.ndarray
    ratio: float
    T: Optional[float]


def survey(compiled, max_steps: int = MAX_STEPS, seconds: float = SECONDS) -> MotionSurvey:
    """Trace the constraints from the initial configuration and report each rank drop (see
    the module doc)."""
    from phc.errors import InconsistentInitialError, ModelEvaluationError, SimulationSetupError
    from phc.simulation import initial_values, parameter_vector, start_state
    from phc.simulation.guard import quiet_floating_point

    start = time.perf_counter()
    out = MotionSurvey()
    mod = compiled.module
    if not len(getattr(mod, "INVARIANTS", ())):
        out.skipped = "the model has no position constraints"
        return out
    if mod.N > 2000:
        out.skipped = f"{mod.N} unknowns (the survey is dense: up to 2000)"
        return out
    p = parameter_vector(mod, None)
    t0 = float(compiled.options.get("t_start", 0.0) or 0.0)
    try:
        values, fixed = initial_values(compiled, p)
        init = start_state(compiled, p, t0, values, fixed)
    except (InconsistentInitialError, SimulationSetupError, ModelEvaluationError, np.linalg.LinAlgError,
            ValueError, ArithmeticError) as err:
        out.skipped = f"no consistent initial state ({str(err)[:120]})"
        return out
    with quiet_floating_point():
        try:
            _trace(compiled, p, t0, init, out, max_steps, start + seconds)
        except (ModelEvaluationError, np.linalg.LinAlgError, ArithmeticError) as err:
            out.cut_short = f"stopped where the equations cannot be evaluated ({str(err)[:120]})"
    out.seconds = time.perf_counter() - start
    _report(compiled, out)
    return out


def _trace(compiled, p, t0, init, out: MotionSurvey, max_steps: int, deadline: float) -> None:
    man = _Manifold(compiled, p, t0, init.y0)
    names = [str(compiled.module.VARIABLES[j]) for j in man.cols]
    q0 = init.y0[man.cols].copy()
    G0 = man.G(q0)
    m, n = G0.shape
    full_rank = min(m, n)
    man.scales = _scales(G0)
    _, rank0, _, vh0 = _conditioning(G0, full_rank, man.scales)
    if rank0 < full_rank:
        out.skipped = (f"the initial configuration is itself singular (rank {rank0} of {full_rank}; the coupling "
                       "certificate names the connection)")
        return
    if n <= full_rank:
        out.skipped = "the position constraints fix the configuration (no degree of freedom to trace)"
        return
    energy = _Energy(compiled, man, full_rank)
    out.energy_note = energy.note
    kinetic = (lambda q: None) if energy.note else energy.kinetic
    size = max(1.0, float(np.abs(q0).max(initial=0.0)))
    # directions: the initial velocity's, then the kernel's basis, each way
    v = np.asarray(init.yp0, dtype=float)[man.cols]
    directions = []
    t_v = _tangent(G0, full_rank, v) if np.linalg.norm(v) > 0 else None
    if t_v is not None:
        directions += [t_v, -t_v]
    for k in range(full_rank, n):
        w = vh0[k]
        if t_v is not None and abs(float(w @ t_v)) > 0.99:
            continue
        directions += [w, -w]
    found: list[tuple[RankDrop, np.ndarray]] = []
    budget = max_steps
    curves = []
    for d_index, direction in enumerate(directions):
        if budget <= 0 or time.perf_counter() > deadline:
            out.cut_short = out.cut_short or "the step or time budget ran out before every direction was traced"
            break
        if d_index % 2 == 1 and curves and curves[-1][1] == "closed":
            continue  # the curve closed: the other way round is the same curve
        points, end, steps = _curve(man, full_rank, q0, direction, size, budget, deadline, kinetic)
        budget -= steps
        out.steps += steps
        out.length += points[-1].s
        out.closed = out.closed or end == "closed"
        if end in ("budget", "time"):
            out.cut_short = "the step or time budget ran out (the curve was traced in part)"
        curves.append((points, end))
        for drop, q in _drops(man, full_rank, points, end, names, kinetic, size, deadline):
            if any(_same_configuration(q, other, SAME * size) for _, other in found):
                continue
            found.append((drop, q))
    # the energy verdicts of a one-degree-of-freedom mechanism: reached when T > 0 on the way
    if not energy.note:
        _verdicts(curves, found, energy, size)
    out.drops = [d for d, _ in found]


def _curve(man, full_rank, q0, direction, size, budget, deadline, kinetic):
    """Continue from q0 along `direction`; (points, how it ended, steps)."""
    h = FIRST_STEP * size
    q, t = q0.copy(), direction / np.linalg.norm(direction)
    G0 = man.G(q)
    ratio, _, _, _ = _conditioning(G0, full_rank, man.scales)
    points = [_Point(0.0, q.copy(), ratio, kinetic(q))]
    steps = 0
    left_start = False
    while True:
        if steps >= budget:
            return points, "budget", steps
        if time.perf_counter() > deadline:
            return points, "time", steps
        if points[-1].s > MAX_LENGTH * size:
            return points, "length", steps
        steps += 1
        q_new = man.project(q + h * t)
        t_new = None
        if q_new is not None and np.linalg.norm(q_new - q) > 0.25 * h:
            t_new = _tangent(man.G(q_new), full_rank, t)
        if t_new is None or float(t_new @ t) < math.cos(MAX_TURN) or np.linalg.norm(q_new - q) > 2 * h:
            h *= 0.5
            if h < MIN_STEP * size:
                return points, "end", steps  # no step along the constraints from here
            continue
        ratio, _, _, _ = _conditioning(man.G(q_new), full_rank, man.scales)
        s = points[-1].s + float(np.linalg.norm(q_new - q))
        points.append(_Point(s, q_new.copy(), ratio, kinetic(q_new)))
        if float(t_new @ t) > math.cos(0.3 * MAX_TURN):
            h = min(1.5 * h, MAX_STEP * size)
        q, t = q_new, t_new
        distance = float(np.linalg.norm(q - q0))
        if distance > 2 * h:
            left_start = True
        elif left_start and distance < h:
            return points, "closed", steps
        if left_start and _same_configuration(q, q0, h) and _periodic(man, q, q0, G0):
            return points, "closed", steps  # back where it started, up to whole turns of its angles


def _periodic(man, q, q0, G0) -> bool:
    """Whether q0 moved by the whole turns nearest to q − q0 is the same configuration: on the
    constraints, with the same Jacobian (a coordinate that is not an angle changes them)."""
    k = np.round((q - q0) / (2 * math.pi))
    if not k.any():
        return False
    shifted = q0 + 2 * math.pi * k
    G = man.G(shifted)
    scale = float(np.abs(G0).max(initial=0.0)) or 1.0
    return bool(np.abs(man.g(shifted)).max(initial=0.0) <= 1e-12 * scale * (1.0 + float(np.abs(q0).max()))
                and np.abs(G - G0).max(initial=0.0) <= 1e-12 * scale)


def _drops(man, full_rank, points, end, names, kinetic, size, deadline=math.inf):
    """The rank drops at the local minima of the conditioning along `points`."""
    from scipy.optimize import minimize_scalar

    ratios = [pt.ratio for pt in points]
    candidates = [k for k in range(1, len(points) - 1) if ratios[k] <= ratios[k - 1] and ratios[k] < ratios[k + 1]]
    if end == "end" and ratios[-1] < WARN_RTOL:
        # the curve ends (no step down to MIN_STEP is accepted) where G becomes singular: a cusp
        # or an end of the constraints' smooth part, which no continuation passes; located to the
        # last step only
        q = points[-1].q
        ratio, _, _, _ = _conditioning(man.G(q), full_rank, man.scales)
        rank, rows = _lost(man, q, full_rank)
        drop = RankDrop({name: float(x) for name, x in zip(names, q)}, ratio, rank, full_rank,
                        rows, [], "undecided", kinetic(q))
        drop._s, drop._ends, drop._points = points[-1].s, True, points
        yield drop, q
        candidates = [k for k in candidates if points[-1].s - points[k].s > 1e-3 * size]
    for k in candidates:
        if time.perf_counter() > deadline + SECONDS:  # locating is bounded too (twice the box at most)
            return
        a, b = points[max(k - 1, 0)].q, points[min(k + 1, len(points) - 1)].q

        def at(x):
            return man.project(a + x * (b - a))

        def f(x):
            q = at(x)
            return 1.0 if q is None else _conditioning(man.G(q), full_rank, man.scales)[0]

        # golden section to round-off: near a rank drop σ_min falls like the distance to it (a V,
        # which Brent's parabolas do not speed up), and the rank test needs it within round-off
        try:
            best = minimize_scalar(f, bracket=(0.0, 0.5, 1.0), method="golden",
                                   options={"xtol": 4 * np.finfo(float).eps, "maxiter": 200})
        except ValueError:  # the chord's midpoint is not below both ends: search it all
            best = minimize_scalar(f, bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-14})
        x = float(best.x)
        q = at(x)
        if q is None:
            continue
        ratio, rank, u, _ = _conditioning(man.G(q), full_rank, man.scales)
        if ratio >= WARN_RTOL or not (ratio < RANK_RTOL or _falls_linearly(f, x)):
            continue  # a smooth minimum, not a rank drop
        rank, rows = _lost(man, q, full_rank)
        drop = RankDrop({name: float(x) for name, x in zip(names, q)}, ratio, rank, full_rank, rows, [],
                        "undecided", kinetic(q))
        drop._s = points[k].s  # where on its curve (the energy verdict)
        drop._ends = False  # the curve went on through it
        drop._points = points
        yield drop, q


def _lost(man, q, full_rank) -> tuple[int, list[str]]:
    """(rank, the rows that become dependent) at a located rank drop: the singular values of
    the scaled G below :data:`LOST` of the largest are lost (at least one), and the rows are
    the large entries (above 0.1) of their left singular vectors. Where several branches
    cross (the N four-bar loses one rank per loop at once) the configuration is located to
    about √ε, so the lost singular values are up to ~1e-6, not round-off."""
    E = (man.scales[0][:, None] * man.G(q)) * man.scales[1][None, :]
    u, s, _ = np.linalg.svd(E, full_matrices=True)
    s = s[:full_rank]
    lost = [k for k in range(len(s)) if s[k] < LOST * s[0]] or [len(s) - 1]
    weight = np.abs(u[:, lost]).max(axis=1)
    rows = [man.labels[i] for i in np.argsort(-weight) if weight[i] > 0.1]
    return full_rank - len(lost), rows


def _falls_linearly(f, x) -> bool:
    """Whether the conditioning falls to zero like the distance to `x` on both sides (at
    1e-3 and 1e-4 of the bracket from it: ten times less, to a factor 2), as σ_min does at a
    rank drop. A configuration where the branches of the constraints cross can be located
    only to about √ε of its size (Newton's residual ε divided by σ_min), so the conditioning
    found there stays near 1e-8, above the rank threshold; its linear fall shows the rank
    drop. A smooth minimum above zero flattens instead (ratio near 1)."""
    for side in (1.0, -1.0):
        far, near = f(x + side * 1e-3), f(x + side * 1e-4)
        if not (far > 0 and 0.05 < near / far < 0.2):
            return False
    return True


def _verdicts(curves, found, energy, size) -> None:
    """Reached: T > 0 on the curve from the start to it (the motion turns back where T
    reaches 0, and then goes the other way)."""
    floor = ENERGY_RTOL * energy.scale
    for drop, _ in found:
        points = drop._points
        on_way = [pt.T for pt in points if pt.s < drop._s]
        T = drop.kinetic_energy
        reached = all(x is not None and x > floor for x in on_way[1:]) and T is not None and T > floor
        if not reached and len(on_way) > 1:
            # on a closed curve the motion may come the other way round
            closed = next((end for pts, end in curves if pts is points), None) == "closed"
            if closed:
                beyond = [pt.T for pt in points if pt.s > drop._s]
                reached = all(x > floor for x in beyond) and T is not None and T > floor
        if not reached:
            drop.verdict = "not reached"
            drop.why = (f"the motion does not reach it: on the way the potential energy exceeds the initial energy "
                        f"H₀ = {energy.H0:.6g}" if T is None or T > floor else
                        f"the motion does not reach it: the kinetic energy there would be {T:.4g} ≤ 0")
        elif drop._ends:
            drop.verdict = "cannot continue"
            drop.why = (f"the motion reaches it with kinetic energy T = H₀ − V = {T:.6g} and cannot continue: the constrained "
                        "configurations end or turn back there")
        else:
            drop.verdict = "passes"
            drop.why = (f"the motion passes it: it arrives with kinetic energy T = H₀ − V = {T:.6g} and the constraints continue "
                        "through it (the constraint forces lose a direction for an instant, the motion does not)")


def _report(compiled, out: MotionSurvey) -> None:
    from phc.simulation.monitor import describe_equations

    names = describe_equations(compiled)
    spans = {c.label: c.span for c in compiled.description.connections}
    components = {name: span for name, _, span in compiled.dae.topology.components}
    for drop in out.drops:
        for attr in ("_s", "_ends", "_points"):
            drop.__dict__.pop(attr, None)
        where = []
        for row in drop.rows:
            label = row.rsplit(".", 1)[0]
            if row in names:  # a connection's row
                head = names[row].split(" row ")[0]
            else:  # a rigid component's own constraint, `body.constraints[0]`
                owner = next((c for c in sorted(components, key=len, reverse=True) if row.startswith(c + ".")), None)
                head, label = (f"the constraints of `{owner}`", owner) if owner else (f"row `{row}`", row)
            if head not in where:
                where.append(head)
            if drop.span is None:
                drop.span, drop.path = spans.get(label, components.get(label)), label
        drop.connections = where
        # located to about √ε of the configuration's size where branches cross: smaller is 0
        size = max([1.0] + [abs(v) for v in drop.configuration.values()])
        config = ", ".join(f"{k} = {0.0 if abs(v) < 1e-7 * size else v:.6g}" for k, v in drop.configuration.items())
        if not drop.why:
            drop.why = ("whether the motion reaches and passes it is not decided here ("
                        + out.energy_note + "); `phc simulate` with a fixed-step solver reports each rank drop it "
                        "passes and stops where the motion cannot continue")
        out.diagnostics.append(Diagnostic(
            "PHC-W422",
            f"the position constraints lose rank along the motion at {config} (rank {drop.rank} of "
            f"{drop.full_rank}, σ_min/σ_max {drop.ratio:.1e}): the rows "
            f"{', '.join(f'`{r}`' for r in drop.rows)} become dependent"
            + (f" ({', '.join(where)})" if where else "") + f"; {drop.why}",
            span=drop.span, path=drop.path, severity="warning",
            hint=("the fixed-step solvers (midpoint, discrete_gradient, midpoint4) pass such a configuration and "
                  "report each passage; see docs/hard-cases.md" if drop.verdict == "passes" else
                  "a configuration where the motion cannot continue needs another model of the joint "
                  "(a compliance, or constraints that stay independent)" if drop.verdict == "cannot continue" else
                  "no action needed unless the motion is meant to reach it")))


__all__ = ["MotionSurvey", "RankDrop", "survey"]
