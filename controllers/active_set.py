"""Exact, batched solution of a small QP family by enumeration of its candidate active sets.

The family is ``min 1/2 z'Pz + q'z  s.t.  C z <= h`` (one-sided rows, see
:class:`controllers.qp.QPFamily`), an instance is ``w = [q; h]``. For small ``d`` and few rows
every candidate active set (a set of at most ``d`` rows with independent rows and a positive
definite reduced Hessian) is enumerated once; each gives exact linear maps from ``w`` to the
solution and to the KKT residuals (:func:`controllers.qp.active_set_maps`). An instance is
solved by evaluating every candidate's residuals on the whole batch at once and keeping, per
instance, the lowest-index candidate that passes the KKT test (sufficient for a convex QP). The
candidates are ordered with the largest active sets first, the usual optima of the
receding-horizon problems. Ties (degenerate problems) are broken by that order, so the answer
does not depend on earlier calls.

The KKT test is that of :class:`controllers.kkt_maps.ActiveSetMaps`: each row, at the returned
solution, at most :data:`controllers.kkt.KKT_TOL` times its own terms, and each negated
multiplier at most that fraction of the magnitude of its terms, a negative one confirmed.
Residuals that are ``<= 0`` pass outright; only the rare borderline ones get the tolerance
computed; the winner's rows are checked at its solution, and a winner accepted on a tolerance
is tested by :meth:`ActiveSetMaps.check` itself.

Instances that no candidate settles are flagged, and the caller solves them otherwise. The
family's size is capped (:data:`controllers.qp.MAX_CANDIDATES`); the caller builds an
enumeration only below the cap.
"""

from __future__ import annotations

from functools import lru_cache, partial
from itertools import combinations
from typing import Any

import numpy as np

from .kkt import KKT_TOL
from .kkt_maps import ActiveSetMaps, active_set_maps

__all__ = ["ActiveSetQP", "candidate_maps"]

#: Candidate ranges whose stacked maps are kept (the two ranges of :meth:`ActiveSetQP.solve`).
_MAX_RANGES = 2


