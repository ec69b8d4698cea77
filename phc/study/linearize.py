"""Linearization about a consistent point (`phc linearize`): the descriptor system, its
finite eigenvalues with natural frequencies and damping ratios, and the mode shapes of
distributed components.

A compiled model is the DAE ``F(t, y, ẏ, p) = 0`` (:mod:`phc.ir.dae`). About a consistent
point ``(y₀, ẏ₀)`` at time ``t₀`` small perturbations obey the descriptor system

    E δẏ = A δy + B δu,        δz = C δy + D δu

with ``E = ∂F/∂ẏ`` and ``A = −∂F/∂y`` (the generated module's analytic Jacobian
``∂F/∂y + cj·∂F/∂ẏ`` evaluated at ``cj = 0`` and ``cj = 1``), ``B = −∂F/∂u``, and
``C = ∂g/∂y``, ``D = ∂g/∂u`` for the model's outputs ``g`` (central differences: the
outputs are small expressions; ``B`` and ``D`` are exact for inputs that enter affinely,
as a port-Hamiltonian system's inputs do).

What is what:

* **variables** ``y``: every DAE variable (states, efforts, multipliers, ...) except the
  energy accumulator ``energy.supplied``, whose row (the energy balance) is left out too;
* **inputs** ``u``: an additive perturbation of the value of every top-level
  ``effort_source`` and ``flow_source`` (one per entry of a vector source; a flow source
  with a ``position`` is a prescribed motion, not an input) and of the effort or flow of
  every exposed port of the top-level model (its ``simulation.inputs`` entry, or the zero
  effort of a free port; a port driven by a CSV table is left out). Sources inside nested
  model files are part of the plant. A feedback source stays in the loop: its input is
  added to what the controller computes;
* **outputs** ``z``: the model's ``simulation.outputs`` (a scene's ``outputs``). When an
  output uses rates ``ẏ`` the report carries ``C_rate = ∂g/∂ẏ`` as well.

The point is the model's initial state made consistent by phc's consistent
initialization (:func:`phc.simulation.initial_values`, ``start_state``), with ``state``
overriding initial values, or the state a simulation reaches at time ``at``. Nothing
requires an equilibrium; the report says whether the rates vanish there (then the
eigenvalues describe small oscillations about it; otherwise the frozen system at that
instant).

The finite eigenvalues of the pencil, ``det(λE − A) = 0``, are computed on its deflating
subspace of finite eigenvalues, the limit of the Wong sequence ``V₀ = ℝⁿ``,
``V_{i+1} = A⁻¹(E V_i)`` (rank decisions by SVD of the equilibrated pencil): with ``W`` an
orthonormal basis of ``E V``, the pencil restricted to it, ``(Wᵀ A V, Wᵀ E V)``, has exactly
the finite eigenvalues and an invertible ``Wᵀ E V``. The infinite eigenvalues (the
algebraic part: constraints, multipliers, co-energy variables) are thus discarded by rank
decisions on the equations' structure, never by a threshold on |λ| — the near-infinite
eigenvalues an index-2 pencil shows under rounding (|λ| ~ 1/√ε) cannot pass for modes.
Each eigenvalue λ gives the natural frequency ``ω_n = |λ|``, the damping ratio
``ζ = −Re λ / |λ|`` and the damped frequency ``|Im λ|``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np
import scipy.linalg as sla

from phc.errors import ModelError, SimulationSetupError
from phc.inert import inert
from phc.frontend.scene import Scene, is_scene_file, load_scene, scene_variant

ENERGY = "energy.supplied"
RANK_TOL = 1e-10
"""Relative tolerance of the rank decisions (singular values of the equilibrated pencil)."""
DENSE_LIMIT = 6000
"""Largest number of variables linearized (dense eigenvalue problem, O(n³))."""
_FIELD = re.compile(r"^(?P<comp>.+)\.(?P<field>[A-Za-z_][A-Za-z0-9_]*)\[(?P<i>\d+)\]$")


@dataclass(frozen=True)
class Input:
    """One input: an additive perturbation of a source's value or an exposed port's effort or flow."""

    name: str
    """``supply`` (or ``supply[k]`` of a vector source), or the exposed port's name."""
    kind: str
    """``effort`` or ``flow``."""
    origin: str
    """What it perturbs, e.g. "effort_source `supply`" or "exposed port `drive`"."""
    parameter: str = field(default="", repr=False)


