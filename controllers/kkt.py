"""The one verification of every receding-horizon QP: exact solve of an active set, KKT test.

The QP is ``min 1/2 z'Pz + q'z  s.t.  C z <= h`` (one-sided rows, see
:class:`controllers.qp.QPFamily`); an instance is ``w = [q; h]``. For an active set ``S`` (rows
of ``C``) the solution and the multipliers are linear in ``w``. Whatever found ``S`` (a warm
start, OSQP, DAQP, an enumeration, cvxpy), the answer is accepted only through this module, by
one test, for problem P3 and for the scenario tree alike:

* the active rows and the variables are equilibrated (Ruiz scaling of ``C_S``; a variable in no
  active row by its curvature), and ``S`` is a candidate only if its scaled, row-normalized rows
  are linearly independent and the reduced Hessian on their null space is positive definite,
  relative to its own scale;
* the solution is computed by the null-space method on the scaled rows: ``C_S' = Q R``,
  ``z = Q1 R1^{-T} h_S + Q2 y`` with ``(Q2' P Q2) y = -Q2'(q + P z_p)``, and the multipliers
  from stationarity;
* the KKT test accepts ``S`` when every primal residual ``C_i z - h_i`` of an inactive row and
  every negated multiplier is at most :data:`KKT_TOL` times the magnitude of the terms summed to
  compute it. The magnitudes are carried through every product with absolute values (so a
  cancellation is not mistaken for a small term), in the equilibrated variables, which makes
  the test invariant under a scaling of the rows, of the variables or of the objective.

Two forms compute the same numbers: :func:`active_set_maps` (the maps as matrices over the
whole ``w``, for families with a fixed Hessian that solve many instances, e.g. P3 and its
enumeration) and :func:`check_active_set` (one instance, for the scenario tree, whose Hessian
changes at every solve and whose maps would be large). Both are built from one
:class:`ActiveSetFactor` (the part that depends only on ``C`` and ``S``) and one
:func:`_columns` (the part that depends on ``P``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from operator import mul

import numpy as np

__all__ = [
    "KKT_TOL",
    "ActiveSetFactor",
    "ActiveSetMaps",
    "active_set_factor",
    "active_set_maps",
    "check_active_set",
    "snap_bounds",
]

#: Relative tolerance of the KKT test: a residual is accepted when it is at most this fraction of
#: the magnitude of the terms summed to compute it.
KKT_TOL = 1e-9

#: Rank and definiteness thresholds of the exact solve, relative to the scale of the matrices.
_RANK_TOL = 1e-11
_PD_TOL = 1e-12


def _ruiz(CS: np.ndarray, d: int, sweeps: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Dc, Dr, used)``: Ruiz equilibration of the active rows ``CS`` (every row and every
    column of ``Dr CS Dc`` then has its largest entry near 1); ``Dc = 1`` for a variable in no
    active row (``used`` False), which :func:`_free_scaling` scales by its curvature."""
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


@dataclass(frozen=True, eq=False)
class ActiveSetFactor:
    """The part of an active set's exact solve that depends only on ``C`` and the rows.

    In the scaled variables ``z = Dc z~`` (``Dc`` is :attr:`Dc_used` for the variables in an
    active row and the curvature scaling of :func:`_free_scaling` for the others) and with the
    active rows scaled by ``Dn`` and normalized, ``Chat' = [Q1 Q2] [R1; 0]``.

    Attributes
    ----------
    rows : tuple of int
    idx : (s,) int array
    used : (d,) bool
        Variables in an active row.
    Dc_used : (d,) float
        Their Ruiz scaling (1 for the others).
    Q1 : (d, s), Q2 : (d, d - s)
    Lmap : (s, d)
        ``R1^{-1} Q1'``: the multipliers from the stationarity residual.
    Zp : (d, s)
        The particular solution ``z~_p = Zp h_S`` (``Q1 R1^{-T} Dn``).
    Tp : (d, s)
        The magnitude of its terms, per datum (``|Q1| |R1^{-T}| Dn``).
    bounds : tuple of (int, int, float)
        ``(i, j, C_ij)`` for each active row ``i`` on a single variable ``j`` (a bound): the
        solution has ``z_j = h_i / C_ij`` exactly, and :func:`snap_bounds` sets it so.
    """

    rows: tuple[int, ...]
    idx: np.ndarray
    used: np.ndarray
    Dc_used: np.ndarray
    Q1: np.ndarray
    Q2: np.ndarray
    Lmap: np.ndarray
    Zp: np.ndarray
    Tp: np.ndarray
    bounds: tuple  # (row, variable, coefficient) of the active rows on one variable
    absQ2: np.ndarray = field(init=False, repr=False)
    absLmap: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "absQ2", np.abs(self.Q2))
        object.__setattr__(self, "absLmap", np.abs(self.Lmap))

    @property
    def floats(self) -> int:
        """Floats held (for cache budgets)."""
        return sum(
            a.size
            for a in (self.Q1, self.Q2, self.Lmap, self.Zp, self.Tp, self.absQ2, self.absLmap)
        )


