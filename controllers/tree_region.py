"""The probability that a Gaussian state lies in the region ``G x <= H``, for the scenario tree.

The branch probabilities of a tree node below the root depend on ``q = Pr{G x <= H_{k+t}}`` for
the node's Gaussian state (see :mod:`controllers.scenario_tree`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

__all__ = ["RegionClasses"]

#: Two rows of G are parallel when |cos| of their angle is within this of 1.
_PARALLEL_TOL = 1e-12


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    a.setflags(write=False)
    return a


class RegionClasses:
    """``Pr{G x <= H}`` for Gaussian ``x``, by classes of parallel rows of ``G``.

    The rows of ``G`` are grouped into classes of parallel or antiparallel rows; within a class
    the rows bound one projection ``g'x`` from above and below, an interval whose Gaussian
    probability is exact. The probability of the region is the product over the classes: exact
    for one class (e.g. a band, as in the macroeconomic example) and for classes whose
    projections are uncorrelated; otherwise an approximation (deterministic). A row ``G_j = 0``
    holds iff ``0 <= H_j``.

    Parameters
    ----------
    G : (r, n)
    """

    def __init__(self, G: np.ndarray) -> None:
        G = np.asarray(G, dtype=np.float64)
        r = G.shape[0]
        norms = np.linalg.norm(G, axis=1)
        self.zero_rows = np.flatnonzero(norms == 0.0)
        directions: list[np.ndarray] = []
        members: list[list[int]] = []
        scale = np.ones(r)  # G_j = scale_j g_c: g_c'x <= H_j / scale_j (>= when scale_j < 0)
        for j in np.flatnonzero(norms > 0.0).tolist():
            unit = G[j] / norms[j]
            for c, g in enumerate(directions):
                cos = float(g @ unit)
                if abs(cos) >= 1.0 - _PARALLEL_TOL:
                    members[c].append(j)
                    scale[j] = math.copysign(norms[j], cos)
                    break
            else:
                directions.append(unit)
                members.append([j])
                scale[j] = norms[j]
        self.directions = _frozen(np.array(directions).reshape(len(directions), G.shape[1]))
        self._inv_scale = _frozen(1.0 / scale)
        # per class, the rows bounding g'x from above and from below, padded with the index r
        # (upper: +inf) or r + 1 (lower: -inf) of the two columns appended to H / scale
        width_u = max([sum(scale[j] > 0 for j in mem) for mem in members] + [1])
        width_l = max([sum(scale[j] < 0 for j in mem) for mem in members] + [1])
        up = np.full((len(members), width_u), r)
        lo = np.full((len(members), width_l), r + 1)
        for c, mem in enumerate(members):
            rows_u = [j for j in mem if scale[j] > 0]
            rows_l = [j for j in mem if scale[j] < 0]
            up[c, : len(rows_u)] = rows_u
            lo[c, : len(rows_l)] = rows_l
        self._up, self._lo = up, lo
        # one row above and one below per class (a band): limits() reads them directly
        self._pair = None
        if width_u == 1 and width_l == 1 and (up < r).all() and (lo < r).all():
            self._pair = (up[:, 0], lo[:, 0], self._inv_scale[up[:, 0]], self._inv_scale[lo[:, 0]])

    @property
    def count(self) -> int:
        """Number of classes."""
        return int(self.directions.shape[0])

    def probability(self, mu: np.ndarray, sd: np.ndarray, H: np.ndarray) -> np.ndarray:
        """``Pr{G x <= H}`` (S,) for ``x ~ N(mean, Sigma)``, given the projections of the mean
        ``mu = mean @ directions.T`` (S, classes), their standard deviations ``sd`` (S, classes)
        and the bounds ``H`` (S, r)."""
        return self.probability_within(mu, sd, self.limits(H))

    def limits(self, H: np.ndarray) -> tuple:
        """The interval of each class's projection allowed by the bounds ``H`` (S, r), and
        whether the rows without a direction hold: what :meth:`probability_within` needs (a
        function of ``H`` alone, computed once per decision)."""
        if self._pair is not None and not self.zero_rows.size:
            up, lo_rows, inv_up, inv_lo = self._pair
            hi, lo = H[:, up] * inv_up, H[:, lo_rows] * inv_lo
            return lo, hi, lo <= hi, None
        S = H.shape[0]
        ext = np.empty((S, H.shape[1] + 2))
        np.multiply(H, self._inv_scale, out=ext[:, :-2])
        ext[:, -2], ext[:, -1] = np.inf, -np.inf
        hi = ext[:, self._up].min(axis=2)  # (S, classes)
        lo = ext[:, self._lo].max(axis=2)
        zero = np.ones(S, dtype=bool)
        for j in self.zero_rows.tolist():
            zero &= H[:, j] >= 0.0
        return lo, hi, lo <= hi, zero if self.zero_rows.size else None

    def probability_within(self, mu: np.ndarray, sd: np.ndarray, limits: tuple) -> np.ndarray:
        """:meth:`probability` with the :meth:`limits` of the bounds."""
        lo, hi, nonempty, zero = limits
        positive = sd > 0.0
        spread = bool(positive.all())
        safe = sd if spread else np.where(positive, sd, 1.0)
        a, b = (lo - mu) / safe, (hi - mu) / safe
        # Phi(b) - Phi(a) on the side where both tails are small (no cancellation)
        flip = a > 0.0
        p = special.ndtr(np.where(flip, -a, b)) - special.ndtr(np.where(flip, -b, a))
        if not spread:
            p = np.where(positive, p, (lo <= mu) & (mu <= hi))
        p = np.where(nonempty, np.minimum(np.maximum(p, 0.0), 1.0), 0.0)
        q = p.prod(axis=1) if p.shape[1] != 1 else p[:, 0]
        return q if zero is None else q * zero
