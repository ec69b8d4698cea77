"""The flexible slider–crank written by hand with numpy/scipy, as a user would without phc.

Same equations and discretization as ``models/flexible_slider_crank.yaml`` (seed section 5:
crank wheel, moving-frame Euler–Bernoulli rod with the partitioned mixed FEM — Hermite
cubics for the transverse momentum p_b, discontinuous P1 for the curvature κ — pin joints
without moments, right end on the guide y = 0, drive and slider ports free).

State z (41 for 8 elements)::

    θ, q0 (2), qf (2), κ (2n), p_θ, p_b (2n + 2), p_t

Velocities v = (θ̇, e_p = p_b/ρ, e_t = p_t/m) and momenta p_m = M v with
M = diag(I_w, ρ M_A, m). The three joint constraints (crank pin, guide normal) are on
velocity level, G(q, θ) v = 0:

    e_t t + e_p(0) n − r a⊥(θ) θ̇ = 0,        e_t t_y + e_p(L) n_y = 0,

and the multipliers λ (the joint reaction efforts) are eliminated at every call of the
right-hand side from the differentiated constraint G v̇ + γ(q, θ, v) = 0:

    ṗ_m = f − Gᵀλ,   (G M⁻¹ Gᵀ) λ = G M⁻¹ f + γ,   p_m = (p_θ, M_A p_b, p_t),

with f = (0, −Dᵀ EI κ − ω e_t ρ r, ω rᵀp_b), ω = (e_p(L) − e_p(0))/L, r_j = ∫φ_j,
M_B κ̇ = D e_p, D_ij = ∫ψ_i φ_j''. ``jacobian`` is the exact analytic Jacobian of this
right-hand side (chain rule through the elimination).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

GAUSS_S, GAUSS_W = np.polynomial.legendre.leggauss(5)
GAUSS_S, GAUSS_W = 0.5 * (GAUSS_S + 1.0), 0.5 * GAUSS_W
J2 = np.array([[0.0, -1.0], [1.0, 0.0]])


def hermite(s, h, d):
    """Hermite cubic basis (value, slope at left node; value, slope at right node) or derivatives."""
    if d == 0:
        return np.stack([1 - 3 * s**2 + 2 * s**3, h * (s - 2 * s**2 + s**3), 3 * s**2 - 2 * s**3, h * (-s**2 + s**3)])
    return np.stack([(-6 + 12 * s) / h**2, (-4 + 6 * s) / h, (6 - 12 * s) / h**2, (-2 + 6 * s) / h])  # d == 2


class FlexibleSliderCrank:
    def __init__(self, elements=8, r=0.15, L=0.30, EI=68.27, rhoA=0.50368, Iw=1.0e-3, omega0=150.0):
        self.n, self.r, self.L, self.EI, self.rho, self.Iw, self.omega0 = elements, r, L, EI, rhoA, Iw, omega0
        self.m = rhoA * L
        n, h = elements, L / elements
        na, nb = 2 * n + 2, 2 * n
        self.na, self.nb = na, nb
        # Element matrices by 5-point Gauss quadrature (exact for these polynomials).
        w = h * GAUSS_W
        H0, H2 = hermite(GAUSS_S, h, 0), hermite(GAUSS_S, h, 2)
        P1 = np.stack([1 - GAUSS_S, GAUSS_S])
        MA, MB, D, rv = np.zeros((na, na)), np.zeros((nb, nb)), np.zeros((nb, na)), np.zeros(na)
        for e in range(n):
            a, b = slice(2 * e, 2 * e + 4), slice(2 * e, 2 * e + 2)
            MA[a, a] += (H0 * w) @ H0.T
            MB[b, b] += (P1 * w) @ P1.T
            D[b, a] += (P1 * w) @ H2.T
            rv[a] += H0 @ w
        self.MA, self.MB, self.D, self.rv = MA, MB, D, rv
        self.CK = np.linalg.solve(MB, D) / rhoA          # κ̇ = CK p_b
        self.FK = -D.T * EI                               # f_p ∋ FK κ
        self.MAinv = np.linalg.inv(MA)                    # M_A ṗ_b = f_p − (joint reactions)
        # M⁻¹ on the velocity coordinates (θ̇, e_p, e_t); columns touched by G: θ̇, e_p(0), e_p(L), e_t.
        Minv = np.zeros((na + 2, na + 2))
        Minv[0, 0] = 1 / Iw
        Minv[1:na + 1, 1:na + 1] = np.linalg.inv(rhoA * MA)
        Minv[-1, -1] = 1 / self.m
        self.cols = np.array([0, 1, 1 + 2 * n, na + 1])   # in p_m / v indexing
        self.Minv_sub = Minv[self.cols]                   # (4, na + 2)
        self.Minv_cc = Minv[np.ix_(self.cols, self.cols)]
        # state layout
        self.iK = slice(5, 5 + nb)
        self.ipth = 5 + nb
        self.iP = slice(6 + nb, 6 + nb + na)
        self.ipt = 6 + nb + na
        self.size = self.ipt + 1
        self.iP0, self.iPL = 6 + nb, 6 + nb + 2 * n
        # midspan deflection w(L/2) = g·κ (Green's function of w'' = κ, w(0) = w(L) = 0)
        xs = L / 2
        self.g = np.zeros(nb)
        for e in range(n):
            xi = e * h + h * GAUSS_S
            green = np.where(xi <= xs, xi * (xs - L) / L, xs * (xi - L) / L)
            self.g[2 * e:2 * e + 2] += (P1 * w) @ green
        self._jconst = np.zeros((self.size, self.size))
        jc = self._jconst
        jc[0, self.ipth] = 1 / Iw
        jc[self.iK, self.iP] = self.CK

    # ---- initial state: straight rod moving rigidly with the crank pin --------------------------
    def initial_state(self):
        z = np.zeros(self.size)
        z[1], z[3] = self.r, self.r + self.L
        z[self.ipth] = self.Iw * self.omega0
        v0 = self.r * self.omega0            # normal velocity of the left end; right end 0 (guide)
        nodes = np.linspace(0.0, self.L, self.n + 1)
        ep = np.zeros(self.na)
        ep[0::2] = v0 * (1 - nodes / self.L)
        ep[1::2] = -v0 / self.L
        z[self.iP] = self.rho * ep
        return z

    # ---- right-hand side --------------------------------------------------------------------------
    def _parts(self, z):
        th = z[0]
        c = z[3:5] - z[1:3]
        ell = np.hypot(c[0], c[1])
        t = c / ell
        nn = np.array([-t[1], t[0]])
        P = z[self.iP]
        vth, v0, vL, et = z[self.ipth] / self.Iw, z[self.iP0] / self.rho, z[self.iPL] / self.rho, z[self.ipt] / self.m
        om = (vL - v0) / self.L
        a = np.array([np.cos(th), np.sin(th)])
        ap = np.array([-a[1], a[0]])
        f = np.empty(self.na + 2)
        f[0] = 0.0
        f[1:-1] = self.FK @ z[self.iK] - (om * et * self.rho) * self.rv
        rP = self.rv @ P
        f[-1] = om * rP
        Gc = np.array([[-self.r * ap[0], nn[0], 0.0, t[0]],
                       [-self.r * ap[1], nn[1], 0.0, t[1]],
                       [0.0, 0.0, nn[1], t[1]]])
        omc = (vL - v0) / ell
        gam = np.empty(3)
        gam[:2] = et * omc * nn - v0 * omc * t + self.r * vth**2 * a
        gam[2] = et * omc * nn[1] - vL * omc * t[1]
        hc = self.Minv_sub @ f
        S = Gc @ self.Minv_cc @ Gc.T
        lam = np.linalg.solve(S, Gc @ hc + gam)
        return th, c, ell, t, nn, P, vth, v0, vL, et, om, omc, a, ap, f, rP, Gc, gam, hc, S, lam

    def rhs(self, t_, z):
        th, c, ell, t, nn, P, vth, v0, vL, et, om, omc, a, ap, f, rP, Gc, gam, hc, S, lam = self._parts(z)
        dz = np.empty(self.size)
        dz[0] = vth
        dz[1:3] = et * t + v0 * nn
        dz[3:5] = et * t + vL * nn
        dz[self.iK] = self.CK @ P
        dp = f
        dp[self.cols] -= Gc.T @ lam
        dz[self.ipth] = dp[0]
        dz[self.iP] = self.MAinv @ dp[1:-1]
        dz[self.ipt] = dp[-1]
        return dz

    def jacobian(self, t_, z):
        th, c, ell, t, nn, P, vth, v0, vL, et, om, omc, a, ap, f, rP, Gc, gam, hc, S, lam = self._parts(z)
        r, rho, m, Iw, L = self.r, self.rho, self.m, self.Iw, self.L
        Jz = self._jconst.copy()
        ipth, iP0, iPL, ipt = self.ipth, self.iP0, self.iPL, self.ipt
        # kinematics q̇0 = e_t t + v0 n, q̇f = e_t t + vL n
        Pt = (np.eye(2) - np.outer(t, t)) / ell
        dt_dq = np.hstack([-Pt, Pt])                       # (2, 4) w.r.t. q0x, q0y, qfx, qfy
        dn_dq = J2 @ dt_dq
        Jz[1:3, 1:5] = et * dt_dq + v0 * dn_dq
        Jz[3:5, 1:5] = et * dt_dq + vL * dn_dq
        Jz[1:5, ipt] = np.concatenate([t, t]) / m
        Jz[1:3, iP0] = nn / rho
        Jz[3:5, iPL] = nn / rho
        # df/dz (rows p_m, 20 + ... ) — K part is constant (in _jconst), add the velocity parts
        dfdz = np.zeros((self.na + 2, self.size))
        dfdz[1:-1, self.iK] = self.FK
        dfdz[1:-1, iP0] += et * self.rv / L
        dfdz[1:-1, iPL] -= et * self.rv / L
        dfdz[1:-1, ipt] -= om * rho * self.rv / m
        dfdz[-1, self.iP] = om * self.rv
        dfdz[-1, iP0] -= rP / (rho * L)
        dfdz[-1, iPL] += rP / (rho * L)
        # da/dz, a = Gc hc + γ
        da = Gc @ (self.Minv_sub @ dfdz)                   # (3, size)
        dS_lam = np.zeros((3, self.size))
        MG_lam = self.Minv_cc @ (Gc.T @ lam)
        dGcT_lam = np.zeros((self.size, 4))               # rows: z, cols: dGcᵀλ (4)
        # geometric columns: θ and q
        dGc_th = np.zeros((3, 4))
        dGc_th[:2, 0] = r * a
        dgam_th = np.array([r * vth**2 * ap[0], r * vth**2 * ap[1], 0.0])
        da[:, 0] += dGc_th @ hc + dgam_th
        dS_lam[:, 0] = dGc_th @ MG_lam + Gc @ self.Minv_cc @ (dGc_th.T @ lam)
        dGcT_lam[0] = dGc_th.T @ lam
        for k in range(4):
            dtk, dnk = dt_dq[:, k], dn_dq[:, k]
            dc = np.zeros(2)
            dc[k % 2] = 1.0 if k >= 2 else -1.0
            dell = t @ dc
            domc = -omc * dell / ell
            dG = np.zeros((3, 4))
            dG[:2, 1] = dnk
            dG[:2, 3] = dtk
            dG[2, 2] = dnk[1]
            dG[2, 3] = dtk[1]
            dg = np.empty(3)
            dg[:2] = et * (domc * nn + omc * dnk) - v0 * (domc * t + omc * dtk)
            dg[2] = et * (domc * nn[1] + omc * dnk[1]) - vL * (domc * t[1] + omc * dtk[1])
            da[:, 1 + k] += dG @ hc + dg
            dS_lam[:, 1 + k] = dG @ MG_lam + Gc @ self.Minv_cc @ (dG.T @ lam)
            dGcT_lam[1 + k] = dG.T @ lam
        # velocity columns of γ
        dg_vth = np.array([2 * r * vth * a[0], 2 * r * vth * a[1], 0.0])
        dg_et = np.array([omc * nn[0], omc * nn[1], omc * nn[1]])
        dg_v0 = np.empty(3)
        dg_v0[:2] = -et * nn / ell - omc * t + v0 * t / ell
        dg_v0[2] = -et * nn[1] / ell + vL * t[1] / ell
        dg_vL = np.empty(3)
        dg_vL[:2] = et * nn / ell - v0 * t / ell
        dg_vL[2] = et * nn[1] / ell - omc * t[1] - vL * t[1] / ell
        da[:, ipth] += dg_vth / Iw
        da[:, iP0] += dg_v0 / rho
        da[:, iPL] += dg_vL / rho
        da[:, ipt] += dg_et / m
        dlam = np.linalg.solve(S, da - dS_lam)            # (3, size)
        dp = dfdz
        dp[self.cols] -= Gc.T @ dlam
        dp[self.cols] -= dGcT_lam.T
        Jz[ipth] = dp[0]
        Jz[self.iP] = self.MAinv @ dp[1:-1]
        Jz[ipt] = dp[-1]
        return Jz

    # ---- outputs ------------------------------------------------------------------------------------
    def slider_x(self, Z):
        return Z[3]

    def midspan_deflection(self, Z):
        return self.g @ Z[self.iK]

    def solve(self, t_eval, method="Radau", rtol=1e-8, atol=None, analytic_jacobian=False):
        z0 = self.initial_state()
        if atol is None:
            atol = rtol * 1e-2
        sol = solve_ivp(self.rhs, (t_eval[0], t_eval[-1]), z0, method=method, t_eval=t_eval, rtol=rtol, atol=atol,
                        jac=self.jacobian if analytic_jacobian else None)
        return sol