def active_set_factor(C: np.ndarray, rows: tuple[int, ...]) -> ActiveSetFactor | None:
    """The :class:`ActiveSetFactor` of ``rows`` of ``C``, or None when the scaled,
    row-normalized rows are linearly dependent (or more than ``d``)."""
    d = C.shape[1]
    s = len(rows)
    if s > d:
        return None
    idx = np.array(rows, dtype=np.int64)
    CS = C[idx]
    Dc, Dr, used = _ruiz(CS, d)
    if s:
        Ct = CS * Dr[:, None] * Dc[None, :]
        norms = np.sqrt(np.einsum("ij,ij->i", Ct, Ct))
        if not np.all(norms > 0.0):
            return None
        Dn = Dr / norms  # the full row scaling of the active rows
        Chat = CS * Dn[:, None] * Dc[None, :]
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
        Q1, Q2 = np.zeros((d, 0)), np.eye(d)
        Zp, Tp, Lmap = np.zeros((d, 0)), np.zeros((d, 0)), np.zeros((0, d))
    if not (np.all(np.isfinite(Zp)) and np.all(np.isfinite(Lmap))):
        return None
    return ActiveSetFactor(
        tuple(int(i) for i in rows), idx, used, Dc, Q1, Q2, Lmap, Zp, Tp, _bounds(CS, idx)
    )


def _bounds(CS: np.ndarray, idx: np.ndarray) -> tuple:
    """``(i, j, C_ij)`` of the rows of ``CS`` (rows ``idx`` of ``C``) with one nonzero entry."""
    out = []
    for row, i in zip(CS, idx.tolist(), strict=True):
        nz = np.flatnonzero(row)
        if nz.size == 1:
            j = int(nz[0])
            out.append((i, j, float(row[j])))
    return tuple(out)


def snap_bounds(z: list[float], bounds: tuple, w: np.ndarray) -> list[float]:
    """``z`` with each variable of an active bound set to the bound exactly (``h_i / C_ij``):
    the active set's solution meets its bounds exactly, so only round-off is removed (a slack
    whose bound ``rho >= 0`` is active is 0, not -1e-17)."""
    if bounds:
        d = len(z)
        for i, j, a in bounds:
            z[j] = float(w[d + i]) / a
    return z


def _free_scaling(fac: ActiveSetFactor, P: np.ndarray) -> np.ndarray:
    """``Dc``: the Ruiz scaling of the variables in an active row; a variable in no active row
    is scaled by its curvature, ``1 / sqrt(P_ii)`` (1 where ``P_ii = 0``). Variables of very
    different sizes (an offset of 1 next to a slack of 1e12, rows scaled by 1e-11) then get
    comparable scaled sizes, and rank and conditioning are judged in them."""
    diag = np.abs(np.diag(P))
    free = ~fac.used & (diag > 0.0)
    if not free.any():
        return fac.Dc_used
    Dc = fac.Dc_used.copy()
    Dc[free] = 1.0 / np.sqrt(diag[free])
    return Dc


def _columns(fac: ActiveSetFactor, P: np.ndarray):
    """The solution's maps in the scaled variables, on the data they depend on (``q`` and
    ``h_S``), and the magnitudes of their terms: ``(Dc, Pt, Zq, ZS, Tq, TS)`` with
    ``z~ = Zq q + ZS h_S`` and term magnitudes ``Tq |q| + TS |h_S|``; None when the reduced
    Hessian is not positive definite (the minimizer is not unique), relative to its scale."""
    d, s = P.shape[0], fac.idx.size
    Dc = _free_scaling(fac, P)
    Pt = P * Dc[:, None] * Dc[None, :]
    if d - s:
        Q2 = fac.Q2
        M = Q2.T @ Pt @ Q2
        M = 0.5 * (M + M.T)
        eig, vecs = np.linalg.eigh(M)
        if not (eig[-1] > 0.0 and eig[0] > _PD_TOL * eig[-1]):
            return None
        Y = -((vecs / eig) @ (vecs.T @ Q2.T))  # y = Y (q~ + P~ z~_p)
        Zq = Q2 @ (Y * Dc[None, :])
        ZS = fac.Zp + Q2 @ (Y @ (Pt @ fac.Zp))
        absQ2Y = fac.absQ2 @ np.abs(Y)
        Tq = absQ2Y * Dc[None, :]
        TS = fac.Tp + absQ2Y @ (np.abs(Pt) @ fac.Tp)
    else:
        Zq, ZS = np.zeros((d, d)), fac.Zp
        Tq, TS = np.zeros((d, d)), fac.Tp
    return Dc, Pt, Zq, ZS, Tq, TS


