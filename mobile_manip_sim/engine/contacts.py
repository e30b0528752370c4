"""The end stops' contact problem (docs/model.md, "Several stops at once"): for m rods at their
stops, the Delassus matrix W = Eᵀ M⁻¹ E of the contacts (`contact_matrix`) and the exact solve of
the linear complementarity problem P ≥ 0, w = W P + q ≥ 0, Pᵀw = 0 (`solve_contacts`). An impact
(`stops.contact_impulses`) solves it for impulses, a release (`stops.release`) for holding forces.
"""
from __future__ import annotations

import math

from ..dynamics import kernels
from ..dynamics.jit import jit
from . import layout


@jit
def solve_contacts(W, q, bilateral, active, P, w, scratch, idx):
    """The impact LCP of docs/model.md, exactly: P ≥ 0, w = W P + q ≥ 0, Pᵀw = 0 (W m×m symmetric
    positive definite, so the solution is unique), by Murty's least-index principal pivoting:
    solve on the active set, toggle the first contact that is wrong (a negative impulse, or an
    inactive one moving into its stop), repeat — finite for a P-matrix. A ``bilateral`` contact
    is always active with an impulse of either sign (a rod held by the Zeno guard). ``scratch`` is
    (m, m + 1), ``idx`` (m,) int64. Returns the pivots taken."""
    m = q.shape[0]
    for i in range(m):
        active[i] = bilateral[i]
    scale = 0.0
    for i in range(m):
        scale = max(scale, abs(q[i]))
    tol = 1e-13 * scale
    for pivots in range(1 << min(m + 4, 30)):
        # P_A = −W_AA⁻¹ q_A by Cholesky on the active rows, zero elsewhere
        L = scratch
        n = 0
        for i in range(m):
            if active[i]:
                idx[n] = i
                n += 1
        for a in range(n):
            for c in range(a + 1):
                s = W[idx[a], idx[c]]
                for k in range(c):
                    s -= L[a, k] * L[c, k]
                if a == c:
                    L[a, a] = math.sqrt(s) if s > 0.0 else math.nan
                else:
                    L[a, c] = s / L[c, c]
        y = L[:, m]
        for a in range(n):
            s = -q[idx[a]]
            for k in range(a):
                s -= L[a, k] * y[k]
            y[a] = s / L[a, a]
        for a in range(n - 1, -1, -1):
            s = y[a]
            for k in range(a + 1, n):
                s -= L[k, a] * y[k]
            y[a] = s / L[a, a]
        for i in range(m):
            P[i] = 0.0
        for a in range(n):
            P[idx[a]] = y[a]
        for i in range(m):
            s = q[i]
            for j in range(m):
                s += W[i, j] * P[j]
            w[i] = s
        wrong = -1
        for i in range(m):
            if bilateral[i]:
                continue
            if active[i] and P[i] < -tol or not active[i] and w[i] < -tol:
                wrong = i
                break
        if wrong < 0:
            for i in range(m):
                if not active[i]:
                    P[i] = 0.0
            return pivots
        active[wrong] = not active[wrong]
    return -1


@jit
def contact_matrix(system, stops, s, m, scratch):
    """W = Eᵀ M⁻¹ E (into scratch.W[:m, :m]) and M⁻¹ E (scratch.MinvE, one row per contact, over
    the free DOFs in free order) for the m contacts scratch.rods[:m] with directions σ in
    scratch.contact[0], every DOF free but the scene's locked ones (into scratch.free). Returns
    how many DOFs are free."""
    nq, nu = layout.sizes(system)
    q = s[:nq]
    rods, free, sigma = scratch.rods, scratch.free, scratch.contact[0]
    for j in range(nu):
        free[j] = -1
    n_free = 0
    for j in range(nu):
        if not stops.permanent[j]:
            free[n_free] = j
            n_free += 1
    zeros, unit, column = scratch.vectors[0], scratch.vectors[1], scratch.vectors[2]
    kernels.frames(system.model, q, system.ws)
    for i in range(nu):
        zeros[i] = 0.0
    kernels.mass_matrix(system.model, q, system.ws, zeros, unit, column, scratch.M)
    MinvE = scratch.MinvE
    for c in range(m):
        for i in range(nu):
            unit[i] = 0.0
        unit[layout.u_slide(rods[c])] = sigma[c]
        kernels.cholesky_solve(scratch.M, unit, free, n_free, scratch.L, MinvE[c])
    W = scratch.W
    for a in range(m):
        # W_ab = E_aᵀ M⁻¹ E_b: row a of E picks DOF j_a, which sits at position pos in free
        j = layout.u_slide(rods[a])
        pos = 0
        while free[pos] != j:
            pos += 1
        for b in range(m):
            W[a, b] = sigma[a] * MinvE[b, pos]
    return n_free