@dataclass
class Mode:
    """One finite eigenvalue (of a complex pair, the one with Im λ > 0) and its eigenvector."""

    eigenvalue: complex
    vector: np.ndarray
    """Eigenvector over `Linearization.variables` (complex, largest state entry 1)."""
    shapes: dict = field(default_factory=dict)
    """Distributed components: name -> {"xi_over_L": nodes, "deflection": real shape}
    (the transverse velocity field ``e_p`` divided by λ, normalized to max |w| = 1)."""

    @property
    def natural_frequency(self) -> float:
        """ω_n = |λ| [rad/s]."""
        return float(abs(self.eigenvalue))

    @property
    def frequency_hz(self) -> float:
        return self.natural_frequency / (2 * math.pi)

    @property
    def damped_frequency(self) -> float:
        """|Im λ| [rad/s]."""
        return float(abs(self.eigenvalue.imag))

    @property
    def damping_ratio(self) -> float:
        """ζ = −Re λ / |λ| (NaN for λ = 0)."""
        w = self.natural_frequency
        return float(-self.eigenvalue.real / w) + 0.0 if w > 0 else math.nan


@dataclass
class Linearization:
    """The descriptor system ``E δẏ = A δy + B δu``, ``δz = C δy + D δu`` about a point,
    and its finite spectrum. See the module docstring."""

    model: str
    t: float
    point: str
    """How the point was chosen (the model's initial state, given states, a simulated time)."""
    variables: tuple[str, ...]
    differential: np.ndarray
    inputs: tuple[Input, ...]
    outputs: tuple[str, ...]
    E: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    y: np.ndarray
    """The point: values of `variables`."""
    yp: np.ndarray
    """Their rates at the point."""
    eigenvalues: np.ndarray
    """All finite eigenvalues (complex), by natural frequency."""
    modes: list[Mode]
    n_infinite: int
    C_rate: Optional[np.ndarray] = None
    """``∂g/∂ẏ`` when some output uses rates (else None): ``δz = C δy + C_rate δẏ + D δu``."""
    singular: bool = False
    """The pencil is singular (det(λE − A) ≡ 0: the linearized equations leave a direction
    undetermined); the eigenvalues are then those of its regular part, found by threshold."""
    notes: list[str] = field(default_factory=list)

    @property
    def n_states(self) -> int:
        return int(np.count_nonzero(self.differential))

    @property
    def max_rate(self) -> tuple[float, str]:
        """Largest |ẏ| of a state at the point and the state's name (an equilibrium: 0)."""
        rates = np.abs(self.yp) * self.differential
        if not len(rates):
            return 0.0, ""
        k = int(np.argmax(rates))
        return float(rates[k]), self.variables[k]

    def is_equilibrium(self, tol: float = 1e-9) -> bool:
        rate, _ = self.max_rate
        scale = max(1.0, float(np.abs(self.y).max(initial=0.0)))
        return rate <= tol * scale

    # -- reports -------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Everything as JSON-ready values (complex numbers as [re, im], NaN as None)."""
        states = [j for j, d in enumerate(self.differential) if d]

        def num(x):
            return None if not math.isfinite(x) else float(x)

        def mode(m: Mode) -> dict:
            return {
                "eigenvalue": [float(m.eigenvalue.real), float(m.eigenvalue.imag)],
                "natural_frequency": m.natural_frequency, "frequency_hz": m.frequency_hz,
                "damped_frequency": m.damped_frequency, "damping_ratio": num(m.damping_ratio),
                "states": {self.variables[j]: [float(m.vector[j].real), float(m.vector[j].imag)] for j in states},
                "shapes": {c: {k: np.asarray(v).tolist() for k, v in s.items()} for c, s in m.shapes.items()},
            }

        rate, where = self.max_rate
        out = {
            "model": self.model, "t": self.t, "point": self.point,
            "equilibrium": self.is_equilibrium(), "max_rate": rate, "max_rate_variable": where or None,
            "variables": list(self.variables), "differential": [bool(d) for d in self.differential],
            "inputs": [{"name": u.name, "kind": u.kind, "origin": u.origin} for u in self.inputs],
            "outputs": list(self.outputs),
            "E": self.E.tolist(), "A": self.A.tolist(), "B": self.B.tolist(), "C": self.C.tolist(),
            "D": self.D.tolist(), "C_rate": None if self.C_rate is None else self.C_rate.tolist(),
            "y": self.y.tolist(), "yp": self.yp.tolist(),
            "n_finite": int(len(self.eigenvalues)), "n_infinite": int(self.n_infinite),
            "singular": bool(self.singular),
            "eigenvalues": [[float(z.real), float(z.imag)] for z in self.eigenvalues],
            "modes": [mode(m) for m in self.modes],
            "notes": list(self.notes),
        }
        return out

    def save_npz(self, path: str | os.PathLike) -> None:
        """Arrays E, A, B, C, D (and C_rate), y, yp, eigenvalues, the mode vectors (columns
        of `modes`), natural_frequency, damping_ratio and the names."""
        arrays: dict[str, Any] = dict(
            E=self.E, A=self.A, B=self.B, C=self.C, D=self.D, y=self.y, yp=self.yp, t=np.array(self.t),
            eigenvalues=self.eigenvalues,
            modes=np.array([m.vector for m in self.modes]).T if self.modes else np.zeros((len(self.variables), 0)),
            mode_eigenvalues=np.array([m.eigenvalue for m in self.modes], dtype=complex),
            natural_frequency=np.array([m.natural_frequency for m in self.modes]),
            damping_ratio=np.array([m.damping_ratio for m in self.modes]),
            variables=np.array(self.variables, dtype=str), differential=np.asarray(self.differential, dtype=bool),
            inputs=np.array([u.name for u in self.inputs], dtype=str),
            outputs=np.array(self.outputs, dtype=str), n_infinite=np.array(self.n_infinite))
        if self.C_rate is not None:
            arrays["C_rate"] = self.C_rate
        for k, m in enumerate(self.modes):
            for comp, shape in m.shapes.items():
                arrays[f"shape_{k}_{comp}"] = np.asarray(shape["deflection"])
                arrays[f"shape_{k}_{comp}_xi"] = np.asarray(shape["xi_over_L"])
        np.savez(path, **arrays)

    def render_text(self, max_modes: int = 20) -> str:
        rate, where = self.max_rate
        lines = [f"{self.model}: linearized at t = {self.t:.6g} ({self.point})"]
        if self.is_equilibrium():
            lines.append("  point    an equilibrium (the rates of the states vanish)")
        else:
            lines.append(f"  point    not an equilibrium: `{where}` changes at {rate:.6g}/s; the eigenvalues are "
                         "those of the system frozen at this instant")
        lines.append(f"  system   E x' = A x + B u, y = C x + D u: {len(self.variables)} variables "
                     f"({self.n_states} states), {len(self.inputs)} input{'s' * (len(self.inputs) != 1)}, "
                     f"{len(self.outputs)} output{'s' * (len(self.outputs) != 1)}")
        for u in self.inputs:
            lines.append(f"  input    {u.name}: {u.kind} of {u.origin}")
        if self.outputs:
            lines.append(f"  outputs  {', '.join(self.outputs)}" + (" (some use rates: C_rate)" if self.C_rate is not None
                                                                     else ""))
        pairs = sum(1 for m in self.modes if m.eigenvalue.imag > 0)
        lines.append(f"  spectrum {len(self.eigenvalues)} finite eigenvalue{'s' * (len(self.eigenvalues) != 1)} "
                     f"({pairs} oscillating pair{'s' * (pairs != 1)}, {len(self.modes) - pairs} real), "
                     f"{self.n_infinite} infinite" + (" (singular pencil)" if self.singular else ""))
        if self.modes:
            lines.append(f"  {'mode':>6}  {'eigenvalue':<32}{'ω_n [rad/s]':>14}{'f [Hz]':>14}{'ζ':>12}")
            for k, m in enumerate(self.modes[:max_modes], 1):
                z = m.eigenvalue
                # a real part below 1e-10 |λ| is rounding (an undamped mode): shown as 0
                re_part = 0.0 if abs(z.real) <= 1e-10 * abs(z) else z.real
                ev = f"{re_part:.6g} ± {abs(z.imag):.6g}i" if z.imag > 0 else f"{re_part:.6g}"
                zeta = ("-" if math.isnan(m.damping_ratio) else "0" if abs(m.damping_ratio) <= 1e-10
                        else f"{m.damping_ratio:.4g}")
                lines.append(f"  {k:>6}  {ev:<32}{m.natural_frequency:>14.6g}{m.frequency_hz:>14.6g}{zeta:>12}")
            if len(self.modes) > max_modes:
                lines.append(f"  ... {len(self.modes) - max_modes} more (--modes N lists more; --format json "
                             "or npz has all)")
        for note in self.notes:
            lines.append(f"  note     {note}")
        return "\n".join(inert(line) for line in lines)  # the model's and its parts' names (phc.inert)


