"""The factor of an active set: the part of its exact solve that depends only on ``C`` and the
rows (see :mod:`controllers.kkt`, which solves and tests with it).

:func:`active_set_factor` splits the active rows into bounds, pivot rows and the reduced rows
(:class:`ActiveSetFactor` says what each is), refuses a set that is not a candidate, and
factors the reduced rows (Ruiz scaling, row normalization, QR) for the null-space method.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ActiveSetFactor", "active_set_factor", "blocks", "halves"]

#: Rank threshold of the reduced rows, relative to the scale of their terms.
_RANK_TOL = 1e-11


def _ruiz(CS: np.ndarray, d: int, sweeps: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Dc, Dr, used)``: Ruiz equilibration of the rows ``CS`` (every row and every column of
    ``Dr CS Dc`` then has its largest entry near 1); ``Dc = 1`` for a variable in no row
    (``used`` False), which :func:`controllers.kkt.reduce_hessian` scales by its curvature."""
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


def blocks(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The block-diagonal ``[[A, 0], [0, B]]``."""
    out = np.zeros((A.shape[0] + B.shape[0], A.shape[1] + B.shape[1]))
    out[: A.shape[0], : A.shape[1]], out[A.shape[0] :, A.shape[1] :] = A, B
    return out


def halves(index: np.ndarray, offset: int) -> np.ndarray:
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
    in a reduced row and the curvature scaling of :func:`controllers.kkt.reduce_hessian` for
    the others, and
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
            CgB2=blocks(self.CgB, -np.abs(self.CgB)),
            E2=blocks(self.E, -np.abs(self.E)),
            CaN2=blocks(self.CaN, -np.abs(self.CaN)),
            CaNT2=blocks(self.CaN.T, -np.abs(self.CaN.T)),
            CuST2=blocks(self.CuS.T, np.abs(self.CuS.T)),
            CgBT2=blocks(self.CgB.T, np.abs(self.CgB.T)),
            Zp2=blocks(self.Zp, self.Tp),
            Q22=blocks(self.Q2, np.abs(self.Q2)),
            Lmap2=blocks(-self.Lmap, np.abs(self.Lmap)),
            Dn2=np.concatenate([self.Dn, self.Dn])[:, None],
            inv_b2=np.concatenate([1.0 / self.b_coef, 1.0 / np.abs(self.b_coef)])[:, None],
            lam_b2=np.concatenate([-1.0 / self.b_coef, 1.0 / np.abs(self.b_coef)])[:, None],
            inv_c2=np.concatenate([1.0 / self.c, 1.0 / np.abs(self.c)])[:, None],
            lam_c2=np.concatenate([-1.0 / self.c, 1.0 / np.abs(self.c)])[:, None],
        )
        # the rows of both halves of the stacked arrays (see halves)
        width, s_all, g_n = d + self.n_rows, self.idx.size, self.gen.size
        consts.update(
            hb2=halves(d + self.b_rows, width),
            gen2=halves(d + self.gen, width),
            ia2=halves(self.ia, g_n),
            iu2=halves(self.iu, g_n),
            qN2=halves(N, width),
            qS2=halves(self.S, width),
            qB2=halves(bv, width),
            zN2=halves(N, d),
            zS2=halves(self.S, d),
            zB2=halves(bv, d),
            at_u2=halves(consts["at_u"], s_all),
            at_a2=halves(consts["at_a"], s_all),
            at_b2=halves(consts["at_b"], s_all),
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
    split = _bounds(C[idx], idx)
    if split is None:
        return None  # two bounds on one variable
    b_rows, b_vars, b_coef, gen = split
    fixed = np.zeros(d, dtype=bool)
    fixed[b_vars] = True
    ia, S = _pivot_rows(C[gen], pivots & ~fixed if pivots is not None else None)
    iu = np.setdiff1d(np.arange(gen.size), ia)
    rest = ~fixed
    rest[S] = False
    N = np.flatnonzero(rest)
    Cg = C[gen]
    c_piv = Cg[ia, S] if S.size else np.zeros(0)
    CaN = Cg[ia][:, N]
    CuS = Cg[iu][:, S]
    E = CuS / c_piv[None, :] if S.size else np.zeros((iu.size, 0))
    if iu.size > N.size:
        return None
    reduced = _reduced_rows(Cg[iu][:, N], E, CaN)
    if reduced is None:
        return None
    used, Dc, Dn, Q1, Q2, Zp, Tp, Lmap = reduced
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


def _bounds(
    CS: np.ndarray, idx: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """``(b_rows, b_vars, b_coef, gen)`` of the active rows ``CS`` (rows ``idx`` of ``C``): the
    rows on a single variable, that variable and its coefficient, and the general rows; None
    when two bounds fix one variable."""
    nonzero = CS != 0.0
    single = nonzero.sum(axis=1) == 1
    b_vars = np.argmax(nonzero[single], axis=1).astype(np.int64)
    if np.unique(b_vars).size != b_vars.size:
        return None
    b_coef = CS[single, b_vars] if b_vars.size else np.zeros(0)
    return idx[single], b_vars, b_coef, idx[~single]


def _pivot_rows(Cg: np.ndarray, candidates: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``(ia, S)``: the pivot rows among the general rows ``Cg`` (positions) and their slacks, a
    general row with one nonzero among the free pivot slacks ``candidates`` (a mask; None for
    none), on a slack that no earlier pivot row took."""
    ia_list, S_list = [], []
    if candidates is not None and Cg.shape[0]:
        taken = np.zeros(candidates.size, dtype=bool)
        on = (Cg != 0.0) & candidates[None, :]
        for n in np.flatnonzero(on.sum(axis=1) == 1).tolist():
            j = int(np.flatnonzero(on[n])[0])
            if not taken[j]:
                taken[j] = True
                ia_list.append(n)
                S_list.append(j)
    return np.array(ia_list, dtype=np.int64), np.array(S_list, dtype=np.int64)


def _reduced_rows(CuN: np.ndarray, E: np.ndarray, CaN: np.ndarray) -> tuple | None:
    """The factor of the reduced rows ``C_uN - E C_aN`` (the other general rows with the pivot
    slacks substituted) on the free variables: ``(used, Dc, Dn, Q1, Q2, Zp, Tp, Lmap)`` (see
    :class:`ActiveSetFactor`); None when a row is round-off of its terms or the rows are
    linearly dependent, judged scaled and normalized."""
    Cr = CuN - E @ CaN
    s, d_n = Cr.shape
    Dc, Dr, used = _ruiz(Cr, d_n)
    if not s:
        Q1, Q2 = np.zeros((d_n, 0)), np.eye(d_n)
        Zp, Tp, Lmap = np.zeros((d_n, 0)), np.zeros((d_n, 0)), np.zeros((0, d_n))
        return used, Dc, np.zeros(0), Q1, Q2, Zp, Tp, Lmap
    Ct = Cr * Dr[:, None] * Dc[None, :]
    norms = np.sqrt(np.einsum("ij,ij->i", Ct, Ct))
    # a reduced row must not be round-off of its terms (rows 2.3e-12 apart: multipliers 1e24)
    Mt = (np.abs(CuN) + np.abs(E) @ np.abs(CaN)) * Dr[:, None] * Dc[None, :]
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
    return used, Dc, Dn, Q1, Q2, Zp, Tp, Lmap
