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
only on ``C`` and ``S``, :mod:`controllers.kkt_factor`) and one :func:`reduce_hessian` (the part that depends on ``P``): the
maps over the whole ``w`` (:mod:`controllers.kkt_maps`; P3 and its enumeration, whose Hessian
is fixed, and the scenario tree's pairs of Hessian and active set met again) and
:func:`check_active_set` (one instance, for the scenario tree, whose Hessian changes). A third,
:class:`HessianFreeMaps`, serves an active set whose rows fix every variable under a Hessian
that changes (the belief controller's): ``z`` does not depend on ``P``, so the maps at ``P = 0``
are kept and ``P z`` is added to the linear term per instance; the test that follows is
:func:`check_active_set`'s (``tests/test_kkt_hessian_free.py`` compares the forms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .kkt_confirm import CONFIRM_TOL, confirm_multipliers
from .kkt_factor import ActiveSetFactor, active_set_factor, blocks

__all__ = [
    "CONFIRM_TOL",
    "KKT_TOL",
    "ActiveSetFactor",
    "HessianFreeMaps",
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

#: Definiteness threshold of the exact solve, relative to the scale of the reduced Hessian.
_PD_TOL = 1e-12


@dataclass(frozen=True, eq=False)
class HessianFreeMaps:
    """:func:`solve_stacked` of an active set whose rows fix every variable (no null space, so
    no variable scaled by its curvature), as two matrices built once for any Hessian
    (:func:`controllers.kkt_maps.hessian_free_maps`): ``z`` does not depend on ``P``, and the
    Hessian enters the multipliers only through the products ``P z`` (stationarity on the free
    variables, the coupling to the fixed ones, the bounds' rows). ``Fz`` and ``Fl`` are the
    products at ``P = 0``; :meth:`solve` adds ``P z`` to the linear term (and ``|P| T_z`` to its
    magnitude, as the products do) before ``Fl``. The same numbers as the step-by-step products
    up to round-off, for a Hessian that changes at every instance (the belief controller's)."""

    Fz: np.ndarray
    Fl: np.ndarray

    def solve(self, P: np.ndarray, W2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(z2, lam2)`` of :func:`solve_stacked` for the Hessian ``P`` and instances ``W2``."""
        z2 = self.Fz @ W2
        d, width = P.shape[0], W2.shape[0] // 2
        G2 = W2.copy()
        G2[:d] += P @ z2[:d]
        G2[width : width + d] += np.abs(P) @ z2[d:]
        return z2, self.Fl @ G2


def _pivot_has_curvature(fac: ActiveSetFactor, P: np.ndarray) -> bool:
    """Whether a pivot slack of ``fac`` has curvature in ``P``: its row then does not give the
    slack exactly, and the active set is not a candidate (every form of the solve tests this)."""
    return bool(fac.S.size) and bool(P[fac.S].any())


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
    if _pivot_has_curvature(fac, P):
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
    ops = {"Pt2": blocks(Pt, absPt), "Dc2": np.concatenate([Dc, Dc])[:, None]}
    if Y.shape[0]:
        ops["Y2"] = blocks(Y, np.abs(Y))
    if P_NB is not None:
        ops["PNB2"] = blocks(P_NB, np.abs(P_NB))
    if fac.b_vars.size:
        Pb = flat[fac.consts["BP"]].reshape(fac.b_vars.size, P.shape[0])
        ops["Pb2"] = blocks(Pb, np.abs(Pb))
    return Dc, Pt, Y, P_NB, ops


def solve_stacked(
    fac: ActiveSetFactor,
    red: tuple | None,
    P: np.ndarray,
    W2: np.ndarray,
    maps: tuple | HessianFreeMaps | None = None,
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
    (:func:`controllers.kkt_maps.stacked_maps`), applied instead when given, or
    :class:`HessianFreeMaps` (``red`` is then not read)."""
    if isinstance(maps, HessianFreeMaps):
        return maps.solve(P, W2)
    if maps is not None:
        return maps[0] @ W2, maps[1] @ W2
    assert red is not None
    _, _, Y, P_NB, ops = red
    k = W2.shape[1]
    zB = _fixed_variables(fac, W2) if fac.b_vars.size else None
    ra, ru = _general_sides(fac, W2, zB)
    coupling = None if P_NB is None else ops["PNB2"] @ zB  # P_NB: some fixed variables
    qt = ops["Dc2"] * _linear_term(fac, W2, coupling)
    zt = _reduced_solution(fac, Y, ops, ru, qt, k)
    z2 = _primal(fac, P.shape[0], ops["Dc2"] * zt, zB, ra, k)
    return z2, _multipliers(fac, ops, zt, qt, z2, W2)


# The steps of solve_stacked, each on stacked values and magnitudes [v; T_v].
def _fixed_variables(fac: ActiveSetFactor, W2: np.ndarray) -> np.ndarray:
    """The fixed variables, exactly: ``h / C_ij`` (a product by ``1 / C_ij`` when it is +-1)."""
    cache = fac.consts
    zB = W2[cache["hb2"]]
    if cache["unit_b"]:
        return zB * cache["inv_b2"]
    nb = fac.b_vars.size
    zB[:nb] /= fac.b_coef[:, None]
    zB[nb:] *= cache["abs_inv_b"]
    return zB


def _general_sides(
    fac: ActiveSetFactor, W2: np.ndarray, zB: np.ndarray | None
) -> tuple[np.ndarray | None, np.ndarray]:
    """``(ra, ru)``: the general rows' right side less the fixed part, of the pivot rows (None
    without any) and of the reduced rows (the pivot slacks substituted)."""
    cache = fac.consts
    rg = W2[cache["gen2"]]
    if zB is not None and fac.gen.size:
        rg = rg - cache["CgB2"] @ zB
    if not fac.S.size:
        return None, rg
    ra = rg[cache["ia2"]]
    return ra, rg[cache["iu2"]] - cache["E2"] @ ra


def _linear_term(fac: ActiveSetFactor, W2: np.ndarray, coupling: np.ndarray | None) -> np.ndarray:
    """The linear term on the variables ``N`` (unscaled): ``q_N``, plus the ``coupling`` to the
    fixed variables ``P_NB z_B`` (None where it is zero), less the pivot slacks' part."""
    cache = fac.consts
    qN = W2[cache["qN2"]]
    if coupling is not None:
        qN = qN + coupling
    if fac.S.size:
        qN = qN - cache["CaNT2"] @ (W2[cache["qS2"]] * cache["inv_c2"])
    return qN


def _reduced_solution(
    fac: ActiveSetFactor, Y: np.ndarray, ops: dict, ru: np.ndarray, qt: np.ndarray, k: int
) -> np.ndarray:
    """``z~`` on the scaled variables ``N``: the particular solution of the reduced rows plus
    the minimizer on their null space."""
    cache = fac.consts
    if fac.iu.size:
        zt = cache["Zp2"] @ ru  # the particular solution (scaled variables N)
        if Y.shape[0]:
            zt = zt + cache["Q22"] @ (ops["Y2"] @ (qt + ops["Pt2"] @ zt))
        return zt
    if Y.shape[0]:  # no reduced row: the minimizer of the scaled objective on N
        return ops["Y2"] @ qt
    return np.zeros((0, k))  # no variable left


def _primal(
    fac: ActiveSetFactor,
    d: int,
    zN: np.ndarray,
    zB: np.ndarray | None,
    ra: np.ndarray | None,
    k: int,
) -> np.ndarray:
    """``z`` (2 d, k) from its parts: the variables ``N``, the fixed ones and the pivot
    slacks (from their rows)."""
    cache = fac.consts
    z2 = np.empty((2 * d, k))
    z2[cache["zN2"]] = zN
    if zB is not None:
        z2[cache["zB2"]] = zB
    if ra is not None:
        z2[cache["zS2"]] = (ra - cache["CaN2"] @ zN) * cache["inv_c2"]
    return z2


def _multipliers(
    fac: ActiveSetFactor, ops: dict, zt: np.ndarray, qt: np.ndarray, z2: np.ndarray, W2: np.ndarray
) -> np.ndarray:
    """The multipliers in the order of ``fac.rows``: the reduced rows' from stationarity on
    ``N`` (scaled: ``Pt z~ + q~ + Chat' lam^ = 0``, ``lam^`` of the sign of the row's
    multiplier), the pivot rows' from their slacks', ``q_s + c lam_a + C_uS' lam_u = 0``, the
    bounds' from the fixed variables', ``(P z + q + C_g' lam_g)_j + C_ij lam_i = 0``."""
    cache = fac.consts
    lam2 = np.empty((2 * fac.idx.size, W2.shape[1]))
    lam_u = lam_a = None
    if fac.iu.size:
        lam_hat = cache["Lmap2"] @ (ops["Pt2"] @ zt + qt)
        lam2[cache["at_u2"]] = lam_hat
        if fac.S.size or fac.b_vars.size:
            lam_u = cache["Dn2"] * lam_hat
    if fac.S.size:
        q_s = W2[cache["qS2"]]
        if lam_u is not None:
            q_s = q_s + cache["CuST2"] @ lam_u
        lam_a = q_s * cache["lam_c2"]
        lam2[cache["at_a2"]] = lam_a
    if fac.b_vars.size:
        stat = ops["Pb2"] @ z2 + W2[cache["qB2"]]
        if fac.gen.size:
            lam_g = np.empty((2 * fac.gen.size, W2.shape[1]))
            if lam_u is not None:
                lam_g[cache["iu2"]] = lam_u
            if lam_a is not None:
                lam_g[cache["ia2"]] = lam_a
            stat = stat + cache["CgBT2"] @ lam_g
        lam2[cache["at_b2"]] = stat * cache["lam_b2"]
    return lam2


def check_active_set(
    fac: ActiveSetFactor,
    P: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    absC: np.ndarray | None = None,
    report: dict | None = None,
    red: tuple | None = None,
    maps: tuple[np.ndarray, np.ndarray] | HessianFreeMaps | None = None,
) -> list[float] | None:
    """``z`` (a list of d floats) if the active set of ``fac`` passes the KKT test at the
    instance ``w`` of ``min 1/2 z'Pz + q'z  s.t.  C z <= h``, else None.

    The test of :meth:`ActiveSetMaps.check` of :func:`active_set_maps`, computed for the one
    instance (the same products, applied to ``w``). ``absC``: ``|C|``, when the caller keeps
    it. ``report``: a dict that receives, when the test fails, ``"add"`` (the inactive rows
    violated beyond their tolerance, most violated first, relative to it) and ``"drop"`` (the
    active rows whose multipliers are negative beyond their tolerance); both empty when the set
    is not a candidate. ``red``: :func:`reduce_hessian` of ``fac`` and ``P``, when the caller
    has it; ``maps``: see :func:`solve_stacked` (with :class:`HessianFreeMaps` the only
    condition on ``P`` left to test is no curvature on a pivot slack, :func:`reduce_hessian`'s).
    """
    if report is not None:
        report.update(add=[], drop=[])
    if isinstance(maps, HessianFreeMaps):
        if _pivot_has_curvature(fac, P):
            return None
    else:
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
        if gen.size and (np.abs(primal[gen]) > KKT_TOL * primal_T[gen]).any():
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
    if not (math.isfinite(worst + float(z.sum())) and np.isfinite(terms).all()):
        return None
    if worst > 0.0 and not (resid <= KKT_TOL * terms).all():
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