# -- inputs: a scene that adds a perturbation parameter to each source and exposed port ---
@dataclass
class _InputScene(Scene):
    """A scene (or a plain model wrapped as one) that also adds, to the value of every
    top-level source and to every exposed port's effort or flow, a parameter (default 0):
    the inputs of the linearization. Nothing is written to disk."""

    port_dimensions: dict = field(default_factory=dict)
    inputs: list = field(default_factory=list)

    def apply(self, files, spec, smap):
        applied = super().apply(files, spec, smap)
        spec = applied.spec
        taken = set(spec.parameters) | set(spec.components)
        self.inputs = []

        def parameter() -> str:
            k = len(self.inputs)
            name = f"linearize_u{k}"
            while name in taken:
                name += "_"
            taken.add(name)
            return name

        def perturbed(value, names):
            return [f"({v}) + {u}" for v, u in zip(value, names)]

        components = dict(spec.components)
        for cname, comp in spec.components.items():
            kind = {"effort_source": "effort", "flow_source": "flow"}.get(comp.type)
            if kind is None or cname in applied.skip:
                continue
            if kind == "flow" and getattr(comp, "position", None) is not None:
                continue  # a prescribed motion (its position integrates the value)
            values = comp.value if isinstance(comp.value, list) else [comp.value]
            names = []
            for k in range(len(values)):
                names.append(parameter())
                label = cname if len(values) == 1 else f"{cname}[{k}]"
                self.inputs.append(Input(label, kind, f"{comp.type} `{cname}`", names[-1]))
            new = perturbed(values, names)
            components[cname] = comp.model_copy(update={"value": new if isinstance(comp.value, list) else new[0]})
        sim = spec.simulation
        inputs = dict(sim.inputs)
        for pname in spec.ports:
            given = inputs.get(pname)
            if given is None:
                dim = self.port_dimensions.get(pname)
                if dim is None:
                    continue
                kind, signals, as_list = "effort", [0] * dim, dim > 1
            else:
                kind = "effort" if given.effort is not None else "flow"
                signal = getattr(given, kind)
                as_list = isinstance(signal, list) and not (signal and hasattr(signal[0], "until"))
                signals = signal if as_list else [signal]
            names, new = [], []
            for k, sig in enumerate(signals):
                if hasattr(sig, "file"):  # a CSV table: not perturbed
                    new.append(sig)
                    continue
                names.append(parameter())
                label = pname if len(signals) == 1 else f"{pname}[{k}]"
                self.inputs.append(Input(label, kind, f"exposed port `{pname}`", names[-1]))
                if isinstance(sig, list):  # pieces
                    new.append([piece.model_copy(update={"value": f"({piece.value}) + {names[-1]}"}) for piece in sig])
                else:
                    new.append(f"({sig}) + {names[-1]}")
            inputs[pname] = type(given if given is not None else _input_spec()).model_validate(
                {kind: new if as_list else new[0]})
        parameters = dict(spec.parameters)
        for u in self.inputs:
            parameters[u.parameter] = 0.0
        new_sim = sim.model_copy(update={"inputs": inputs})
        spec = spec.model_copy(update={"components": components, "parameters": parameters, "simulation": new_sim})
        return dataclasses.replace(applied, spec=spec)


