"""`SimResult`: what a simulation returns, successful or not."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from phc.errors import SimulationInterrupted  # noqa: F401  (its old home)


@dataclass
class SimResult:
    """Time series and figures of one run.

    A failed run (``success=False``) keeps everything computed up to the failure.
    ``energy_balance_error`` is ``max |H(t) − H(t₀) + ∫(P_ports + P_diss) dt|``, zero in
    exact arithmetic by the paper's Remark 3 "Energy balance"; ``energy_balance_relative``
    divides it by the largest |H| seen. ``constraint_drift`` is the largest |g| of the
    position-level invariants over the output times, ``velocity_drift`` the same for the
    velocity constraints.
    """

    success: bool
    message: str
    t: np.ndarray
    y: np.ndarray
    yp: np.ndarray
    variables: tuple[str, ...]
    differential: np.ndarray
    H: np.ndarray
    port_power: np.ndarray
    dissipation: np.ndarray
    energy_supplied: np.ndarray
    outputs: dict[str, np.ndarray] = field(default_factory=dict)
    invariants: Optional[np.ndarray] = None
    invariant_labels: tuple[str, ...] = ()
    velocity_invariants: Optional[np.ndarray] = None
    energy_balance_error: float = float("nan")
    energy_balance_relative: float = float("nan")
    constraint_drift: float = 0.0
    velocity_drift: float = 0.0
    steps: int = 0
    n_residual_evals: int = 0
    n_jacobian_evals: int = 0
    cpu_time_s: float = 0.0
    timings: dict = field(default_factory=dict)
    """CPU seconds (``time.process_time``) of the run's phases: ``start`` (the consistent
    initial state, or the compilation's kept one), ``scales`` (the nominal scales),
    ``integrate`` (the solver's steps, its set-up and the switches between them) and
    ``polish`` (the algebraic variables at the output times), which add up to `cpu_time_s`;
    then ``finish`` (energies, powers, outputs and invariants at the output times), which
    `cpu_time_s` leaves out. A benchmark of a solver's step cost reads ``integrate``."""
    n_states: int = 0
    n_equations: int = 0
    solver: str = "ida"
    rtol: float = 0.0
    atol: float = 0.0
    step: Optional[float] = None
    """Step of the fixed-step solvers (their accuracy setting; rtol/atol do not apply)."""
    initial_choices: dict[str, float] = field(default_factory=dict)
    interrupted: bool = False
    """The run was stopped by Ctrl-C (KeyboardInterrupt); the results are those computed so far."""
    events: list = field(default_factory=list)
    """Switches of the run in time order (:class:`phc.simulation.events.Event`: time,
    condition as written in the model, direction, kind ``time``/``state``/``stick``/``slip``);
    see docs/events.md."""
    backend: str = "numpy"
    """What ran the generated functions (``numpy``, ``numba`` or ``c``; :mod:`phc.codegen.backends`)."""
    backend_note: str = ""
    """One line on why, when the run chose a backend of its own (``auto`` on a long fixed-step
    run: :func:`phc.codegen.backends.for_run`); empty otherwise."""
    units: dict = field(default_factory=dict)
    """Unit labels of outputs, variables and `H` where the model's units give them
    (`{"x": "m", "spring.x": "m", "H": "J"}`; docs/units.md). Empty for a model without units."""

    def unit(self, name: str) -> Optional[str]:
        """The unit label of an output, variable or `H`, or None when it is not known."""
        return self.units.get(name)

    def __getitem__(self, name: str) -> np.ndarray:
        """Time series of a variable or output by name."""
        if name in self.outputs:
            return self.outputs[name]
        if name == "H":
            return self.H
        try:
            return self.y[:, self.variables.index(name)]
        except ValueError:
            raise KeyError(f"no variable or output named `{name}`") from None

    def reference_errors(self) -> dict:
        """``{output: {"max": max_t |y − y_ref|, "relative": that over max_t |y_ref|}}`` for
        every output a scene gives a closed form of (``reference:``, its ``<name>_reference``
        output), over the output times of the run."""
        out = {}
        for name, ref in self.outputs.items():
            if not name.endswith("_reference") or name[: -len("_reference")] not in self.outputs:
                continue
            y = np.asarray(self.outputs[name[: -len("_reference")]], dtype=float)
            r = np.asarray(ref, dtype=float)
            if y.shape != r.shape or not y.size:
                continue
            err = float(np.abs(y - r).max())
            size = float(np.abs(r).max())
            out[name[: -len("_reference")]] = {"max": err, "relative": err / size if size > 0 else float("nan")}
        return out

    def summary(self) -> dict:
        """The JSON summary printed by `phc simulate --format json`."""
        return {
            "success": bool(self.success),
            "message": self.message,
            "interrupted": bool(self.interrupted),
            "solver": self.solver,
            "rtol": self.rtol,
            "atol": self.atol,
            "step": self.step,
            "backend": self.backend,
            "backend_note": self.backend_note,
            "n_states": int(self.n_states),
            "n_equations": int(self.n_equations),
            "t_final": float(self.t[-1]) if len(self.t) else None,
            "steps": int(self.steps),
            "n_residual_evals": int(self.n_residual_evals),
            "n_jacobian_evals": int(self.n_jacobian_evals),
            "cpu_time_s": float(self.cpu_time_s),
            "timings": {name: float(v) for name, v in self.timings.items()},
            "energy_balance_error": float(self.energy_balance_error),
            "energy_balance_relative": float(self.energy_balance_relative),
            "constraint_drift": float(self.constraint_drift),
            "velocity_drift": float(self.velocity_drift),
            "initial_choices": self.initial_choices,
            "reference_errors": self.reference_errors(),
            "events": [e.as_dict() for e in self.events],
            "units": dict(self.units),
        }

