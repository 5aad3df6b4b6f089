"""The one verification of every receding-horizon QP: exact solve of an active set, KKT test.

The QP is ``min 1/2 z'Pz + q'z  s.t.  C z <= h`` (one-sided rows, see
:class:`controllers.qp.QPFamily`); an instance is ``w = [q; h]``. For an active set ``S`` (rows
of ``C``) the solution and the multipliers are linear in ``w``. Whatever found ``S`` (a warm
start, OSQP, DAQP, an enumeration, cvxpy), the answer is accepted only through this module, by
one test, for problem P3 and for the scenario tree alike:

* an active row on a single variable (a *bound*: the box on ``nu``, ``rho >= 0``) fixes that
  variable exactly, ``z_j = h_i / C_ij``; the other active rows (the *general* ones) act on the
  remaining free variables, with the fixed ones moved to their right side. Eliminating the
  bounds exactly keeps a huge linear term of a fixed variable (a penalty ``alpha`` of 1e9 on a
  slack at its bound) out of the free variables' solution, where a round-off in the null-space
  basis would multiply it;
* the general rows and the free variables are equilibrated (Ruiz scaling; a free variable in no
  general row by its curvature), and ``S`` is a candidate only if its scaled, row-normalized
  general rows are linearly independent and the reduced Hessian on their null space is positive
  definite, relative to its own scale;
* the free variables are computed by the null-space method on the scaled rows:
  ``C_g' = Q R``, ``z = Q1 R1^{-T} r_g + Q2 y`` with ``(Q2' P Q2) y = -Q2'(q + P z_p)``
  (``r_g`` the general rows' right side less the fixed variables' part); the general rows'
  multipliers from the free variables' stationarity, the bounds' from the fixed ones';
* the KKT test accepts ``S`` when every primal residual ``C_i z - h_i`` (of an active row: its
  absolute value) and every negated multiplier is at most :data:`KKT_TOL` (round-off) times
  the magnitude of the terms summed to compute it. The magnitudes are carried through every
  product with absolute values (so a cancellation is not mistaken for a small term), in the
  equilibrated variables, which makes the test invariant under a scaling of the rows, of the
  variables or of the objective;
* a multiplier accepted below zero is computed again, densely (:func:`confirm_multipliers`):
  an ill-conditioned reduced Hessian made magnitudes of 1e10 for a multiplier of -3.8.

Two forms compute the same numbers from one :class:`ActiveSetFactor` (the part that depends
only on ``C`` and ``S``) and one :func:`reduce_hessian` (the part that depends on ``P``): the
maps over the whole ``w`` (:mod:`controllers.kkt_maps`; P3 and its enumeration, whose Hessian
is fixed, and the scenario tree's pairs of Hessian and active set met again) and
:func:`check_active_set` (one instance, for the scenario tree, whose Hessian changes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .kkt_confirm import CONFIRM_TOL, confirm_multipliers

__all__ = [
    "CONFIRM_TOL",
    "KKT_TOL",
    "ActiveSetFactor",
    "active_set_factor",
    "check_active_set",
    "confirm_multipliers",
    "reduce_hessian",
    "solve_stacked",
]

#: Relative tolerance of the KKT test: a residual (a row's, or a negated multiplier) is accepted
#: when it is at most this fraction of the magnitude of the terms summed to compute it: about
#: 4500 ulps, as what decides optimality is there (a row's residual is paid at the price of its
#: slack, which may be 1e12 per unit; the negative multipliers of nearly parallel rows are
#: 1e-11 of their terms).
KKT_TOL = 1e-12

#: Rank and definiteness thresholds of the exact solve, relative to the scale of the matrices.
_RANK_TOL = 1e-11
_PD_TOL = 1e-12


def _ruiz(CS: np.ndarray, d: int, sweeps: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Dc, Dr, used)``: Ruiz equilibration of the rows ``CS`` (every row and every column of
    ``Dr CS Dc`` then has its largest entry near 1); ``Dc = 1`` for a variable in no row
    (``used`` False), which :func:`_free_scaling` scales by its curvature."""
    s = CS.shape[0]
    absC = np.abs(CS)
    Dc, Dr = np.ones(d), np.ones(s)
    used = absC.max(axis=0, initial=0.0) > 0.0
    for _ in range(sweeps):
        scaled = absC * Dr[:, None] * Dc[None, :]
        row = scaled.max(axis=1, initial=0.0)
        col = scaled.max(axis=0, initial=0.0)
        fr = np.sqrt(np.where(row > 0.0, row, 1.0))
        fc = np.sqrt(np.where(col > 0.0, col, 1.0))
        if np.all(np.abs(fr - 1.0) < 1e-6) and np.all(np.abs(fc - 1.0) < 1e-6):
            break
        Dr, Dc = Dr / fr, Dc / fc
    return Dc, Dr, used