def _input_spec():
    from phc.spec.model import InputSpec

    return InputSpec(effort=0)


def _exposed_dimensions(scene: Scene) -> dict[str, int]:
    """Dimensions of the top-level model's exposed ports without an input (from the
    elaborate and interconnect passes; empty when the model has errors, which the
    compilation then reports)."""
    from phc.frontend.elaborate import elaborate
    from phc.spec.load import load_spec

    spec, _, _ = load_spec(scene.model_path)
    if spec is None:
        return {}
    free = [p for p in spec.ports if p not in spec.simulation.inputs and p not in scene.spec.inputs]
    if not free:
        return {}
    elab, _ = elaborate(scene.model_path, scene)
    if elab is None:
        return {}
    out = {}
    for pname in free:
        port = elab.ports.get(elab.resolve_alias(spec.ports[pname].port))
        if port is not None:
            out[pname] = port.dimension
    return out


def compile_with_inputs(path, params: Optional[dict], mesh: Optional[dict], certify: bool,
                        backend: Optional[str]):
    """The model or scene file compiled with an input parameter (default 0) added to every
    top-level source's value and exposed port's effort or flow (:class:`_InputScene`), and
    those inputs (:class:`Input`, in parameter order): the inputs of the linearization and of an
    exported FMU (:mod:`phc.export.fmu`). Raises :class:`~phc.errors.ModelError` with the model's
    own diagnostics, located as written."""
    from phc.pipeline import compile_model

    if is_scene_file(path):
        base, diags = load_scene(path)
        if base is None:
            raise ModelError(diags)
    else:
        base = Path(path)
    variant = scene_variant(base, parameters=params or None, mesh=mesh or None)
    scene = _InputScene(variant.path, variant.spec, variant.smap)
    try:
        scene.port_dimensions = _exposed_dimensions(scene)
        compiled = compile_model(scene.model_path, scene=scene, certify=certify, backend=backend)
    except ModelError:
        # Report the model's own mistakes located as written (the inputs shift columns).
        compile_model(path, certify=certify, backend=backend)
        raise
    return compiled, scene.inputs


