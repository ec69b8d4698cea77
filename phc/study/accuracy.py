"""Error estimates of a run: ``phc simulate --estimate-error``.

Every run reports its energy-balance residual and constraint drift (what the structure
guarantees). On request phc also estimates the *discretization* errors of the requested
outputs by Richardson extrapolation from a second run:

* **temporal**: a fixed-step solver (order q: 2, 4 for ``midpoint4``) reruns with half the
  step; the error of the first run is ``|y_h − y_{h/2}| · 2^q/(2^q − 1)``. IDA reruns with
  tolerances / 10; its error is taken as ``|y_tol − y_{tol/10}| · 10/9`` (error roughly
  proportional to the tolerance);
* **spatial**: every distributed component is recompiled with twice the elements (same
  solver settings; initial fields of ξ are projected onto the finer mesh, per-dof initial
  values make the estimate unavailable, PHC-E214) and ``|y_n − y_{2n}| · 2^q/(2^q − 1)``, with q the method's order:
  2 for strings, Timoshenko beams and pde1d (P1/P0 mixed elements), 4 for Euler–Bernoulli
  and moving beams (Hermite cubics) — see README, "Distributed components".

Estimates are maxima over the output grid, per output. They are estimates: they assume
the asymptotic regime (errors dominated by the leading term), which the reruns also let a
user check (halving again should divide the estimate by 2^order).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from phc.library.registry import FieldView
from phc.frontend.scene import scene_variant

SPATIAL_ORDER = FieldView("spatial_order")
"""Type -> convergence order of its discretization in the element size (:mod:`phc.library.registry`)."""
FIXED_STEP_ORDER = {"midpoint": 2, "discrete_gradient": 2, "midpoint4": 4}
"""Order of each fixed-step solver (the Richardson factor of the half-step rerun)."""
IDA_TOL_FACTOR = 10.0


@dataclass
class ErrorEstimate:
    kind: str
    """`temporal` or `spatial`."""
    method: str
    per_output: dict[str, float]
    cpu_time_s: float
    ok: bool = True
    message: str = ""

    @property
    def max(self) -> float:
        return max(self.per_output.values(), default=0.0)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "method": self.method, "max": self.max, "per_output": self.per_output,
                "cpu_time_s": self.cpu_time_s, "ok": self.ok, "message": self.message}


def _observed(result) -> dict[str, np.ndarray]:
    """The quantities compared: the requested outputs, else the energy states."""
    if result.outputs:
        return {k: v for k, v in result.outputs.items() if not k.endswith("_reference")}
    cols = np.flatnonzero(result.differential)
    return {"states": result.y[:, cols]}


def _difference(a, b) -> dict[str, float]:
    oa, ob = _observed(a), _observed(b)
    n = min(len(a.t), len(b.t))
    return {k: float(np.abs(np.asarray(oa[k])[:n] - np.asarray(ob[k])[:n]).max(initial=0.0)) for k in oa}


OUTPUT_ROUNDOFF = 1e-10
"""Outputs whose reference stays below this size throughout are left out of a relative error
(a constraint residual, a deflection that stays at 1e-17: a ratio of round-off means nothing)."""


def relative_output_errors(run, ref, floor: float = OUTPUT_ROUNDOFF) -> dict[str, float]:
    """``max_t |y − y_ref| / max_t |y_ref|`` of every scalar output of `run` against `ref`
    (a reference run of the same model), over the output times both reached."""
    errors = {}
    for name, values in run.outputs.items():
        a, b = np.asarray(values, dtype=float), np.asarray(ref.outputs[name], dtype=float)
        k = min(len(a), len(b))
        if a.ndim != 1 or k == 0:
            continue
        scale = float(np.abs(b[:k]).max())
        if scale < floor:
            continue
        errors[name] = float(np.abs(a[:k] - b[:k]).max()) / scale
    return errors


def temporal_estimate(compiled, result, run_kwargs: dict) -> ErrorEstimate:
    from phc.simulation import FIXED_STEP, simulate

    kwargs = dict(run_kwargs, t_eval=result.t)
    kwargs.pop("n_out", None)
    if result.solver in FIXED_STEP:
        opts = compiled.options
        h = kwargs.get("step") or opts.get("step") or float(np.diff(result.t).min())
        fine = simulate(compiled, **dict(kwargs, step=h / 2))
        q = FIXED_STEP_ORDER.get(result.solver, 2)
        factor = 2**q / (2**q - 1)
        method = f"rerun with half the step (h = {h:.3g} → {h / 2:.3g}), Richardson order {q}"
    else:
        fine = simulate(compiled, **dict(kwargs, rtol=result.rtol / IDA_TOL_FACTOR, atol=result.atol / IDA_TOL_FACTOR))
        factor = IDA_TOL_FACTOR / (IDA_TOL_FACTOR - 1)
        method = f"rerun with rtol {result.rtol / IDA_TOL_FACTOR:.1e}, atol {result.atol / IDA_TOL_FACTOR:.1e}"
    est = {k: factor * v for k, v in _difference(result, fine).items()}
    return ErrorEstimate("temporal", method, est, fine.cpu_time_s, fine.success, "" if fine.success else fine.message)


def spatial_estimate(compiled, result, run_kwargs: dict) -> Optional[ErrorEstimate]:
    from phc.errors import ModelError
    from phc.pipeline import compile_model
    from phc.simulation import simulate

    meshes = compiled.dae.meshes
    if not meshes:
        return None
    order = min(SPATIAL_ORDER.get(kind, 2) for kind, _ in meshes.values())
    fine_scene = scene_variant(compiled.scene if compiled.scene is not None else compiled.dae.sources[0],
                               mesh={name: 2 * n for name, (_, n) in meshes.items()})
    sizes = ", ".join(f"{name} {n} → {2 * n}" for name, (_, n) in meshes.items())
    try:
        fine_model = compile_model(fine_scene.model_path, scene=fine_scene, certify=False)
    except ModelError as err:  # e.g. initial values per dof, which belong to the coarse mesh (PHC-E214)
        first = err.diagnostics.errors[0].render() if err.diagnostics.errors else str(err)
        return ErrorEstimate("spatial", f"not estimated: the model does not compile with twice the elements "
                             f"({sizes})", {}, 0.0, False, first)
    kwargs = dict(run_kwargs, t_eval=result.t)
    kwargs.pop("n_out", None)
    fine = simulate(fine_model, **kwargs)
    factor = 2**order / (2**order - 1)
    est = {k: factor * v for k, v in _difference(result, fine).items()}
    return ErrorEstimate("spatial", f"rerun with twice the elements ({sizes}), Richardson order {order}", est,
                         fine.cpu_time_s, fine.success, "" if fine.success else fine.message)


def estimate_errors(compiled, result, run_kwargs: Optional[dict] = None) -> list[ErrorEstimate]:
    """Temporal and (for models with distributed components) spatial error estimates of
    `result`, obtained with the same `run_kwargs` that produced it (`simulate` keywords)."""
    run_kwargs = {k: v for k, v in (run_kwargs or {}).items() if k != "progress"}
    out = [temporal_estimate(compiled, result, run_kwargs)]
    spatial = spatial_estimate(compiled, result, run_kwargs)
    if spatial is not None:
        out.append(spatial)
    return out


__all__ = ["ErrorEstimate", "estimate_errors", "temporal_estimate", "spatial_estimate", "SPATIAL_ORDER",
           "relative_output_errors"]
