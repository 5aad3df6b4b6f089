"""The maps form of the KKT verification of :mod:`controllers.kkt`: the exact solution of an
active set and its KKT residuals as matrices over the whole instance ``w = [q; h]``.

For families with a fixed Hessian that solve many instances (P3 and its enumeration): one
matrix product per instance gives ``z`` and every residual. The numbers are those of
:func:`controllers.kkt.check_active_set` (the same :func:`controllers.kkt.solve_stacked` products,
applied to the identity).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from operator import mul

import numpy as np

from .kkt import (
    KKT_TOL,
    ActiveSetFactor,
    HessianFreeMaps,
    active_set_factor,
    confirm_multipliers,
    reduce_hessian,
    solve_stacked,
)

__all__ = [
    "ActiveSetMaps",
    "active_set_maps",
    "hessian_free_maps",
    "snap_bounds",
    "stacked_maps",
]


def snap_bounds(z: list[float], bounds: tuple, w: np.ndarray) -> list[float]:
    """``z`` with each variable of an active bound set to the bound exactly (``h_i / C_ij``):
    the active set's solution meets its bounds exactly, so only round-off is removed (a slack
    whose bound ``rho >= 0`` is active is 0, not -1e-17)."""
    if bounds:
        d = len(z)
        for i, j, a in bounds:
            z[j] = float(w[d + i]) / a
    return z


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
    P : (d, d) or None
        The Hessian, for :func:`controllers.kkt.confirm_multipliers` (None: not confirmed).
    """

    rows: tuple[int, ...]
    Z: np.ndarray
    R: np.ndarray
    T: np.ndarray
    C: np.ndarray
    absC: np.ndarray
    bounds: tuple = ()  # see ActiveSetFactor.bounds
    P: np.ndarray | None = None
    RZ: np.ndarray = field(init=False, repr=False)  # [R; Z]: residuals and z in one product
    active: list = field(init=False, repr=False)  # (C_i as a list, index of h_i in w) per row
    #: ``KKT_TOL`` times the largest row sum of ``T``: no residual's tolerance exceeds
    #: ``loose * max|w|``, so a residual above it fails without its own tolerance computed
    loose: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "RZ", np.vstack([self.R, self.Z]))
        d = self.Z.shape[0]
        on_bound = {i for i, _, _ in self.bounds}
        active = [(self.C[i].tolist(), d + i) for i in self.rows if i not in on_bound]
        object.__setattr__(self, "active", active)
        loose = KKT_TOL * float(self.T.sum(axis=1).max(initial=0.0))
        object.__setattr__(self, "loose", loose)

    def check(self, w: np.ndarray) -> list[float] | None:
        """``z`` (a list of d floats) if the active set passes the KKT test at ``w``, else None."""
        v = (self.RZ @ w).tolist()
        nr = self.R.shape[0]
        worst = max(v[:nr], default=-math.inf)
        if worst > 0.0 and worst > self.loose * float(np.abs(w).max()):
            return None  # beyond every tolerance (NaN goes on, to the test below)
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
            neg_lam = np.asarray(v[c:nr])
            lam_tol = KKT_TOL * (self.T[c:] @ np.abs(w))
            if not np.all(neg_lam <= lam_tol):
                return None
            # a multiplier accepted below zero is computed again (see controllers.kkt)
            negative = neg_lam > 0.0
            if (
                negative.any()
                and self.P is not None
                and not confirm_multipliers(self.P, self.C, self.rows, w, negative, za)
            ):
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
    P: np.ndarray,
    C: np.ndarray,
    rows: tuple[int, ...],
    factor: ActiveSetFactor | None = None,
    pivots: np.ndarray | None = None,
) -> ActiveSetMaps | None:
    """The maps of :class:`ActiveSetMaps` for ``min 1/2 z'Pz + q'z  s.t.  C_S z = h_S``, or
    None when the active set is not a candidate (see the module docstring). ``factor``: the
    :func:`active_set_factor` of ``rows``, when the caller has it; ``pivots``: see there."""
    d, c = P.shape[0], C.shape[0]
    fac = active_set_factor(C, rows, pivots) if factor is None else factor
    if fac is None:
        return None
    red = reduce_hessian(fac, P)
    if red is None:
        return None
    eye = np.eye(d + c)
    z2, lam2 = solve_stacked(fac, red, P, np.vstack([eye, eye]))
    Z, lam, T_lam = z2[:d], lam2[: fac.idx.size], lam2[fac.idx.size :]
    absC = np.abs(C)
    eye_h = eye[d:]
    # every row, active ones included, is tested at the returned z against its own terms
    # |C_i| |z| + |h_i|, bounded here linearly in |w| (a quick pre-test of the batched solve)
    primal = C @ Z - eye_h
    primal_T = absC @ np.abs(Z) + eye_h
    # an active row holds with equality up to round-off: it is tested at the returned z only
    primal[fac.idx] = 0.0
    R = np.vstack([primal, -lam])
    T = np.vstack([primal_T, T_lam])
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(T)) and np.all(np.isfinite(Z))):
        return None
    return ActiveSetMaps(fac.rows, Z, R, T, C, absC, fac.bounds, P)


def stacked_maps(
    fac: ActiveSetFactor, red: tuple, P: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`controllers.kkt.solve_stacked` of one active set and one Hessian as two matrices
    ``(Fz, Fl)``: for the stacked instances ``W2 = [W; |W|]``, ``Fz @ W2`` and ``Fl @ W2`` are
    its ``z2`` and ``lam2`` (the same products applied to the identity, as in
    :func:`active_set_maps`; the values act on ``W``, the magnitudes on ``|W|``). For the
    scenario tree, whose Hessian returns with the region probabilities, where one pair of
    Hessian and active set is tested again and again. None when a number is not finite."""
    d, width = P.shape[0], P.shape[0] + fac.n_rows
    eye = np.eye(width)
    z2, lam2 = solve_stacked(fac, red, P, np.vstack([eye, eye]))
    if not (np.all(np.isfinite(z2)) and np.all(np.isfinite(lam2))):
        return None
    s = fac.idx.size
    Fz = np.zeros((2 * d, 2 * width))
    Fz[:d, :width], Fz[d:, width:] = z2[:d], z2[d:]
    Fl = np.zeros((2 * s, 2 * width))
    Fl[:s, :width], Fl[s:, width:] = lam2[:s], lam2[s:]
    return Fz, Fl


def hessian_free_maps(fac: ActiveSetFactor, d: int) -> HessianFreeMaps | None:
    """The :class:`controllers.kkt.HessianFreeMaps` of an active set of a QP with ``d``
    variables: :func:`stacked_maps` at the Hessian 0. None when its rows leave a direction free
    (the solution then depends on the Hessian), when a free variable is in no reduced row (its
    scaling is its curvature) or when a number is not finite."""
    if fac.Q2.shape[1] or not fac.used.all():
        return None
    P0 = np.zeros((d, d))
    red = reduce_hessian(fac, P0)
    if red is None:
        return None
    pair = stacked_maps(fac, red, P0)
    return None if pair is None else HessianFreeMaps(*pair)