# -- the linearization ----------------------------------------------------------------------
def linearize_model(path: str | os.PathLike, *, at: Optional[float] = None, state: Optional[dict] = None,
              params: Optional[dict] = None, mesh: Optional[dict] = None, certify: bool = True,
              backend: Optional[str] = "numpy") -> Linearization:
    """Linearize a model (or scene) file about a consistent point.

    Parameters
    ----------
    path : path
        A model file or a scene file.
    at : float, optional
        Linearize at this time of the simulated motion (from the initial state); default:
        at the start time, about the initial state.
    state : dict, optional
        Initial values by state name (fixed), over the model's; the rest is found by
        consistent initialization.
    params : dict, optional
        Parameter values by name (compiled in).
    mesh : dict, optional
        Element counts of distributed components by name (as a scene's ``accuracy.mesh``).
    certify, backend
        As for :func:`phc.compile_model` (the numpy module by default: a linearization
        evaluates the functions a few times only).

    Returns
    -------
    Linearization

    Raises
    ------
    ModelError
        When the model has errors.
    InconsistentInitialError
        When the given states violate the equations.
    SimulationSetupError
        Unknown state names, a time before the start, a failed simulation to `at`, a model
        too large for a dense eigenvalue problem.
    """
    from phc.simulation import initial_values, parameter_vector, simulate, start_state
    from phc.simulation.guard import guard, quiet_floating_point
    from phc.simulation.initial import consistent_initial_conditions

    compiled, inputs = compile_with_inputs(path, params, mesh, certify, backend)
    mod = guard(compiled.module, compiled.source)
    n = mod.N
    if n - 1 > DENSE_LIMIT:
        raise SimulationSetupError(f"the model has {n - 1} variables; `phc linearize` solves a dense eigenvalue "
                                   f"problem and stops at {DENSE_LIMIT} (use a coarser mesh or `modes:`)")
    p = parameter_vector(mod)
    t0 = float(compiled.options["t_start"])
    values, fixed = initial_values(compiled, p, state)
    given = "" if not state else " with " + ", ".join(f"{k} = {float(v):g}" for k, v in state.items())
    with quiet_floating_point():
        init = start_state(compiled, p, t0, values, fixed, mod)
        y, yp, t = init.y0, init.yp0, t0
        point = "the model's initial state" + given + ", made consistent"
        if at is not None and float(at) != t0:
            at = float(at)
            if not math.isfinite(at) or at < t0:
                raise SimulationSetupError(f"--at must be a finite time from the start time {t0:g} on, got {at:g}")
            run = simulate(compiled, t_end=at, n_out=2, initial=state)
            if not run.success:
                raise SimulationSetupError(f"the simulation to t = {at:g} failed: {run.message}")
            dif = set(np.flatnonzero(np.asarray(mod.DIFFERENTIAL)).tolist())
            again = consistent_initial_conditions(mod, p, at, dict(enumerate(run.y[-1])), dif,
                                                  initial_relations=False)
            y, yp, t = again.y0, again.yp0, at
            point = f"the simulated state at t = {at:g}" + (" from" + given if given else "")
        jy, jyp = dense_jacobians(mod, t, y, yp, p)
        fu = _parameter_derivative(mod, t, y, yp, p, [mod.PARAMETERS.index(u.parameter) for u in inputs])
        gy, gyp, gu = _output_derivatives(mod, t, y, yp, p, [mod.PARAMETERS.index(u.parameter) for u in inputs])

    roles = list(mod.ROLES)
    energy = [j for j, r in enumerate(roles) if r == "energy"]
    rows = np.ones(len(mod.EQUATIONS), dtype=bool)
    cols = np.ones(n, dtype=bool)
    for j in energy:  # the energy accumulator and its balance row
        used = np.flatnonzero((jy[:, j] != 0) | (jyp[:, j] != 0))
        if len(used) == 1 and np.count_nonzero(jyp[used[0]]) == 1:
            rows[used[0]] = False
            cols[j] = False
    E, A = jyp[np.ix_(rows, cols)], -jy[np.ix_(rows, cols)]
    B = -fu[rows]
    C, D = gy[:, cols], gu
    C_rate = gyp[:, cols] if np.any(gyp[:, cols] != 0) else None
    names = tuple(v for v, keep in zip(mod.VARIABLES, cols) if keep)
    differential = np.asarray(mod.DIFFERENTIAL, dtype=bool)[cols]
    lam, vectors, n_inf, singular = finite_eigenvalues(A, E)
    modes = _modes(lam, vectors, names, differential, compiled.dae.meshes)
    lin = Linearization(compiled.description.model, t, point, names, differential, tuple(inputs), tuple(mod.OUTPUTS),
                        E, A, B, C, D, y[cols], yp[cols], lam, modes, n_inf, C_rate, singular)
    if singular:
        lin.notes.append("the pencil (A, E) is singular: the linearized equations leave a direction undetermined")
    return lin


