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
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

__all__ = ["ActiveSetQP"]


@dataclass
class _Candidate:
    rows: np.ndarray  # indices into the one-sided constraint list
    Mz_q: np.ndarray  # (d, d): z = Mz_q @ q + Mz_h @ h_S
    Mz_h: np.ndarray  # (d, |S|)
    Ml_q: np.ndarray  # (|S|, d): lambda = Ml_q @ q + Ml_h @ h_S
    Ml_h: np.ndarray  # (|S|, |S|)


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
        self.candidates: list[_Candidate] = []
        n_rows = self.C.shape[0]
        for size in range(0, min(max_active, d) + 1):
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
                # [z; lam] = Kinv @ [-q; h_S]
                self.candidates.append(
                    _Candidate(
                        rows=rows_arr,
                        Mz_q=-Kinv[:d, :d],
                        Mz_h=Kinv[:d, d:],
                        Ml_q=-Kinv[d:, :d],
                        Ml_h=Kinv[d:, d:],
                    )
                )

    def one_sided_bounds(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """``h`` of the one-sided form ``C z <= h`` for bounds ``l, u`` of shape ``(B, c)``."""
        return np.concatenate([upper[:, self._upper_idx], -lower[:, self._lower_idx]], axis=1)

    def solve(
        self, q: np.ndarray, lower: np.ndarray, upper: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Solve a batch of instances.

        Parameters
        ----------
        q : (B, d)
        lower, upper : (B, c)

        Returns
        -------
        z : (B, d) solutions (NaN where ``ok`` is False)
        ok : (B,) bool, whether a candidate passed the KKT test
        """
        q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        h = self.one_sided_bounds(np.atleast_2d(lower), np.atleast_2d(upper))
        B = q.shape[0]
        best_z = np.full((B, self.d), np.nan)
        best_obj = np.full(B, np.inf)
        scale = 1.0 + np.max(np.abs(h), axis=1)
        for cand in self.candidates:
            hS = h[:, cand.rows]
            z = q @ cand.Mz_q.T + hS @ cand.Mz_h.T
            if cand.rows.size:
                lam = q @ cand.Ml_q.T + hS @ cand.Ml_h.T
                dual_ok = np.all(
                    lam >= -self.tol * (1.0 + np.abs(lam).max(axis=1, keepdims=True)), axis=1
                )
            else:
                dual_ok = np.ones(B, dtype=bool)
            primal_ok = np.all(z @ self.C.T <= h + self.tol * scale[:, None], axis=1)
            ok = primal_ok & dual_ok
            if not np.any(ok):
                continue
            obj = 0.5 * np.einsum("bi,ij,bj->b", z, self.P, z) + np.einsum("bi,bi->b", q, z)
            better = ok & (obj < best_obj)
            best_obj[better] = obj[better]
            best_z[better] = z[better]
        return best_z, np.isfinite(best_obj)