@dataclass(frozen=True, eq=False)
class ActiveSetMaps:
    """Exact solution of one active set as linear maps of the instance ``w = [q; h]``.

    Attributes
    ----------
    rows : tuple of int
        The active rows of ``C`` (sorted).
    Z : (d, d + c)
        ``z = Z w``.
    R : (c + s, d + c)
        KKT residuals ``[C z - h; -lambda_S] = R w``: all ``<= 0`` at a KKT point (``s = len(rows)``).
    T : (c + s, d + c)
        Nonnegative: ``T |w|`` bounds the tolerance terms of each residual (for the primal rows,
        ``|C| |Z| + |E_h|`` bounds the row's own terms ``|C_i| |z| + |h_i|``; for the multipliers,
        the magnitude of the terms summed to compute them).
    C, absC : (c, d)
        The rows and their absolute values (the primal test is made at the returned ``z``).
    """

    rows: tuple[int, ...]
    Z: np.ndarray
    R: np.ndarray
    T: np.ndarray
    C: np.ndarray
    absC: np.ndarray
    bounds: tuple = ()  # see ActiveSetFactor.bounds
    RZ: np.ndarray = field(init=False, repr=False)  # [R; Z]: residuals and z in one product
    active: list = field(init=False, repr=False)  # (C_i as a list, index of h_i in w) per row

    def __post_init__(self) -> None:
        object.__setattr__(self, "RZ", np.vstack([self.R, self.Z]))
        d = self.Z.shape[0]
        on_bound = {i for i, _, _ in self.bounds}
        active = [(self.C[i].tolist(), d + i) for i in self.rows if i not in on_bound]
        object.__setattr__(self, "active", active)

    def check(self, w: np.ndarray) -> list[float] | None:
        """``z`` (a list of d floats) if the active set passes the KKT test at ``w``, else None."""
        v = (self.RZ @ w).tolist()
        nr = self.R.shape[0]
        worst = max(v[:nr], default=-math.inf)
        z = snap_bounds(v[nr:], self.bounds, w)
        if not math.isfinite(worst + sum(z)):  # NaN or inf anywhere
            return None
        if not self._active_hold(z, w):  # one step of iterative refinement, then again
            z = self._refine(z, w)
            if not self._active_hold(z, w):
                return None
        if worst > 0.0:  # a residual above 0: within round-off of its terms?
            c = self.C.shape[0]
            za = np.asarray(z)
            h = w[w.shape[0] - c :]
            primal = self.C @ za - h  # at the returned z
            tol = KKT_TOL * (self.absC @ np.abs(za) + np.abs(h))
            if not np.all(primal <= tol):
                return None
            lam_tol = KKT_TOL * (self.T[c:] @ np.abs(w))
            if not np.all(np.asarray(v[c:nr]) <= lam_tol):
                return None
        return z

    def _active_hold(self, z: list[float], w: np.ndarray) -> bool:
        """Whether the active rows that are not bounds hold at ``z`` to :data:`KKT_TOL` of
        their own terms (both ways: they are equalities)."""
        for row, j in self.active:
            hj = float(w[j])
            if abs(sum(map(mul, row, z)) - hj) > KKT_TOL * (
                sum(abs(a * b) for a, b in zip(row, z, strict=True)) + abs(hj)
            ):
                return False
        return True

    def _refine(self, z: list[float], w: np.ndarray) -> list[float]:
        """``z - Z_S r_S`` with ``r_S = C_S z - h_S`` the active rows' residuals at ``z``: the
        solution of the active set for the corrected bounds (stationarity is kept)."""
        d = len(z)
        za = np.asarray(z)
        idx = np.array(self.rows, dtype=np.int64)
        r = self.C[idx] @ za - w[d + idx]
        return snap_bounds((za - self.Z[:, d + idx] @ r).tolist(), self.bounds, w)