def dense_jacobians(mod, t, y, yp, p) -> tuple[np.ndarray, np.ndarray]:
    """Dense ∂F/∂y and ∂F/∂ẏ from the module's Jacobian at cj = 0 and cj = 1."""
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    buf = np.zeros(len(rows))
    mod.jacobian(t, y, yp, p, 0.0, buf)
    d0 = buf.copy()
    mod.jacobian(t, y, yp, p, 1.0, buf)
    shape = (len(mod.EQUATIONS), mod.N)
    jy, jyp = np.zeros(shape), np.zeros(shape)
    np.add.at(jy, (rows, cols), d0)
    np.add.at(jyp, (rows, cols), buf - d0)
    return jy, jyp


def _step(x: float) -> float:
    return 1e-6 * max(1.0, abs(x))


def _parameter_derivative(mod, t, y, yp, p, which) -> np.ndarray:
    """∂F/∂p_k for the parameters `which`, by central differences."""
    out = np.zeros((len(mod.EQUATIONS), len(which)))
    f1, f2 = np.zeros(len(mod.EQUATIONS)), np.zeros(len(mod.EQUATIONS))
    for c, k in enumerate(which):
        h = _step(p[k])
        pp, pm = p.copy(), p.copy()
        pp[k] += h
        pm[k] -= h
        mod.residual(t, y, yp, pp, f1)
        mod.residual(t, y, yp, pm, f2)
        out[:, c] = (f1 - f2) / (2 * h)
    return out


def _output_derivatives(mod, t, y, yp, p, which) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """∂g/∂y, ∂g/∂ẏ and ∂g/∂u of the outputs by central differences."""
    m = len(mod.OUTPUTS)
    gy, gyp, gu = np.zeros((m, mod.N)), np.zeros((m, mod.N)), np.zeros((m, len(which)))
    if not m:
        return gy, gyp, gu
    for j in range(mod.N):
        h = _step(y[j])
        a, b = y.copy(), y.copy()
        a[j] += h
        b[j] -= h
        gy[:, j] = (np.asarray(mod.outputs(t, a, yp, p)) - np.asarray(mod.outputs(t, b, yp, p))) / (2 * h)
        h = _step(yp[j])
        a, b = yp.copy(), yp.copy()
        a[j] += h
        b[j] -= h
        gyp[:, j] = (np.asarray(mod.outputs(t, y, a, p)) - np.asarray(mod.outputs(t, y, b, p))) / (2 * h)
    for c, k in enumerate(which):
        h = _step(p[k])
        a, b = p.copy(), p.copy()
        a[k] += h
        b[k] -= h
        gu[:, c] = (np.asarray(mod.outputs(t, y, yp, a)) - np.asarray(mod.outputs(t, y, yp, b))) / (2 * h)
    # round-off of a difference of equal values is noise, not a dependence
    for g in (gy, gyp, gu):
        g[np.abs(g) < 1e-12 * max(1.0, float(np.abs(g).max(initial=0.0)))] = 0.0
    return gy, gyp, gu


