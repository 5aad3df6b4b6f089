"""Exact, batched solution of a small convex QP family by active-set enumeration.

A *family* is a QP whose Hessian ``P`` and constraint matrix ``A`` are fixed, while the linear
term and the bounds change from one instance to the next (OSQP's form)::

    minimize  1/2 z' P z + q' z     subject to   l <= A z <= u,       z in R^d

The one-step receding-horizon problem P3 has this form with ``d = m + 1`` variables
``z = (nu, rho)``, and its ``P`` and ``A`` depend only on the mode and on the region the state is
in. For such small ``d`` every candidate active set ``S`` (a set of at most ``d`` one-sided
constraints with a nonsingular KKT matrix) can be enumerated once; each gives a linear map from
``(q, bounds)`` to the stationary point of the equality-constrained problem. An instance is
solved by evaluating all candidate maps on the whole batch at once and keeping, per instance,
the candidate that is primal feasible and dual feasible (the KKT conditions, which are
sufficient for a convex QP). Ties (degenerate problems) are broken by the smallest objective.

Instances for which no candidate passes (which needs more than ``d`` active constraints with
no linearly independent subset satisfying KKT: not expected for strictly convex problems in
``nu`` with independent constraint rows) are flagged, and the caller solves them otherwise.

For one instance at a time (the controller's ``act``) the same maps serve a cheaper test:
:meth:`ActiveSetQP.verify` evaluates a single candidate (e.g. the active set of the previous
solution, or the one an iterative solver identified, :meth:`ActiveSetQP.candidate_from_duals`)
and accepts it only if it passes the KKT test; :meth:`ActiveSetQP.solve_one` enumerates every
candidate for one instance and returns the winner's index as well.
"""

from __future__ import annotations

import math
from itertools import combinations

import numpy as np

__all__ = ["ActiveSetQP"]

#: Primal tolerance of :meth:`ActiveSetQP.verify` with ``strict=True``, relative to the bounds
#: (the receding-horizon controller reports a slack below this relative size as zero).
STRICT_PRIMAL_TOL = 1e-10