def _stacked_range(R: np.ndarray, Z: np.ndarray, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
    """Residual and solution maps of candidates ``lo .. hi-1`` as row blocks: row
    ``j * (hi - lo) + c`` of the first is residual ``j`` of candidate ``lo + c``, row
    ``c * d + i`` of the second is ``z_i`` of candidate ``lo + c``."""
    r = R[lo:hi]
    return (
        r.transpose(1, 0, 2).reshape(-1, r.shape[2]).copy(),
        Z[lo:hi].reshape(-1, r.shape[2]).copy(),
    )


def candidate_maps(P: np.ndarray, C: np.ndarray) -> list[ActiveSetMaps]:
    """The exact maps of every candidate active set of ``min 1/2 z'Pz + q'z  s.t.  C z <= h``
    (sets of at most ``d`` rows that pass :func:`controllers.kkt_maps.active_set_maps`), largest
    sets first, then in lexicographic order."""
    P = np.asarray(P, dtype=np.float64)
    C = np.asarray(C, dtype=np.float64)
    d, c = P.shape[0], C.shape[0]
    pivots = np.asarray(~P.any(axis=1), dtype=bool)  # the slacks without curvature
    maps = []
    for size in range(min(d, c), -1, -1):  # largest active sets first
        for rows in combinations(range(c), size):
            m = active_set_maps(P, C, rows, pivots=pivots)
            if m is not None:
                maps.append(m)
    return maps


class ActiveSetQP:
    """Candidate active sets of ``min 1/2 z'Pz + q'z  s.t.  C z <= h``, tested on batches.

    Parameters
    ----------
    C : (c, d) one-sided constraint rows
    maps : list of ActiveSetMaps
        The candidates, in the order of the lowest-index rule: every candidate
        (:func:`candidate_maps`, an enumeration) or some of them (the active sets a family has
        met, :meth:`controllers.qp.QPFamily.seen`).

    Attributes
    ----------
    active_sets : list of tuple
        The candidates, in the order of the lowest-index rule.
    index : dict
        Candidate index of each active set.
    """

    def __init__(self, C: np.ndarray, maps: list[ActiveSetMaps]) -> None:
        C = np.asarray(C, dtype=np.float64)
        d, c = C.shape[1], C.shape[0]
        self.d, self.c = d, c
        self._maps = maps
        self.C, self.absC = C, np.abs(C)
        # the active bounds of each candidate (kkt_maps.snap_bounds): row and coefficient per
        # variable
        self._snap_row = np.full((len(maps), d), -1, dtype=np.int64)
        self._snap_coef = np.ones((len(maps), d))
        self._active = np.zeros((len(maps), c), dtype=bool)  # each candidate's active rows
        for i, m in enumerate(maps):
            self._active[i, list(m.rows)] = True
            for row, j, a in m.bounds:
                self._snap_row[i, j], self._snap_coef[i, j] = row, a
        self.active_sets = [m.rows for m in maps]
        self.index = {rows: i for i, rows in enumerate(self.active_sets)}
        self.n_candidates = len(maps)
        width = d + c
        nres = c + d  # residual rows, padded to the same count for every candidate
        R = np.zeros((self.n_candidates, nres, width))
        T = np.zeros((self.n_candidates, nres, width))
        for i, m in enumerate(maps):
            R[i, : m.R.shape[0]] = m.R
            T[i, : m.T.shape[0]] = m.T
            R[i, m.R.shape[0] :] = 0.0  # padding rows: residual 0, always passes
        self._R, self._T = R, T
        self._R_flat = R.reshape(-1, width)
        self._Z = np.stack([m.Z for m in maps]) if maps else np.zeros((0, d, width))
        # the largest tolerance any residual of a candidate can get for |w| <= 1 (per candidate):
        # a residual above loose * max|w| fails without computing its own tolerance
        self._loose = KKT_TOL * (T.sum(axis=2).max(axis=1) if maps else np.zeros(0))
        self._set_range_cache()
        self._guess = self.n_candidates - 1  # first call: one pass over every candidate

    def _set_range_cache(self) -> None:
        # functools' LRU does this cache's job (a count of entries keyed by the range); over
        # the arrays, not self, so that no reference cycle keeps a dropped enumeration alive
        self._range = lru_cache(maxsize=_MAX_RANGES)(partial(_stacked_range, self._R, self._Z))

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        del state["_range"]  # an lru_cache does not pickle; a copy starts empty
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._set_range_cache()

    def _exact_ok(self, cand: np.ndarray, wr: np.ndarray) -> np.ndarray:
        """KKT test with per-residual tolerances for pairs (candidate ``cand[i]``, column i):
        the multipliers against their terms, every row at the candidate's solution. A screen:
        a winner it passes is tested again by the candidate's own :meth:`ActiveSetMaps.check`
        (see :meth:`solve`)."""
        w = wr.T  # (B', width)
        c = self.c
        res = np.einsum("bij,bj->bi", self._R[cand, c:], w)
        tol = KKT_TOL * np.einsum("bij,bj->bi", self._T[cand, c:], np.abs(w))
        z = self._snap(np.einsum("bij,bj->bi", self._Z[cand], w), cand, w[:, self.d :])
        return np.all(res <= tol, axis=1) & self._rows_hold(z, w[:, self.d :], cand)

    def _snap(self, z: np.ndarray, cand: np.ndarray, h: np.ndarray) -> np.ndarray:
        """``z`` (B, d) of candidates ``cand`` (B,) with their active bounds set exactly."""
        rows = self._snap_row[cand]
        on = rows >= 0
        if not on.any():
            return z
        bound = np.take_along_axis(h, np.where(on, rows, 0), axis=1) / self._snap_coef[cand]
        return np.where(on, bound, z)

    def _rows_hold(self, z: np.ndarray, h: np.ndarray, cand: np.ndarray) -> np.ndarray:
        """Whether every row holds at ``z`` (B, d) to :data:`controllers.kkt.KKT_TOL` of its
        own terms, the active rows of candidates ``cand`` (B,) both ways (B,)."""
        primal = z @ self.C.T - h
        primal = np.where(self._active[cand], np.abs(primal), primal)
        return np.all(primal <= KKT_TOL * (np.abs(z) @ self.absC.T + np.abs(h)), axis=1)

    def solve(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Solve a batch of instances.

        The lowest-index candidate that passes a batched screen wins; the screen accepts
        outright only a candidate whose residuals are all at most 0 and whose rows, the active
        ones both ways, hold at its solution. A winner accepted on a tolerance (a residual
        above 0: a multiplier of an ill-conditioned set, possibly negative) or whose rows do
        not hold is tested by :meth:`ActiveSetMaps.check`, the test of a single instance
        (the multipliers accepted below zero computed again, one step of refinement), and
        when it fails the instance goes through :meth:`solve_one`: an answer of the batch
        passed the same test as one of :meth:`solve_one`.

        Parameters
        ----------
        w : (B, d + c)
            ``[q; h]`` per instance.

        Returns
        -------
        z : (B, d) solutions (NaN where ``ok`` is False)
        ok : (B,) bool, whether a candidate passed the KKT test
        """
        w = np.atleast_2d(np.asarray(w, dtype=np.float64))
        # instances along the last axis: the elementwise work runs over contiguous memory
        wT = w.T if w.T.flags.c_contiguous else np.ascontiguousarray(w.T)
        B, d, nc = wT.shape[1], self.d, self.n_candidates
        scale = np.abs(wT).max(axis=0, initial=0.0)
        z = np.full((B, d), np.nan)
        found = np.zeros(B, dtype=bool)
        tolerated = np.zeros(B, dtype=bool)  # the winner had a residual above 0
        chosen = np.zeros(B, dtype=np.int64)
        # The lowest-index candidate that passes wins. For speed the candidates are tried in two
        # ranges: up to the one that won most often in the previous call, then the rest.
        g = self._guess
        todo = None
        winners = []
        nres = self._R.shape[1]
        for lo, hi in ((0, g + 1), (g + 1, nc)):
            if hi <= lo or (todo is not None and todo.size == 0):
                continue
            h = hi - lo
            res_rows, Z_rows = self._range(lo, hi)
            wr, sr = (wT, scale) if todo is None else (wT[:, todo], scale[todo])
            R = wr.shape[1]
            worst = (res_rows @ wr).reshape(nres, h * R).max(axis=0).reshape(h, R)
            ok = worst <= 0.0
            border = ~ok & (worst <= self._loose[lo:hi, None] * sr[None, :])
            if border.any():
                ci, ii = np.nonzero(border)
                ok[ci, ii] = self._exact_ok(lo + ci, wr[:, ii])
            best = np.argmax(ok, axis=0)
            hit = ok.any(axis=0)
            idx = np.arange(B) if todo is None else todo
            if not hit.all():
                best, wr = best[hit], wr[:, hit]
            zr = (Z_rows @ wr).reshape(h, d, -1)
            won = idx[hit]
            z[won] = zr[best, :, np.arange(best.size)]
            found[won] = True
            chosen[won] = lo + best
            tolerated[won] = border[best, np.flatnonzero(hit)]
            winners.append(lo + best)
            todo = idx[~hit]
        if found.any():  # the active rows, and every row, at the returned solutions
            idx = np.flatnonzero(found)
            z[idx] = self._snap(z[idx], chosen[idx], w[idx, d:])
            held = self._rows_hold(z[idx], w[idx, d:], chosen[idx])
            for i in idx[~held | tolerated[idx]].tolist():
                out = self._maps[int(chosen[i])].check(w[i])
                if out is None:
                    one = self.solve_one(w[i])
                    out = None if one is None else one[1]
                found[i] = out is not None
                z[i] = np.nan if out is None else out
        if winners:
            counts = np.bincount(np.concatenate(winners), minlength=nc)
            self._guess = int(counts.argmax()) if counts.any() else self._guess
        return z, found

    def solve_one(self, w: np.ndarray) -> tuple[tuple[int, ...], list[float]] | None:
        """``(rows, z)``: the active set of the lowest-index candidate that passes the KKT test
        (:meth:`controllers.kkt_maps.ActiveSetMaps.check`) at one instance ``w`` (d + c,) and
        the solution that test returned, or None. Independent of earlier calls."""
        w = np.asarray(w, dtype=np.float64)
        res = (self._R_flat @ w).reshape(self.n_candidates, -1)  # (nc, nres)
        worst = res.max(axis=1)
        loose = self._loose * float(np.max(np.abs(w), initial=0.0))
        for cand in np.flatnonzero(worst <= loose).tolist():
            z = self._maps[cand].check(w)
            if z is not None:
                return self.active_sets[cand], z
        return None