def _blocks(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The block-diagonal ``[[A, 0], [0, B]]``."""
    out = np.zeros((A.shape[0] + B.shape[0], A.shape[1] + B.shape[1]))
    out[: A.shape[0], : A.shape[1]], out[A.shape[0] :, A.shape[1] :] = A, B
    return out


def _two(index: np.ndarray, offset: int) -> np.ndarray:
    """``index`` and ``index + offset``: rows of both halves of a stacked array."""
    return np.concatenate([index, index + offset])


@dataclass(frozen=True, eq=False)
class ActiveSetFactor:
    """The part of an active set's exact solve that depends only on ``C`` and the rows.

    The active rows split into bounds (one nonzero: they fix a variable exactly), pivot rows
    and the other general rows. A *pivot row* is a general row whose only nonzero among the
    family's pivot variables (slacks without curvature, e.g. ``rho``) is on a slack that no
    other pivot row uses: the row gives that slack exactly, ``z_s = (r_a - C_aN z_N) / c``, so
    a huge right side (a band ``H_k`` at ``k = 1e15``) goes into the slack alone instead of
    cancelling in the null-space solution of the other variables. The other general rows, with
    the pivot slacks substituted (``C_u - E C_a``, ``E = C_uS / c``), act on the remaining free
    variables ``N``; those are scaled, ``z_N = Dc z~``, with :attr:`Dc_used` for the variables
    in a reduced row and the curvature scaling of :func:`_free_scaling` for the others, and
    with the reduced rows scaled by ``Dn`` and normalized, ``Chat' = [Q1 Q2] [R1; 0]``.

    Attributes
    ----------
    rows : tuple of int
        The active rows (sorted); ``idx`` the same as an array.
    bounds : tuple of (int, int, float)
        ``(i, j, C_ij)`` for each active row ``i`` on a single variable ``j``: the solution has
        ``z_j = h_i / C_ij`` exactly. ``b_rows``, ``b_vars``, ``b_coef``: the same as arrays.
    gen : (s_g,) int array
        The general active rows; ``ia`` and ``iu`` index the pivot rows and the others in it.
    S, c : (s_a,)
        The pivot rows' slacks and their coefficients.
    N : (d_n,) int array
        The remaining free variables.
    used, Dc_used : (d_n,)
        Variables in a reduced row, and their Ruiz scaling (1 for the others).
    Dn : (s_u,)
        The full scaling of the reduced rows (Ruiz, then unit norm).
    CgB : (s_g, s_b)
        The general rows on the fixed variables.
    CaN, CuS, E : (s_a, d_n), (s_u, s_a), (s_u, s_a)
        The pivot rows on ``N``, the other rows on the slacks, ``CuS / c``.
    Q1 : (d_n, s_u), Q2 : (d_n, d_n - s_u)
    Lmap : (s_u, d_n)
        ``R1^{-1} Q1'``: the reduced rows' scaled multipliers from the stationarity residual.
    Zp : (d_n, s_u)
        The particular solution ``z~_p = Zp r_u`` (``Q1 R1^{-T} Dn``); ``Tp`` the magnitude of
        its terms, per datum (``|Q1| |R1^{-T}| Dn``).
    """

    rows: tuple[int, ...]
    idx: np.ndarray
    bounds: tuple
    b_rows: np.ndarray
    b_vars: np.ndarray
    b_coef: np.ndarray
    gen: np.ndarray
    ia: np.ndarray
    iu: np.ndarray
    S: np.ndarray
    c: np.ndarray
    N: np.ndarray
    used: np.ndarray
    Dc_used: np.ndarray
    Dn: np.ndarray
    CgB: np.ndarray
    CaN: np.ndarray
    CuS: np.ndarray
    E: np.ndarray
    Q1: np.ndarray
    Q2: np.ndarray
    Lmap: np.ndarray
    Zp: np.ndarray
    Tp: np.ndarray
    n_rows: int  # rows of C (the instance has d + n_rows entries)
    absQ2: np.ndarray = field(init=False, repr=False)
    absLmap: np.ndarray = field(init=False, repr=False)
    consts: dict = field(init=False, repr=False)  # derived arrays used by every solve

    def __post_init__(self) -> None:
        object.__setattr__(self, "absQ2", np.abs(self.Q2))
        object.__setattr__(self, "absLmap", np.abs(self.Lmap))
        coef = self.b_coef[:, None]
        d = self.used.size + self.b_vars.size + self.S.size
        N, bv = self.N, self.b_vars
        consts = {
            # flat indices of P's blocks: P[N, N], P[N, bv] and P's diagonal at N
            "NN": (N[:, None] * d + N[None, :]).ravel(),
            "NB": (N[:, None] * d + bv[None, :]).ravel(),
            "BP": (bv[:, None] * d + np.arange(d)[None, :]).ravel(),
            "diagN": N * (d + 1),
            "inv_b": 1.0 / coef,
            "unit_b": bool(np.all(np.abs(self.b_coef) == 1.0)),
            "abs_inv_b": 1.0 / np.abs(coef),
            "absCgB": np.abs(self.CgB),
            "absE": np.abs(self.E),
            "absCaN": np.abs(self.CaN),
            "absCuS": np.abs(self.CuS),
            "abs_inv_c": 1.0 / np.abs(self.c[:, None]),
            # where each multiplier goes in the order of the rows
            "at_u": np.searchsorted(self.idx, self.gen[self.iu]),
            "at_a": np.searchsorted(self.idx, self.gen[self.ia]),
            "at_b": np.searchsorted(self.idx, self.b_rows),
        }
        # the products of solve_stacked act on [values; magnitudes] stacked: one product per step with
        # the block-diagonal operator [[A, 0], [0, +-|A|]] (the sign makes the magnitudes add)
        consts.update(
            CgB2=_blocks(self.CgB, -np.abs(self.CgB)),
            E2=_blocks(self.E, -np.abs(self.E)),
            CaN2=_blocks(self.CaN, -np.abs(self.CaN)),
            CaNT2=_blocks(self.CaN.T, -np.abs(self.CaN.T)),
            CuST2=_blocks(self.CuS.T, np.abs(self.CuS.T)),
            CgBT2=_blocks(self.CgB.T, np.abs(self.CgB.T)),
            Zp2=_blocks(self.Zp, self.Tp),
            Q22=_blocks(self.Q2, np.abs(self.Q2)),
            Lmap2=_blocks(-self.Lmap, np.abs(self.Lmap)),
            Dn2=np.concatenate([self.Dn, self.Dn])[:, None],
            inv_b2=np.concatenate([1.0 / self.b_coef, 1.0 / np.abs(self.b_coef)])[:, None],
            lam_b2=np.concatenate([-1.0 / self.b_coef, 1.0 / np.abs(self.b_coef)])[:, None],
            inv_c2=np.concatenate([1.0 / self.c, 1.0 / np.abs(self.c)])[:, None],
            lam_c2=np.concatenate([-1.0 / self.c, 1.0 / np.abs(self.c)])[:, None],
        )
        # the rows of both halves of the stacked arrays (see _two)
        width, s_all, g_n = d + self.n_rows, self.idx.size, self.gen.size
        consts.update(
            hb2=_two(d + self.b_rows, width),
            gen2=_two(d + self.gen, width),
            ia2=_two(self.ia, g_n),
            iu2=_two(self.iu, g_n),
            qN2=_two(N, width),
            qS2=_two(self.S, width),
            qB2=_two(bv, width),
            zN2=_two(N, d),
            zS2=_two(self.S, d),
            zB2=_two(bv, d),
            at_u2=_two(consts["at_u"], s_all),
            at_a2=_two(consts["at_a"], s_all),
            at_b2=_two(consts["at_b"], s_all),
        )
        object.__setattr__(self, "consts", consts)

    @property
    def floats(self) -> int:
        """Floats held (for cache budgets)."""
        return sum(
            a.size
            for a in (self.Q1, self.Q2, self.Lmap, self.Zp, self.Tp, self.absQ2, self.absLmap)
        ) + 2 * (self.CgB.size + self.CaN.size + self.CuS.size)


def active_set_factor(
    C: np.ndarray, rows: tuple[int, ...], pivots: np.ndarray | None = None
) -> ActiveSetFactor | None:
    """The :class:`ActiveSetFactor` of ``rows`` of ``C``, or None when the active rows are not
    a candidate: two bounds on one variable, more active rows than variables, or reduced rows
    whose scaled, normalized forms are linearly dependent or cancel their terms to round-off.
    ``pivots`` (d,) bool: the variables that may be pivot slacks (their rows of ``P`` must be
    zero: the slacks of the receding-horizon QPs); None for none."""
    d = C.shape[1]
    if len(rows) > d:
        return None
    idx = np.array(rows, dtype=np.int64)
    CS = C[idx]
    nonzero = CS != 0.0
    single = nonzero.sum(axis=1) == 1
    b_rows = idx[single]
    b_vars = np.argmax(nonzero[single], axis=1).astype(np.int64)
    if np.unique(b_vars).size != b_vars.size:
        return None  # two bounds on one variable
    b_coef = CS[single, b_vars] if b_vars.size else np.zeros(0)
    gen = idx[~single]
    fixed = np.zeros(d, dtype=bool)
    fixed[b_vars] = True
    # pivot rows: a general row with one nonzero among the free pivot slacks, on a slack that
    # no earlier pivot row took
    ia_list, S_list = [], []
    if pivots is not None and gen.size:
        cand = pivots & ~fixed
        taken = np.zeros(d, dtype=bool)
        on = (C[gen] != 0.0) & cand[None, :]
        for n in np.flatnonzero(on.sum(axis=1) == 1).tolist():
            j = int(np.flatnonzero(on[n])[0])
            if not taken[j]:
                taken[j] = True
                ia_list.append(n)
                S_list.append(j)
    ia = np.array(ia_list, dtype=np.int64)
    S = np.array(S_list, dtype=np.int64)
    iu = np.setdiff1d(np.arange(gen.size), ia)
    rest = ~fixed
    rest[S] = False
    N = np.flatnonzero(rest)
    Cg = C[gen]
    c_piv = Cg[ia, S] if S.size else np.zeros(0)
    CaN = Cg[ia][:, N]
    CuS = Cg[iu][:, S]
    E = CuS / c_piv[None, :] if S.size else np.zeros((iu.size, 0))
    Cr = Cg[iu][:, N] - E @ CaN  # the other rows with the pivot slacks substituted
    s, d_n = iu.size, N.size
    if s > d_n:
        return None
    Dc, Dr, used = _ruiz(Cr, d_n)
    if s:
        Ct = Cr * Dr[:, None] * Dc[None, :]
        norms = np.sqrt(np.einsum("ij,ij->i", Ct, Ct))
        # a reduced row must not be round-off of its terms (rows 2.3e-12 apart: multipliers 1e24)
        Mt = (np.abs(Cg[iu][:, N]) + np.abs(E) @ np.abs(CaN)) * Dr[:, None] * Dc[None, :]
        if not np.all(norms > _RANK_TOL * np.sqrt(np.einsum("ij,ij->i", Mt, Mt))):
            return None
        Dn = Dr / norms  # the full row scaling of the reduced rows
        Chat = Cr * Dn[:, None] * Dc[None, :]
        Q, Rfull = np.linalg.qr(Chat.T, mode="complete")
        R1 = Rfull[:s, :s]
        if not np.all(np.abs(np.diag(R1)) > _RANK_TOL):  # normalized rows: a scale-free test
            return None
        Q1, Q2 = Q[:, :s], np.ascontiguousarray(Q[:, s:])
        R1inv_T = np.linalg.inv(R1.T)
        Zp = Q1 @ (R1inv_T * Dn[None, :])
        # magnitude of the terms summed to compute z~_p, per datum (absolute values carried
        # through every product, so that cancellations are not mistaken for small terms)
        Tp = np.abs(Q1) @ (np.abs(R1inv_T) * Dn[None, :])
        Lmap = np.linalg.solve(R1, Q1.T)
    else:
        Dn = np.zeros(0)
        Q1, Q2 = np.zeros((d_n, 0)), np.eye(d_n)
        Zp, Tp, Lmap = np.zeros((d_n, 0)), np.zeros((d_n, 0)), np.zeros((0, d_n))
    if not (np.all(np.isfinite(Zp)) and np.all(np.isfinite(Lmap)) and np.all(np.isfinite(E))):
        return None
    bounds = tuple(
        (int(i), int(j), float(a)) for i, j, a in zip(b_rows, b_vars, b_coef, strict=True)
    )
    return ActiveSetFactor(
        rows=tuple(int(i) for i in rows),
        idx=idx,
        bounds=bounds,
        b_rows=b_rows,
        b_vars=b_vars,
        b_coef=b_coef,
        gen=gen,
        ia=ia,
        iu=iu,
        S=S,
        c=c_piv,
        N=N,
        used=used,
        Dc_used=Dc,
        Dn=Dn,
        CgB=Cg[:, b_vars],
        CaN=CaN,
        CuS=CuS,
        E=E,
        Q1=Q1,
        Q2=Q2,
        Lmap=Lmap,
        Zp=Zp,
        Tp=Tp,
        n_rows=C.shape[0],
    )


def _free_scaling(fac: ActiveSetFactor, flat: np.ndarray) -> np.ndarray:
    """``Dc`` of the variables ``N``: the Ruiz scaling of those in a reduced row; one in no
    reduced row is scaled by its curvature, ``1 / sqrt(P_jj)`` (1 where ``P_jj = 0``).
    Variables of very different sizes (an offset of 1 next to a slack of 1e12, rows scaled by
    1e-11) then get comparable scaled sizes, and rank and conditioning are judged in them.
    ``flat``: ``P`` raveled."""
    if fac.used.all():
        return fac.Dc_used
    diag = np.abs(flat[fac.consts["diagN"]])
    loose = ~fac.used & (diag > 0.0)
    if not loose.any():
        return fac.Dc_used
    Dc = fac.Dc_used.copy()
    Dc[loose] = 1.0 / np.sqrt(diag[loose])
    return Dc


def _scaled_inverse(M: np.ndarray, Q2: np.ndarray) -> np.ndarray | None:
    """``-M^{-1} Q2'`` with ``M`` judged positive definite once its diagonal is scaled to 1
    (nodes of path probability 1e-12 give directions of curvature 1e-13 times the others, which
    that scaling makes definite), else None."""
    dm = np.sqrt(np.abs(np.diag(M)))
    if not np.all(dm > 0.0):
        return None
    eig, vecs = np.linalg.eigh(M / dm[:, None] / dm[None, :])
    if not (eig[-1] > 0.0 and eig[0] > _PD_TOL * eig[-1]):
        return None
    return -((vecs / eig) @ (vecs.T @ (Q2.T / dm[:, None]))) / dm[:, None]


def reduce_hessian(fac: ActiveSetFactor, P: np.ndarray):
    """The part of the solve that depends on ``P``: ``(Dc, Pt, Y, P_NB, ops)`` with ``Pt`` the
    scaled Hessian of the variables ``N``, ``Y = -(Q2' Pt Q2)^{-1} Q2'`` (d_n - s_u, d_n), so
    that ``y = Y (q~ + Pt z~_p)``, ``P_NB`` the coupling of ``N`` to the fixed variables (None
    where it is zero) and ``ops`` the block-diagonal forms of :func:`solve_stacked`; None when the
    reduced Hessian is not positive definite (the minimizer is not unique), relative to its
    scale, or when a pivot slack has curvature."""
    if fac.S.size and np.any(P[fac.S]):
        return None
    N = fac.N
    flat = P.ravel()
    Dc = _free_scaling(fac, flat)
    dn = N.size
    Pt = flat[fac.consts["NN"]].reshape(dn, dn) * Dc[:, None] * Dc[None, :]
    P_NB = None
    if fac.b_vars.size:
        P_NB = flat[fac.consts["NB"]].reshape(dn, fac.b_vars.size)
        if not P_NB.any():
            P_NB = None
    if fac.Q2.shape[1]:
        Q2 = fac.Q2
        M = Q2.T @ Pt @ Q2
        M = 0.5 * (M + M.T)
        eig, vecs = np.linalg.eigh(M)
        if eig[-1] > 0.0 and eig[0] > _PD_TOL * eig[-1]:
            Y = -((vecs / eig) @ (vecs.T @ Q2.T))
        else:
            Y = _scaled_inverse(M, Q2)
            if Y is None:
                return None
    else:
        Y = np.zeros((0, dn))
    absPt = np.abs(Pt)
    ops = {"Pt2": _blocks(Pt, absPt), "Dc2": np.concatenate([Dc, Dc])[:, None]}
    if Y.shape[0]:
        ops["Y2"] = _blocks(Y, np.abs(Y))
    if P_NB is not None:
        ops["PNB2"] = _blocks(P_NB, np.abs(P_NB))
    if fac.b_vars.size:
        Pb = flat[fac.consts["BP"]].reshape(fac.b_vars.size, P.shape[0])
        ops["Pb2"] = _blocks(Pb, np.abs(Pb))
    return Dc, Pt, Y, P_NB, ops


def solve_stacked(
    fac: ActiveSetFactor, red: tuple, P: np.ndarray, W2: np.ndarray, maps: tuple | None = None
):
    """The exact solution of the active set for the instances ``W`` (d + c, k) given stacked
    with the magnitudes of their entries, ``W2 = [W; |W|]`` (``|W|``: the identity for the
    maps), and the magnitude of the terms of every quantity.

    Returns ``(z2, lam2)``: ``[z; T_z]`` (2 d, k) and ``[lam; T_lam]`` (2 s, k), the
    multipliers in the order of ``fac.rows`` (of the sign of each row's multiplier; scaled for
    the reduced rows) and the magnitudes of the terms summed to compute them. Each step is one
    product with a block-diagonal operator (:attr:`ActiveSetFactor.consts`) on the stacked
    values and magnitudes. The same products serve the maps (:func:`active_set_maps`) and one
    instance (:func:`check_active_set`); the parts that are empty for this active set (no
    bound, no pivot row, no null space) are skipped. ``maps``: these products as two matrices
    (:func:`controllers.kkt_maps.stacked_maps`), applied instead when given."""
    if maps is not None:
        return maps[0] @ W2, maps[1] @ W2
    Dc, Pt, Y, P_NB, ops = red
    d = P.shape[0]
    k = W2.shape[1]
    nb, ns, nu = fac.b_vars.size, fac.S.size, fac.iu.size
    cache = fac.consts
    if nb:  # the fixed variables, exactly: h / C_ij (a product by 1 / C_ij when it is +-1)
        zB = W2[cache["hb2"]]
        if cache["unit_b"]:
            zB = zB * cache["inv_b2"]
        else:
            zB[:nb] /= fac.b_coef[:, None]
            zB[nb:] *= cache["abs_inv_b"]
    # the general rows' right side, less the fixed part; the pivot slacks substituted
    rg = W2[cache["gen2"]]
    if nb and fac.gen.size:
        rg = rg - cache["CgB2"] @ zB
    if ns:
        ra = rg[cache["ia2"]]
        ru = rg[cache["iu2"]] - cache["E2"] @ ra
    else:
        ru = rg
    # the scaled linear term on N
    qN = W2[cache["qN2"]]
    if P_NB is not None:
        qN = qN + ops["PNB2"] @ zB
    if ns:
        qN = qN - cache["CaNT2"] @ (W2[cache["qS2"]] * cache["inv_c2"])
    qt = ops["Dc2"] * qN
    if nu:
        zt = cache["Zp2"] @ ru  # the particular solution (scaled variables N)
        if Y.shape[0]:
            zt = zt + cache["Q22"] @ (ops["Y2"] @ (qt + ops["Pt2"] @ zt))
    elif Y.shape[0]:  # no reduced row: the minimizer of the scaled objective on N
        zt = ops["Y2"] @ qt
    else:  # no variable left
        zt = np.zeros((0, k))
    zN = ops["Dc2"] * zt
    z2 = np.empty((2 * d, k))
    z2[cache["zN2"]] = zN
    if nb:
        z2[cache["zB2"]] = zB
    if ns:  # the pivot slacks, from their rows
        z2[cache["zS2"]] = (ra - cache["CaN2"] @ zN) * cache["inv_c2"]
    # multipliers: the reduced rows' from stationarity on N (scaled: Pt z~ + q~ + Chat' lam^ = 0,
    # lam^ of the sign of the row's multiplier), the pivot rows' from their slacks',
    # q_s + c lam_a + C_uS' lam_u = 0, the bounds' from the fixed variables',
    # (P z + q + C_g' lam_g)_j + C_ij lam_i = 0
    s_all = fac.idx.size
    lam2 = np.empty((2 * s_all, k))
    if nu:
        lam_hat = cache["Lmap2"] @ (ops["Pt2"] @ zt + qt)
        lam2[cache["at_u2"]] = lam_hat
        if ns or nb:
            lam_u = cache["Dn2"] * lam_hat
    if ns:
        q_s = W2[cache["qS2"]]
        if nu:
            q_s = q_s + cache["CuST2"] @ lam_u
        lam_a = q_s * cache["lam_c2"]
        lam2[cache["at_a2"]] = lam_a
    if nb:
        stat = ops["Pb2"] @ z2 + W2[cache["qB2"]]
        if fac.gen.size:
            lam_g = np.empty((2 * fac.gen.size, k))
            if nu:
                lam_g[cache["iu2"]] = lam_u
            if ns:
                lam_g[cache["ia2"]] = lam_a
            stat = stat + cache["CgBT2"] @ lam_g
        lam2[cache["at_b2"]] = stat * cache["lam_b2"]
    return z2, lam2


def check_active_set(
    fac: ActiveSetFactor,
    P: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    absC: np.ndarray | None = None,
    report: dict | None = None,
    red: tuple | None = None,
    maps: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[float] | None:
    """``z`` (a list of d floats) if the active set of ``fac`` passes the KKT test at the
    instance ``w`` of ``min 1/2 z'Pz + q'z  s.t.  C z <= h``, else None.

    The test of :meth:`ActiveSetMaps.check` of :func:`active_set_maps`, computed for the one
    instance (the same products, applied to ``w``). ``absC``: ``|C|``, when the caller keeps
    it. ``report``: a dict that receives, when the test fails, ``"add"`` (the inactive rows
    violated beyond their tolerance, most violated first, relative to it) and ``"drop"`` (the
    active rows whose multipliers are negative beyond their tolerance); both empty when the set
    is not a candidate. ``red``: :func:`reduce_hessian` of ``fac`` and ``P``, when the caller
    has it; ``maps``: see :func:`solve_stacked`.
    """
    if report is not None:
        report.update(add=[], drop=[])
    red = reduce_hessian(fac, P) if red is None else red
    if red is None:
        return None
    d, s_all, gen = P.shape[0], fac.idx.size, fac.gen
    h = w[d:]
    absC = np.abs(C) if absC is None else absC
    with np.errstate(over="ignore", invalid="ignore"):  # a number not finite fails below
        z2, lam2 = solve_stacked(fac, red, P, np.concatenate([w, np.abs(w)])[:, None], maps)
        z, lam, lam_T = z2[:d, 0], lam2[:s_all, 0], lam2[s_all:, 0]
        primal = C @ z - h  # every row, at the returned z, against its own terms
        primal_T = absC @ np.abs(z) + np.abs(h)
        if gen.size and np.any(np.abs(primal[gen]) > KKT_TOL * primal_T[gen]):
            # one step of iterative refinement on the general rows (see ActiveSetMaps)
            r = np.zeros_like(w)
            r[d + gen] = primal[gen]
            dz2 = solve_stacked(fac, red, P, np.concatenate([r, np.abs(r)])[:, None], maps)[0]
            z = z - dz2[:d, 0]
            z[fac.b_vars] = h[fac.b_rows] / fac.b_coef
            primal = C @ z - h
            primal_T = absC @ np.abs(z) + np.abs(h)
    primal[fac.idx] = np.abs(primal[fac.idx])  # the active rows are equalities
    resid = np.concatenate([primal, -lam])
    terms = np.concatenate([primal_T, lam_T])
    worst = float(resid.max(initial=-math.inf))
    if not (math.isfinite(worst + float(z.sum())) and np.all(np.isfinite(terms))):
        return None
    if worst > 0.0 and not np.all(resid <= KKT_TOL * terms):
        if report is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                excess = np.where(resid > KKT_TOL * terms, resid / np.maximum(terms, 1e-300), 0.0)
            c = C.shape[0]
            inactive = excess[:c].copy()
            inactive[fac.idx] = 0.0
            add = np.flatnonzero(inactive > 0.0)
            report["add"] = add[np.argsort(-inactive[add], kind="stable")].tolist()
            report["drop"] = fac.idx[excess[c:] > 0.0].tolist()
        return None
    negative = lam < 0.0
    if negative.any() and not confirm_multipliers(P, C, fac.rows, w, negative, z):
        if report is not None:
            report["drop"] = fac.idx[negative].tolist()
        return None
    return z.tolist()
