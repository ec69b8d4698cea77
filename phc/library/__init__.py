"""Lowering of each component ``type`` to variables, equations and ports.

``LOWERERS[type](builder, ctx, full_name, spec, path)`` adds the component's variables,
equations, Hamiltonian, dissipation and ports to the :class:`phc.elaborate.Builder`.
"""

from __future__ import annotations

from functools import partial

from phc.library import lumped
from phc.library.beams import lower_euler_bernoulli, lower_string, lower_timoshenko
from phc.library.linear import lower_linear_phs
from phc.library.moving import lower_crank_wheel, lower_moving_beam
from phc.library.pde1d import lower_pde1d
from phc.library.phs import lower_phs
from phc.library.rigid import lower_rigid

LOWERERS = {
    "phs": lower_phs,
    "linear_phs": lower_linear_phs,
    "rigid": lower_rigid,
    "mass": partial(lumped.lower_inertia, coeff_field="m", state="p"),
    "inductor": partial(lumped.lower_inertia, coeff_field="L", state="phi"),
    "spring": partial(lumped.lower_compliance, coeff_field="k", state="x", inverse=False),
    "capacitor": partial(lumped.lower_compliance, coeff_field="C", state="q", inverse=True),
    "damper": partial(lumped.lower_resistance, coeff_field="d"),
    "resistor": partial(lumped.lower_resistance, coeff_field="R"),
    "effort_source": partial(lumped.lower_source, which="effort"),
    "flow_source": partial(lumped.lower_source, which="flow"),
    "zero_effort": partial(lumped.lower_termination, which="effort"),
    "zero_flow": partial(lumped.lower_termination, which="flow"),
    "orthogonal_transform": lumped.lower_transform,
    "transformer": lumped.lower_transformer,
    "gyrator": lumped.lower_gyrator,
    "junction": lumped.lower_junction,
    "modulation": lumped.lower_modulation,
    "string": lower_string,
    "timoshenko_beam": lower_timoshenko,
    "euler_bernoulli_beam": lower_euler_bernoulli,
    "pde1d": lower_pde1d,
    "moving_beam": lower_moving_beam,
    "crank_wheel": lower_crank_wheel,
}

__all__ = ["LOWERERS"]