class ActiveSetQP:
    """A QP family ``min 1/2 z'Pz + q'z  s.t.  l <= A z <= u`` solved exactly for batches.

    Parameters
    ----------
    P : (d, d) symmetric positive semidefinite
    A : (c, d)
    lower_finite, upper_finite : (c,) bool
        Which sides of each constraint exist (an infinite bound may only appear where the flag
        is False).
    max_active : int, optional
        Largest active set enumerated (default ``d``).
    tol : float
        KKT tolerance, relative to ``1 + max |[q; h]|`` of the instance.

    Notes
    -----
    The number of candidates is the number of subsets of at most ``d`` of the one-sided
    constraints, so this is meant for small problems (``d`` up to ~4, tens of constraints).
    """

    def __init__(
        self,
        P: np.ndarray,
        A: np.ndarray,
        lower_finite: np.ndarray,
        upper_finite: np.ndarray,
        max_active: int | None = None,
        tol: float = 1e-9,
    ) -> None:
        P = np.asarray(P, dtype=np.float64)
        A = np.asarray(A, dtype=np.float64)
        d = P.shape[0]
        lower_finite = np.asarray(lower_finite, dtype=bool)
        upper_finite = np.asarray(upper_finite, dtype=bool)
        # One-sided rows  C z <= h:  A_i z <= u_i  and  -A_i z <= -l_i.
        self._upper_idx = np.flatnonzero(upper_finite)
        self._lower_idx = np.flatnonzero(lower_finite)
        self.C = np.vstack([A[self._upper_idx], -A[self._lower_idx]])
        self.P, self.d, self.tol = P, d, tol
        max_active = d if max_active is None else max_active
        scale = max(1.0, float(np.max(np.abs(P))), float(np.max(np.abs(self.C))))
        # Candidate S gives [z; lam_S] = Kinv_S [-q; h_S]. With a selection matrix S_c (h_S = S_c h)
        # every candidate is a linear map of w = [q; h]; all of them are stacked so that one
        # matrix product evaluates every candidate for a whole batch.
        n_rows = self.C.shape[0]
        z_maps, lam_maps, rows_list = [], [], []
        # largest active sets first: the usual optima of P3 (rows or bounds active and rho = 0),
        # so that the lowest-index rule of solve() finds them early
        for size in range(min(max_active, d), -1, -1):
            for rows in combinations(range(n_rows), size):
                rows_arr = np.array(rows, dtype=np.int64)
                CS = self.C[rows_arr]
                K = np.zeros((d + size, d + size))
                K[:d, :d] = P
                K[:d, d:] = CS.T
                K[d:, :d] = CS
                if np.linalg.cond(K) > 1e10 * scale:
                    continue
                Kinv = np.linalg.inv(K)
                select = np.zeros((size, n_rows))
                select[np.arange(size), rows_arr] = 1.0
                # w = [q (d); h (n_rows)]
                z_maps.append(np.hstack([-Kinv[:d, :d], Kinv[:d, d:] @ select]))
                lam = np.zeros((n_rows, d + n_rows))  # multipliers of all rows (0 if inactive)
                lam[rows_arr] = np.hstack([-Kinv[d:, :d], Kinv[d:, d:] @ select])
                lam_maps.append(lam)
                rows_list.append(rows_arr)
        self.n_candidates = len(z_maps)
        self.active_sets = rows_list
        #: candidate index of each enumerated active set (a sorted tuple of rows of ``C``)
        self.index = {tuple(rows.tolist()): c for c, rows in enumerate(rows_list)}
        self._n_rows = n_rows
        # KKT residuals as linear maps of w too: C z_c - h (primal) and -lam_c (dual), all <= 0
        # at a KKT point; stacked so that one product gives every residual of every candidate.
        h_part = np.hstack([np.zeros((n_rows, d)), np.eye(n_rows)])
        kkt = np.stack(
            [
                np.vstack([self.C @ zm - h_part, -lm])
                for zm, lm in zip(z_maps, lam_maps, strict=True)
            ]
        )  # (ncand, 2 n_rows, d + n_rows)
        # ordered residual-major (column j * ncand + candidate) so that the worst residual of every
        # candidate is an elementwise maximum of 2 n_rows slices, not a reduction over a short axis
        self._kkt = kkt
        self._kkt_flat = kkt.reshape(-1, kkt.shape[2])  # (ncand * 2 n_rows, d + n_rows)
        self._Zc = np.stack(z_maps)  # (ncand, d, d + n_rows)
        self._single: dict[int, np.ndarray] = {}  # candidate -> [KKT residual map; z map]
        self._ranges: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._guess = self.n_candidates - 1  # first call: one pass over every candidate

    def one_sided_bounds(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """``h`` of the one-sided form ``C z <= h`` for bounds ``l, u`` of shape ``(B, c)``."""
        return np.concatenate([upper[:, self._upper_idx], -lower[:, self._lower_idx]], axis=1)

    def _range(self, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
        """KKT-residual and solution maps of candidates ``lo .. hi-1`` (cached), as row blocks:
        row ``j * (hi - lo) + c`` of the first is residual ``j`` of candidate ``lo + c``, row
        ``c * d + i`` of the second is ``z_i`` of candidate ``lo + c``."""
        key = (lo, hi)
        if key not in self._ranges:
            k = self._kkt[lo:hi]  # (h, 2c, d + c)
            kkt_rows = k.transpose(1, 0, 2).reshape(-1, k.shape[2]).copy()
            Z_rows = self._Zc[lo:hi].reshape(-1, k.shape[2]).copy()
            self._ranges[key] = (kkt_rows, Z_rows)
        return self._ranges[key]

    def solve(
        self, q: np.ndarray, lower: np.ndarray | None = None, upper: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Solve a batch of instances.

        Parameters
        ----------
        q : (B, d)
            Linear terms; or, when ``lower`` and ``upper`` are omitted, the whole data
            ``w = [q; h]`` (B, d + c1) with ``h = one_sided_bounds(lower, upper)``.
        lower, upper : (B, c)

        Returns
        -------
        z : (B, d) solutions (NaN where ``ok`` is False)
        ok : (B,) bool, whether a candidate passed the KKT test
        """
        if lower is None and upper is None:
            w = np.atleast_2d(np.asarray(q, dtype=np.float64))
        else:
            q = np.atleast_2d(np.asarray(q, dtype=np.float64))
            h = self.one_sided_bounds(np.atleast_2d(lower), np.atleast_2d(upper))
            w = np.concatenate([q, h], axis=1)  # (B, d + c)
        # instances along the last axis: every elementwise operation below runs over the batch
        # in contiguous memory (w given as the transpose of a (d + c, B) array costs no copy)
        wT = w.T if w.T.flags.c_contiguous else np.ascontiguousarray(w.T)
        B, d, nc = wT.shape[1], self.d, self.n_candidates
        tol = self.tol * (1.0 + np.abs(wT).max(axis=0, initial=0.0))
        z = np.full((B, d), np.nan)
        found = np.zeros(B, dtype=bool)
        # The answer is always the lowest-index candidate that passes the KKT test (any KKT
        # point is optimal; the rule makes the choice, and its rounding, independent of
        # history). For speed the candidates are tried in two ranges: up to the one that won
        # most often in the previous call, then the rest for the states not settled yet.
        g = self._guess
        todo = None  # every instance
        winners = []
        for lo, hi in ((0, g + 1), (g + 1, nc)):
            if hi <= lo or (todo is not None and todo.size == 0):
                continue
            h = hi - lo
            kkt_rows, Z_rows = self._range(lo, hi)
            wr, tr = (wT, tol) if todo is None else (wT[:, todo], tol[todo])
            R = wr.shape[1]
            residual = (kkt_rows @ wr).reshape(-1, h * R)  # (2c, h R): residual j of (c, i)
            ok = (residual.max(axis=0) <= np.tile(tr, h)).reshape(h, R)  # KKT holds
            best = np.argmax(ok, axis=0)  # the lowest-index candidate that passes
            hit = ok.any(axis=0)
            idx = np.arange(B) if todo is None else todo
            if not hit.all():
                best, wr = best[hit], wr[:, hit]
            zr = (Z_rows @ wr).reshape(h, d, -1)  # z of every candidate of the range
            z[idx[hit]] = zr[best, :, np.arange(best.size)]
            found[idx[hit]] = True
            winners.append(lo + best)
            todo = idx[~hit]
        if winners:
            counts = np.bincount(np.concatenate(winners), minlength=nc)
            self._guess = int(counts.argmax()) if counts.any() else self._guess
        return z, found

    # ------------------------------------------------------------------ one instance
    def _tolerance(self, w: np.ndarray) -> float:
        """KKT tolerance of one instance ``w = [q; h]`` (d + c,), as in :meth:`solve`."""
        return self.tol * (1.0 + max(map(abs, w.tolist())))

    def verify(self, candidate: int, w: np.ndarray, strict: bool = False) -> list[float] | None:
        """The solution of one instance from one candidate active set, if it is the optimum.

        Solves the equality-constrained KKT system of the candidate (a precomputed linear map
        of ``w``) and checks the rest of the KKT conditions: primal feasibility of every row
        and nonnegative multipliers on the active ones (sufficient for a convex QP), with the
        tolerance of :meth:`solve`. The result is a function of ``(candidate, w)`` only: the
        same products, in the same order, whichever caller asks.

        With ``strict=True`` primal feasibility is held to round-off of the bounds,
        ``STRICT_PRIMAL_TOL * (1 + max |h|)``, instead of the tolerance of :meth:`solve`, which
        scales with the whole of ``w`` (a large linear term, such as P3's slack penalty
        ``alpha``, would let a guessed active set that is too small violate a row by ~1e-6 and
        still pass). For callers that guess the active set (a warm start, a solver's duals);
        when the guess fails they enumerate with :meth:`solve_one`, which tries the larger
        active sets first.

        Parameters
        ----------
        candidate : int
            Index into :attr:`active_sets`.
        w : (d + c1,) float64 array
            ``[q; h]``, with ``h = one_sided_bounds(l, u)`` of the instance.

        Returns
        -------
        list of d floats, or None
            ``z`` if the candidate passes the KKT test, None otherwise (also when anything is
            not finite).
        """
        T = self._single.get(candidate)
        if T is None:
            T = np.vstack([self._kkt[candidate], self._Zc[candidate]])
            self._single[candidate] = T
        v = (T @ w).tolist()
        tol = self._tolerance(w)
        n1, n2 = self._n_rows, 2 * self._n_rows
        if not math.isfinite(tol + sum(v)) or max(v[:n2], default=-math.inf) > tol:
            return None
        if strict and n1:
            primal_tol = STRICT_PRIMAL_TOL * (1.0 + max(map(abs, w[self.d :].tolist())))
            if max(v[:n1]) > primal_tol:
                return None
        return v[n2:]

    def solve_one(self, w: np.ndarray) -> tuple[int | None, list[float] | None]:
        """Enumeration for one instance: the lowest-index candidate that passes the KKT test.

        The rule of :meth:`solve` (all candidates' residuals from one product, independent of
        any earlier call); the winner's ``z`` is then computed by :meth:`verify`, so that it is
        bit-identical to what :meth:`verify` gives for that candidate.

        Returns
        -------
        candidate : int or None
        z : list of d floats, or None when no candidate passes
        """
        tol = self._tolerance(w)
        worst = (self._kkt_flat @ w).reshape(self.n_candidates, -1).max(axis=1)
        for candidate in np.flatnonzero(worst <= tol).tolist():
            z = self.verify(candidate, w)  # the same test, on this candidate's own product
            if z is not None:
                return candidate, z
        return None, None

    def candidate_from_duals(
        self, y: np.ndarray, lower: np.ndarray, upper: np.ndarray
    ) -> int | None:
        """The candidate whose active set is the rows with a nonzero multiplier in ``y``.

        Parameters
        ----------
        y : (c,) array
            Multipliers of ``l <= A z <= u`` in OSQP's convention (``y_i > 0``: upper bound
            active, ``y_i < 0``: lower bound active). Entries below ``1e-9`` of the largest are
            read as zero.
        lower, upper : (c,) arrays
            The bounds of the instance. An equality row (``l_i = u_i``) is always active: its
            upper side unless its multiplier is clearly negative (the same side whatever the
            round-off when the multiplier is zero).

        Returns
        -------
        int or None
            None if that set is not among the enumerated candidates (too many rows, or a
            singular KKT matrix).
        """
        y = np.asarray(y, dtype=np.float64)
        if y.size == 0:
            return None
        thr = 1e-9 * max(1.0, float(np.max(np.abs(y))))
        equality = np.asarray(lower) == np.asarray(upper)
        up = (y > thr) | (equality & (y >= -thr))
        low = (y < -thr) & ~up
        active = np.concatenate([up[self._upper_idx], low[self._lower_idx]])
        return self.index.get(tuple(np.flatnonzero(active).tolist()))