def active_set_maps(
    P: np.ndarray, C: np.ndarray, rows: tuple[int, ...], factor: ActiveSetFactor | None = None
) -> ActiveSetMaps | None:
    """The maps of :class:`ActiveSetMaps` for ``min 1/2 z'Pz + q'z  s.t.  C_S z = h_S``, or
    None when the active set is not a candidate (see the module docstring). ``factor``: the
    :func:`active_set_factor` of ``rows``, when the caller has it."""
    d, c = P.shape[0], C.shape[0]
    fac = active_set_factor(C, rows) if factor is None else factor
    if fac is None:
        return None
    cols = _columns(fac, P)
    if cols is None:
        return None
    Dc, Pt, Zq, ZS, Tq, TS = cols
    idx, s = fac.idx, fac.idx.size
    Zt = np.zeros((d, d + c))  # z~ = Zt w
    Zt[:, :d] = Zq
    Zt[:, d + idx] = ZS
    Tz = np.zeros((d, d + c))
    Tz[:, :d] = Tq
    Tz[:, d + idx] = TS
    eye_q = np.hstack([np.diag(Dc), np.zeros((d, c))])  # q~ = Dc q
    eye_h = np.hstack([np.zeros((c, d)), np.eye(c)])
    Z = Zt * Dc[:, None]  # z = Dc z~
    absC = np.abs(C)
    # every row, active ones included, is tested at the returned z against its own terms
    # |C_i| |z| + |h_i|, bounded here linearly in |w| (a quick pre-test of the batched solve)
    primal = C @ Z - eye_h
    primal_T = absC @ np.abs(Z) + eye_h
    # an active row holds with equality up to round-off: it is tested at the returned z only
    primal[idx] = 0.0
    if s:
        # stationarity P~ z~ + q~ + Chat' lam_hat = 0  =>  lam_hat = -R1^{-1} Q1'(P~ z~ + q~);
        # lam_hat has the sign of the multiplier of the unscaled row
        lam = -fac.Lmap @ (Pt @ Zt + eye_q)
        lam_T = fac.absLmap @ (np.abs(Pt) @ Tz + np.abs(eye_q))
        R = np.vstack([primal, -lam])
        T = np.vstack([primal_T, lam_T])
    else:
        R, T = primal, primal_T
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(T)) and np.all(np.isfinite(Z))):
        return None
    return ActiveSetMaps(fac.rows, Z, R, T, C, absC, fac.bounds)


def check_active_set(
    fac: ActiveSetFactor,
    P: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    absC: np.ndarray | None = None,
    report: dict | None = None,
) -> list[float] | None:
    """``z`` (a list of d floats) if the active set of ``fac`` passes the KKT test at the
    instance ``w`` of ``min 1/2 z'Pz + q'z  s.t.  C z <= h``, else None.

    The test of :meth:`ActiveSetMaps.check` of :func:`active_set_maps`, computed for the one
    instance (the maps only on the data ``q`` and ``h_S`` the solution depends on). ``absC``:
    ``|C|``, when the caller keeps it. ``report``: a dict that receives, when the test fails,
    ``"add"`` (the inactive rows violated beyond their tolerance, most violated first, relative
    to it) and ``"drop"`` (the active rows whose multipliers are negative beyond their
    tolerance); both empty when the set is not a candidate.
    """
    if report is not None:
        report.update(add=[], drop=[])
    cols = _columns(fac, P)
    if cols is None:
        return None
    Dc, Pt, Zq, ZS, Tq, TS = cols
    d = P.shape[0]
    idx = fac.idx
    q, h = w[:d], w[d:]
    hS = h[idx]
    zt = Zq @ q + ZS @ hS
    z = Dc * zt
    for i, j, a in fac.bounds:  # snap_bounds
        z[j] = h[i] / a
    if idx.size:  # one step of iterative refinement on the active rows (see ActiveSetMaps)
        z = z - Dc * (ZS @ (C[idx] @ z - hS))
        for i, j, a in fac.bounds:
            z[j] = h[i] / a
    absC = np.abs(C) if absC is None else absC
    primal = C @ z - h  # every row, at the returned z, against its own terms
    primal_T = absC @ np.abs(z) + np.abs(h)
    primal[idx] = np.abs(primal[idx])  # the active rows are equalities
    if idx.size:
        tz = Tq @ np.abs(q) + TS @ np.abs(hS)  # the magnitude of the terms of each component
        lam = -fac.Lmap @ (Pt @ zt + Dc * q)
        lam_T = fac.absLmap @ (np.abs(Pt) @ tz + Dc * np.abs(q))
        resid = np.concatenate([primal, -lam])
        terms = np.concatenate([primal_T, lam_T])
    else:
        resid, terms = primal, primal_T
    worst = float(resid.max(initial=-math.inf))
    if not (math.isfinite(worst + float(z.sum())) and np.all(np.isfinite(terms))):
        return None
    if worst > 0.0 and not np.all(resid <= KKT_TOL * terms):
        if report is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                excess = np.where(resid > KKT_TOL * terms, resid / np.maximum(terms, 1e-300), 0.0)
            c = C.shape[0]
            inactive = excess[:c].copy()
            inactive[idx] = 0.0
            add = np.flatnonzero(inactive > 0.0)
            report["add"] = add[np.argsort(-inactive[add], kind="stable")].tolist()
            report["drop"] = idx[excess[c:] > 0.0].tolist()
        return None
    return z.tolist()