# -- the finite spectrum -------------------------------------------------------------------
def _equilibrate(A: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column scalings (powers of 2) that bring the largest entry of every row and
    column of [A E] near 1 (four rounds of :func:`phc.simulation.equilibrate.equilibrate`
    on ``max(|A|, |E|)``): rank decisions then compare like with like."""
    from phc.simulation.equilibrate import equilibrate

    _, r, c = equilibrate(np.maximum(np.abs(A), np.abs(E)), rounds=4, power_of_two=True)
    return r, c


def _orth(M: np.ndarray, tol: float) -> np.ndarray:
    if M.shape[1] == 0:
        return M
    U, s, _ = sla.svd(M, full_matrices=False)
    return U[:, :int(np.count_nonzero(s > tol))]


def _null(M: np.ndarray, tol: float) -> np.ndarray:
    _, s, Vt = sla.svd(M)
    rank = int(np.count_nonzero(s > tol))
    return Vt[rank:].conj().T


def finite_eigenvalues(A: np.ndarray, E: np.ndarray, rtol: float = RANK_TOL
                       ) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """Finite eigenvalues λ of the square pencil ``det(λE − A) = 0`` and their
    eigenvectors (columns), on the deflating subspace of the Wong sequence (module
    docstring). Returns ``(λ, vectors, number of infinite eigenvalues, singular)``."""
    n = A.shape[0]
    if n == 0:
        return np.zeros(0, dtype=complex), np.zeros((0, 0), dtype=complex), 0, False
    r, c = _equilibrate(A, E)
    As, Es = A * r[:, None] * c[None, :], E * r[:, None] * c[None, :]
    tol = rtol * max(sla.norm(As, 2), sla.norm(Es, 2), 1e-300)
    V = np.eye(n)
    for _ in range(n + 1):
        Q = _orth(Es @ V, tol)
        Vn = _null(As - Q @ (Q.T @ As), tol)
        if Vn.shape[1] >= V.shape[1]:
            break
        V = Vn
    d = V.shape[1]
    W = _orth(Es @ V, tol)
    if W.shape[1] != d:  # singular pencil: fall back to the QZ values with |β| clearly nonzero
        (alpha, beta), vecs = sla.eig(As, Es, homogeneous_eigvals=True)
        keep = (np.abs(beta) > 1e-8 * np.hypot(np.abs(alpha), np.abs(beta))) & (np.abs(alpha) + np.abs(beta) > tol)
        lam = alpha[keep] / beta[keep]
        vectors = vecs[:, keep] * c[:, None]
        order = _order(lam)
        return lam[order], vectors[:, order], int(n - keep.sum()), True
    if d == 0:
        return np.zeros(0, dtype=complex), np.zeros((n, 0), dtype=complex), n, False
    Ar, Er = W.T @ As @ V, W.T @ Es @ V
    lam, w = sla.eig(Ar, Er)
    zeros = _zero_multiplicity(Ar, Er, tol)
    if zeros:
        lam[_cloud(Ar, w, zeros, tol)] = 0.0
    vectors = (V @ w) * c[:, None]
    order = _order(lam)
    return lam[order], vectors[:, order], n - d, False


def _order(lam: np.ndarray) -> np.ndarray:
    """The order of the eigenvalues: by modulus, a complex pair with Im λ > 0 first. QZ
    gives the two values of a pair from one 2×2 block with their own β, so their moduli may
    differ in the last bits, in either direction depending on the BLAS kernel: a pair is
    recognised as such (conjugates to round-off of its modulus), not by its moduli."""
    order = list(np.lexsort((-lam.imag, np.abs(lam))))
    for i in range(len(order) - 1):
        a, b = lam[order[i]], lam[order[i + 1]]
        if a.imag < 0 < b.imag and abs(a - np.conj(b)) <= 64 * np.finfo(float).eps * abs(a):
            order[i], order[i + 1] = order[i + 1], order[i]
    return np.asarray(order, dtype=np.int64)


def _zero_multiplicity(A: np.ndarray, E: np.ndarray, tol: float) -> int:
    """The algebraic multiplicity of the eigenvalue 0 of the regular pencil ``λE − A`` (E
    invertible): the dimension where the chain ``N₁ = ker A``, ``N_{k+1} = {x : Ax ∈ E N_k}``
    stops growing, each step a rank decision at `tol` like the Wong sequence above. Only the
    dimension: the basis of the later steps is not accurate (on a block of size 3 at
    ‖A‖ = 7000, the third step's subspace was 0.4 rad off), so it is not used as one."""
    n = A.shape[0]
    N = _null(A, tol)
    while 0 < N.shape[1] < n:
        Q = _orth(E @ N, tol)
        grown = _null(A - Q @ (Q.T @ A), tol)
        if grown.shape[1] <= N.shape[1]:
            break
        N = grown
    return N.shape[1]


def _cloud(A: np.ndarray, w: np.ndarray, zeros: int, tol: float) -> np.ndarray:
    """Indices of the `zeros` eigenvalues that rounding split off the eigenvalue 0 (its
    algebraic multiplicity, :func:`_zero_multiplicity`). A Jordan block of size m at 0 (a free
    body's position and momentum: m = 2; 3 with a free integrator behind it) comes out of QZ
    as m values spread by about ε^{1/m}·‖A‖ (±0.04 at ‖A‖ = 7000 for m = 3): more than a
    slow mode may be, so the smallest values are not the ones to set to 0 (which of the
    two is larger depends on the BLAS kernel's rounding). Their eigenvectors tell them
    apart: a split value λ of the block has the eigenvector ``(1, λ/a, λ²/a², …)`` in the
    block's chain, within |λ|/‖A‖ of ``ker A``, while a slow mode's (well separated from
    the block, or it would not be a mode of its own) is not. The `zeros` vectors nearest
    ``ker A`` are the split values."""
    kernel = _null(A, tol)
    v = w / np.maximum(np.linalg.norm(w, axis=0), 1e-300)
    away = np.linalg.norm(v - kernel @ (kernel.T @ v), axis=0)
    return np.argsort(away, kind="stable")[:zeros]


def _modes(lam, vectors, names, differential, meshes) -> list[Mode]:
    """One mode per real eigenvalue and per complex pair (Im λ > 0), eigenvectors scaled
    so that the largest state entry is 1, with the deflection shapes of strings and beams."""
    modes = []
    scale = max(1.0, float(np.abs(lam).max(initial=0.0)))
    fields = _velocity_fields(names, meshes)
    for k, z in enumerate(lam):
        if z.imag < -1e-12 * scale:
            continue
        if abs(z.imag) <= 1e-12 * scale:
            z = complex(z.real, 0.0)
        if abs(z) <= 1e-12 * scale:  # a rigid-body (zero) mode off zero by rounding: by the same rule, 0
            z = 0j
        v = vectors[:, k].astype(complex)
        states = np.abs(v) * differential
        pivot = int(np.argmax(states if states.any() else np.abs(v)))
        if v[pivot] != 0:
            v = v / v[pivot]
        shapes = {}
        for comp, (xi, idx) in fields.items():
            w = v[idx] / z if z != 0 else v[idx]
            big = int(np.argmax(np.abs(w)))
            if abs(w[big]) > 0:
                w = w / w[big]
            shapes[comp] = {"xi_over_L": xi, "deflection": np.real(w)}
        modes.append(Mode(complex(z), v, shapes))
    return modes


def _velocity_fields(names, meshes) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Distributed components whose `e_p` field holds nodal transverse velocities (strings
    and beams: P1 nodal values, or the value DOFs of Hermite cubics): name -> (ξ/L of the
    nodes, indices of those variables)."""
    found: dict[str, dict[int, int]] = {}
    for j, name in enumerate(names):
        m = _FIELD.match(name)
        if m and m["field"] == "e_p" and m["comp"] in meshes:
            found.setdefault(m["comp"], {})[int(m["i"])] = j
    out = {}
    for comp, idx in found.items():
        elements = int(meshes[comp][1])
        count = len(idx)
        if count == elements + 1:
            picks = [idx[i] for i in range(count)]
        elif count == 2 * (elements + 1):
            picks = [idx[2 * i] for i in range(elements + 1)]
        else:
            continue
        out[comp] = (np.linspace(0.0, 1.0, elements + 1), np.array(picks, dtype=np.int64))
    return out
