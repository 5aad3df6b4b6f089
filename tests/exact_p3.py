"""An exact reference for problem P3: rational arithmetic, every active set, no solver.

Independent of ``controllers`` except for the tightening ``t`` (irrational: ``Phi^{-1}(xi)`` times a
square root), whose float value is taken as data. P3 is built from the model's matrices in
:class:`fractions.Fraction` (exact for float inputs), written as a QP in ``z = (nu, rho)``::

    J = c0 + nu'H nu + g'nu + alpha rho
    s.t.  G B nu - rho <= H_{k+1} - t - G Atilde x,   -nu_bound <= nu_i <= nu_bound,   rho >= 0

and solved by trying every set of at most ``m + 1`` active one-sided constraints: the exact
solution of its equality-constrained KKT system is optimal as soon as it is feasible with
nonnegative multipliers (sufficient for a convex QP). The optimum ``J*`` is exact for the float data.
Meant for small problems (m <= 2, a few rows) in tests.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction as F
from itertools import combinations

import numpy as np


def _fr(a) -> list:
    """A nested list of Fractions from a float array (exact)."""
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 0:
        return F(float(a))
    return [_fr(v) for v in a]


def _mat(A, B):
    return [
        [sum(A[i][k] * B[k][j] for k in range(len(B))) for j in range(len(B[0]))]
        for i in range(len(A))
    ]


def _vec(A, v):
    return [sum(a * b for a, b in zip(row, v, strict=True)) for row in A]


def _T(A):
    return [list(r) for r in zip(*A, strict=True)]


def _add(A, B):
    return [[a + b for a, b in zip(ra, rb, strict=True)] for ra, rb in zip(A, B, strict=True)]


def _dot(u, v):
    return sum(a * b for a, b in zip(u, v, strict=True))


def _solve(M, b):
    """Exact Gaussian elimination; None if M is singular."""
    n = len(M)
    A = [list(row) + [bi] for row, bi in zip(M, b, strict=True)]
    for c in range(n):
        p = next((r for r in range(c, n) if A[r][c] != 0), None)
        if p is None:
            return None
        A[c], A[p] = A[p], A[c]
        for r in range(n):
            if r != c and A[r][c] != 0:
                f = A[r][c] / A[c][c]
                A[r] = [x - f * y for x, y in zip(A[r], A[c], strict=True)]
    return [A[i][n] / A[i][i] for i in range(n)]


@dataclass
class ExactP3:
    """The exact optimum of P3 at one state: ``nu``, ``rho``, ``J`` (floats rounded from the
    exact values) and the exact ``J`` as a Fraction."""

    nu: np.ndarray
    rho: float
    J: float
    J_exact: F


def exact_p3(ctrl, x, mode: int, k: int) -> ExactP3:
    """The exact optimum of the controller's P3 (its model, K, Psi, alpha, nu_bound, the box U and
    its tightening) at ``(x, mode, k)``."""
    model = ctrl.model
    m, n = model.m, model.n
    chance = ctrl.tightening is not None
    x_f = _fr(x)
    inside = bool(np.all(model.G @ np.asarray(x) <= model.H(k)))
    inside = bool(np.max(model.constraint_values(np.asarray(x, dtype=np.float64), k)) <= 0.0)
    row = _fr((model.P_in if inside else model.P_out)[mode])
    Psi = [_fr(P) for P in ctrl.Psi]
    Pi = [[sum(row[j] * Psi[j][a][b] for j in range(model.N)) for b in range(n)] for a in range(n)]
    A, B, K = _fr(model.A[mode]), _fr(model.B[mode]), _fr(ctrl.K[mode])
    Q, R = _fr(model.Q[mode]), _fr(model.R[mode])
    At = _add(A, _mat(B, K))
    Kx, Ax = _vec(K, x_f), _vec(At, x_f)
    Bt = _T(B)
    H = _add(R, _mat(_mat(Bt, Pi), B))  # R + B'Pi B
    g = [2 * (a + b) for a, b in zip(_vec(R, Kx), _vec(_mat(Bt, Pi), Ax), strict=True)]
    cov = _fr(model.noise_cov[mode])
    c0 = (
        _dot(x_f, _vec(Q, x_f))
        + _dot(Kx, _vec(R, Kx))
        + _dot(Ax, _vec(Pi, Ax))
        + sum(_mat(Pi, cov)[i][i] for i in range(n))
    )
    alpha = F(float(ctrl.alpha)) if chance else F(0)
    nb = F(float(ctrl.nu_bound))
    # one-sided rows C z <= h in z = (nu, rho)
    C, h = [], []
    if chance:
        G = _fr(model.G)
        GB, GA = _mat(G, B), _mat(G, At)
        Hk = _fr(model.H(k + 1))
        t = _fr(ctrl.tightening[mode])
        for j in range(model.r):
            C.append(list(GB[j]) + [F(-1)])
            h.append(Hk[j] - t[j] - _dot(GA[j], x_f))
    for i in range(m):
        e = [F(0)] * (m + 1)
        e[i] = F(1)
        C.append(e)
        h.append(nb)
        C.append([-v for v in e])
        h.append(nb)
    rho_row = [F(0)] * m + [F(-1)]
    C.append(rho_row)  # -rho <= 0
    h.append(F(0))
    if not chance:
        C.append([F(0)] * m + [F(1)])  # rho <= 0
        h.append(F(0))
    d = m + 1
    P = [[2 * H[i][j] if i < m and j < m else F(0) for j in range(d)] for i in range(d)]
    q = list(g) + [alpha]
    best = None
    for size in range(min(d, len(C)), -1, -1):
        for S in combinations(range(len(C)), size):
            M = [list(P[i]) + [C[s][i] for s in S] for i in range(d)]
            M += [list(C[s]) + [F(0)] * size for s in S]
            sol = _solve(M, [-v for v in q] + [h[s] for s in S])
            if sol is None:
                continue
            z, lam = sol[:d], sol[d:]
            if any(v < 0 for v in lam) or any(_dot(C[i], z) > h[i] for i in range(len(C))):
                continue
            J = c0 + _dot(z[:m], _vec(H, z[:m])) + _dot(g, z[:m]) + alpha * z[m]
            if best is None or J < best[0]:
                best = (J, z)
    assert best is not None, "P3 has an optimum: some active set must satisfy the KKT conditions"
    J, z = best
    return ExactP3(np.array([float(v) for v in z[:m]]), float(z[m]), float(J), J)
