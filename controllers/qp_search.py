"""The search of :class:`controllers.qp.QPFamily` around a solver's approximate answer (a mixin):
the active set of its multipliers, its nearly active rows, their subsets, within a budget.

A solver (OSQP, DAQP, Clarabel through cvxpy) answers to its own tolerance; the active set its
answer indicates is re-solved exactly and verified (:mod:`controllers.kkt`). When that fails,
:meth:`LocalSearch.local` tries the sets around it; each set not met before costs its
factorizations (:attr:`controllers.qp.QPFamily.factorizations`), so the search of one instance
stops at a budget (:data:`SEARCH_FACTORIZATIONS`) and hands over to the next solver of the chain.
"""

from __future__ import annotations

from itertools import chain, combinations
from typing import TYPE_CHECKING

import numpy as np

from .qp_daqp import NEAR_ACTIVE_TOL, Solution

__all__ = ["MAX_LOCAL_CANDIDATES", "SEARCH_FACTORIZATIONS", "LocalSearch"]

#: Candidate active sets tried around an OSQP solution (subsets of its nearly active rows).
MAX_LOCAL_CANDIDATES = 256

#: Factorizations (:attr:`controllers.qp.QPFamily.factorizations`) the search around a solver's
#: answer (:meth:`LocalSearch.local`: subsets of its nearly active rows, then repair steps) may
#: spend on one instance (from :meth:`LocalSearch.open_budget`: a solve and its rescue), in a
#: family of at most 64 variables; one of ``d > 64`` variables gets ``(64 / d)**3`` of it (a
#: factorization costs ~d^3), at least 16. Then the search hands over to the next solver of the
#: chain. On random trees of 9 to 33 nodes it verifies as many answers as an unlimited search
#: with a sixth of the factorizations; a tree of 63 variables needed 281 in one solve.
SEARCH_FACTORIZATIONS = 500


class LocalSearch:
    """The search of :class:`controllers.qp.QPFamily` around an approximate answer: a mixin that
    reads the family's ``d``, ``C``, ``absC``, its one-sided row indices, its counter of
    factorizations and :meth:`verify`."""

    # set by QPFamily
    d: int
    C: np.ndarray
    absC: np.ndarray
    upper_idx: np.ndarray
    lower_idx: np.ndarray
    factorizations: int
    _search_until: int

    if TYPE_CHECKING:  # QPFamily's method (declared for the type checker only)

        def verify(
            self, rows: tuple[int, ...], w: np.ndarray, report: dict | None = None
        ) -> list[float] | None: ...

    def near_active(self, z: np.ndarray, w: np.ndarray, loose: bool = False) -> np.ndarray:
        """Rows of ``C`` that are nearly active at the approximate solution ``z``: the slack is
        within :data:`NEAR_ACTIVE_TOL` of the row's own terms (with a floor from the largest
        component: a slack of 1e-106 where the terms are 1e-106 is zero for OSQP), or, with
        ``loose``, of the row's norm times the largest component (which also catches a row that
        OSQP left loose within its tolerance, e.g. the slack of a node of tiny weight)."""
        h = w[self.d :]
        slack = h - self.C @ z
        zmax = float(np.max(np.abs(z), initial=0.0))
        floor = self.absC.sum(axis=1) * zmax
        terms = (floor if loose else self.absC @ np.abs(z) + 1e-6 * floor) + np.abs(h)
        return np.flatnonzero(slack <= NEAR_ACTIVE_TOL * terms)

    def local(self, z: np.ndarray, w: np.ndarray, y: np.ndarray | None = None) -> Solution | None:
        """Exact re-solve around an approximate solution: the active set of the multipliers,
        the nearly active rows, then their subsets (largest first); the same again with the
        looser test of nearly active rows. At most :data:`MAX_LOCAL_CANDIDATES` sets in all;
        beyond the solver's own sets (the first ones), within the instance's budget of
        factorizations (:meth:`open_budget`)."""
        tried: set[tuple[int, ...]] = set()
        nears = [self.near_active(z, w, loose) for loose in (False, True)]
        guesses: list[tuple[int, ...]] = []
        for near in nears:  # the cheap guesses of both tests first
            if y is not None:
                guesses.append(self._rows_from_duals(y, near))
            if near.size <= self.d:
                guesses.append(tuple(near.tolist()))
        guesses = list(dict.fromkeys(guesses))
        subsets = (
            rows
            for near in nears
            for size in range(min(near.size, self.d), -1, -1)
            for rows in combinations(near.tolist(), size)
        )
        count = 0
        for rows in chain(guesses, subsets):
            if rows in tried:
                continue
            tried.add(rows)
            count += 1
            if count > MAX_LOCAL_CANDIDATES or (count > len(guesses) and self.over_budget()):
                return None
            out = self.verify(rows, w)
            if out is not None:
                return Solution(out, rows, "")
        return None

    def open_budget(self) -> None:
        """Start the budget of the search of one instance (:data:`SEARCH_FACTORIZATIONS`,
        scaled to the family's size): :meth:`controllers.qp.QPFamily.solve` starts one (a rescue
        after it shares it), and so does the cvxpy reference, which runs no solve."""
        share = min(1.0, 64.0 / max(self.d, 1)) ** 3
        self._search_until = self.factorizations + max(16, int(SEARCH_FACTORIZATIONS * share))

    def over_budget(self) -> bool:
        """Whether the search of the current instance has spent its budget."""
        return self.factorizations >= self._search_until

    def _rows_from_duals(self, y: np.ndarray, near: np.ndarray) -> tuple[int, ...]:
        """One-sided rows among ``near`` whose OSQP multiplier has the matching sign and is not
        negligible (``y_i > 0``: upper side active, ``y_i < 0``: lower side)."""
        nu = self.upper_idx.size
        scale = float(np.max(np.abs(y))) if y.size else 0.0
        rows = []
        for i in near.tolist():
            a = self.upper_idx[i] if i < nu else self.lower_idx[i - nu]
            yi = y[a] if i < nu else -y[a]
            if yi > 1e-9 * scale:
                rows.append(i)
        return tuple(rows[: self.d])
