"""Rigid-body models shared by tests of different solvers (one text each, not a copy per file)."""

from __future__ import annotations


def bead_on_turned_rod(n_out: int) -> str:
    """A bead sliding freely on a rod turned at the prescribed rate Ω: M(q) = diag(m, J + m r²),
    the rheonomic constraint θ = Ωt; closed form r = r₀ cosh Ωt, p_θ = (J + m r²)Ω (m = 0.5,
    J = 0.02, Ω = 2, r₀ = 0.1), to t = 1.5 with `n_out` output times."""
    return f"""\
format_version: 1
name: bead
parameters:
  m: {{value: 0.5, unit: kg}}
  J: {{value: 0.02, unit: kg*m^2}}
  Om: {{value: 2.0, unit: rad/s}}
  r0: {{value: 0.1, unit: m}}
components:
  rod:
    type: rigid
    q: [r, th]
    v: [vr, om]
    M: [[m, 0], [0, J + m*r**2]]
    constraints:
      - th - Om*t
simulation:
  t_end: 1.5
  n_out: {n_out}
  initial: {{rod.r: r0, rod.th: 0, rod.p_vr: 0}}
"""
