"""Minimal-coordinate (crank angle θ) Lagrange model of the free slider–crank under gravity,
the reference of the rigid peer comparison (Exudyn's classic planar example data).

Crank of length r about the origin, rod of length L from the crank pin to the slider on
y = 0. With s = r sin θ / L, x_s = r cos θ + L √(1 − s²); the rod's centre is the midpoint
of crank pin and slider. T = ½ m(θ) θ̇², V(θ), and θ̈ = −(V'(θ) + ½ m'(θ) θ̇²)/m(θ), with
m(θ) and its derivatives from sympy.
"""

from __future__ import annotations

import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp

DATA = dict(r=0.3, mc=1.0, L=1.0, mr=2.0, ms=0.5, g=9.81, omega0=2 * np.pi)


def _functions(r, mc, L, mr, ms, g):
    th = sp.Symbol("theta")
    pin = sp.Matrix([r * sp.cos(th), r * sp.sin(th)])
    xs = r * sp.cos(th) + sp.sqrt(L**2 - (r * sp.sin(th))**2)
    slider = sp.Matrix([xs, 0])
    centre = (pin + slider) / 2
    phi = sp.atan2(-r * sp.sin(th), xs - r * sp.cos(th))
    # kinetic energy per unit θ̇²: ½ m(θ) θ̇²
    J_pivot = mc * r**2 / 3
    dc = centre.diff(th)
    m_th = J_pivot + mr * dc.dot(dc) + mr * L**2 / 12 * phi.diff(th)**2 + ms * xs.diff(th)**2
    V = mc * g * r / 2 * sp.sin(th) + mr * g * centre[1]
    m_th = sp.simplify(m_th)
    f = sp.lambdify(th, [m_th, m_th.diff(th), V.diff(th), V, xs], "numpy")
    return f


def solve(t_eval, rtol=1e-13, atol=1e-14, **data):
    d = {**DATA, **data}
    f = _functions(d["r"], d["mc"], d["L"], d["mr"], d["ms"], d["g"])

    def rhs(t, z):
        m, dm, dV, _, _ = f(z[0])
        return [z[1], -(dV + 0.5 * dm * z[1]**2) / m]

    sol = solve_ivp(rhs, (t_eval[0], t_eval[-1]), [0.0, d["omega0"]], method="DOP853", t_eval=t_eval, rtol=rtol,
                    atol=atol)
    th, w = sol.y
    vals = [f(x) for x in th]
    xs = np.array([v[4] for v in vals])
    energy = np.array([0.5 * v[0] * wi**2 + v[3] for v, wi in zip(vals, w)])
    return sol.t, xs, energy


if __name__ == "__main__":
    t, xs, E = solve(np.linspace(0.0, 1.0, 101))
    print(f"x_slider(1 s) = {xs[-1]:.10f} m; energy drift {np.abs(E - E[0]).max() / E[0]:.1e}")
