"""The DAQP steps of :class:`controllers.qp.QPFamily` (a mixin), and the verified
:class:`Solution` every step returns.

DAQP (:mod:`controllers.dual_qp`) finds an active set; it is re-solved exactly and verified by
:mod:`controllers.kkt` before it is returned. A family with many more one-sided rows than
variables (a large scenario tree) first gives DAQP a growing subset of its rows
(:meth:`DaqpSolving._solve_screened`): DAQP's iterations scan every row it sees. When such a
family's warm set is far from the optimum, Clarabel's hint (:mod:`controllers.qp_ipm`) comes
first.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from .dual_qp import REGULARIZE, DaqpWorkspace, daqp_data, run_daqp
from .qp_ipm import IPM_MIN_VARIABLES, IPM_MIN_VIOLATED, interior_point_rows

__all__ = [
    "NEAR_ACTIVE_TOL",
    "SCREEN_NEAR",
    "SCREEN_RATIO",
    "SCREEN_ROUNDS",
    "DaqpSolving",
    "Solution",
    "active_set_of_multipliers",
    "first_verified",
]

#: A row whose residual at OSQP's solution is within this fraction of its terms counts as nearly
#: active (OSQP's polished solutions are accurate to ~1e-10 relative).
NEAR_ACTIVE_TOL = 1e-6

#: DAQP sees a growing subset of the general rows first (QPFamily._solve_screened) in families
#: with more one-sided rows than this many per variable, in at most SCREEN_ROUNDS rounds.
SCREEN_RATIO = 4
SCREEN_ROUNDS = 8

#: With the violated rows, a round of QPFamily._solve_screened adds the rows within this
#: fraction of their terms from active at DAQP's answer (fewer rounds).
SCREEN_NEAR = 0.05


@dataclass(frozen=True)
class Solution:
    """An exact, verified solution of one instance: ``z`` and its active set ``rows``."""

    z: list[float]
    rows: tuple[int, ...]
    path: str  # "warm", "repair", "clarabel", "daqp", "osqp", "osqp_retry", "enumeration"


def active_set_of_multipliers(
    y: np.ndarray, upper_of: np.ndarray | list[int], lower_of: np.ndarray | list[int], d: int
) -> tuple[int, ...] | None:
    """The active set (one-sided rows, sorted) of multipliers ``y`` in OSQP's form, one per
    two-sided row: positive where its upper side is active (one-sided row ``upper_of[row]``),
    negative for the lower (``lower_of[row]``; -1 where a side does not exist), 0 where
    inactive, as DAQP reports them. None when a side that does not exist is active or more
    than ``d`` rows (the variables) are. ``upper_of`` and ``lower_of`` may be given as lists
    (kept by a caller that reads many answers)."""
    # the QPs read here have tens of rows: a loop in Python is cheaper than array calls
    up = upper_of if isinstance(upper_of, list) else upper_of.tolist()
    low = lower_of if isinstance(lower_of, list) else lower_of.tolist()
    rows: list[int] = []
    for j, v in enumerate(y.tolist()):
        if v != 0.0:  # NaN counts as nonzero, as for np.flatnonzero
            if len(rows) == d:
                return None
            rows.append(up[j] if v > 0.0 else low[j])
    if rows and min(rows) < 0:
        return None
    return tuple(sorted(rows))


#: DAQP's answer: ``(z, y, status)``, ``z`` and ``y`` None on failure.
DaqpAnswer = tuple[np.ndarray | None, np.ndarray | None, str]


def first_verified(
    runs: Iterable[DaqpAnswer],
    settle: Callable[[np.ndarray, np.ndarray], Solution | None],
    notes: list[str],
) -> Solution | None:
    """The first of DAQP's answers ``runs`` (an iterator: each attempt runs when its turn comes)
    that ``settle(z, y)`` turns into a verified solution; else None, the first failure noted."""
    first = ""
    for z, y, status in runs:
        if z is not None and y is not None:  # DAQP gives both or neither
            sol = settle(z, y)
            if sol is not None:
                return sol
            status = "answer did not verify"
        first = first or status
    notes.append(f"daqp {first}")
    return None


class DaqpSolving:
    """The DAQP steps of :class:`controllers.qp.QPFamily`: a mixin that reads the family's
    ``P``, ``A``, ``C``, bounds, caches and :meth:`verify` / :meth:`local`."""

    # set by QPFamily
    P: np.ndarray
    A: np.ndarray
    C: np.ndarray
    absC: np.ndarray
    d: int
    screen: bool
    _daqp: Any
    _daqp_ws: Any
    _daqp_scaling: Any
    _daqp_simple: bool
    _fixed_P: bool
    _general_pos: np.ndarray | None
    _pool: np.ndarray | None
    _C_csc: Any
    use_daqp: bool
    upper_idx: np.ndarray
    lower_idx: np.ndarray

    if TYPE_CHECKING:  # QPFamily's methods (declared for the type checker only)

        def bounds(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

        def rows_of_multipliers(self, y: np.ndarray) -> tuple[int, ...] | None: ...

        def verify(
            self, rows: tuple[int, ...], w: np.ndarray, report: dict | None = None
        ) -> list[float] | None: ...

        def local(
            self, z: np.ndarray, w: np.ndarray, y: np.ndarray | None = None
        ) -> Solution | None: ...

        def near_active(self, z: np.ndarray, w: np.ndarray, loose: bool = False) -> np.ndarray: ...

    def _solve_daqp(
        self, w: np.ndarray, start: tuple[int, ...] | None, notes: list[str]
    ) -> Solution | None:
        """DAQP, then the active set of its answer re-solved exactly and verified: first the
        rows of its nonzero multipliers, then :meth:`local` around its answer. Attempts: with a
        fixed Hessian, the family's workspace (warm from its last solve, then cold); else warm
        started from ``start`` (an active set), then cold; then on regularized objectives."""
        if self.screen and not self._fixed_P:  # a fixed Hessian keeps DAQP's warm workspace
            sol = self._solve_screened(w, start)
            if sol is not None:
                return sol
        attempts: list[tuple[tuple[int, ...] | str | None, float, bool]] = []
        if self._fixed_P:
            attempts += [(None, 0.0, False), (None, 0.0, True)]
        else:
            attempts += [(start, 0.0, False)] if start is not None else []
            attempts += [(None, 0.0, True)]
        attempts += [(None, mu, True) for mu in REGULARIZE]
        if self._daqp_scaling is not None:  # then once more with the scaling of this P
            attempts.append(("rescale", 0.0, True))

        def runs() -> Iterator[DaqpAnswer]:
            for begin, mu, cold in attempts:
                if isinstance(begin, str):  # "rescale"
                    self._daqp_scaling = self._daqp = None
                    begin = None
                yield self.run_daqp(w, begin, mu, cold)

        return first_verified(runs(), lambda z, y: self._verified(z, y, w), notes)

    def _verified(self, z: np.ndarray, y: np.ndarray, w: np.ndarray) -> Solution | None:
        """DAQP's answer ``z`` (multipliers ``y``) to instance ``w``, verified: the active set of
        its multipliers re-solved exactly, else :meth:`local` around it; None when neither
        verifies."""
        rows = self.rows_of_multipliers(y)
        out = None if rows is None else self.verify(rows, w)
        if rows is not None and out is not None:
            return Solution(out, rows, "daqp")
        sol = self.local(z, w, y)
        return None if sol is None else Solution(sol.z, sol.rows, "daqp")

    def _daqp_from(self, z: np.ndarray, w: np.ndarray, notes: list[str]) -> Solution | None:
        """DAQP started from the rows ``z`` (another solver's approximate answer) leaves nearly
        active, the active set of its answer verified (then :meth:`local` around it); None
        when that fails (noted)."""
        near = tuple(self.near_active(z, w, loose=True).tolist())
        z2, y2, status = self.run_daqp(w, near)
        if z2 is not None and y2 is not None:  # DAQP gives both or neither
            sol = self._verified(z2, y2, w)
            if sol is not None:
                return sol
            status = "answer did not verify"
        notes.append(f"daqp from the osqp iterate: {status}")
        return None

    def run_daqp(
        self,
        w: np.ndarray,
        start: tuple[int, ...] | None = None,
        regularize: float = 0.0,
        cold: bool = False,
        subset: np.ndarray | None = None,
    ) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        """DAQP on instance ``w`` (:mod:`controllers.dual_qp`): ``(z, y, status)``, ``z = y =
        None`` on failure. A family whose Hessian has kept its first value solves in its
        workspace (warm from its last solve unless ``cold``); otherwise, or with a ``start``
        (an active set), a ``regularize`` term or a ``subset`` of the general rows of ``A``
        (sorted positions among them; see :meth:`_solve_screened`), DAQP is set up for this
        one solve."""
        if self._daqp is None:
            self._daqp = daqp_data(self.P, self.A, self._daqp_simple, self._daqp_scaling)
        lo, hi = self.bounds(np.asarray(w[self.d :]))
        q = np.asarray(w[: self.d])
        if self._fixed_P and start is None and not regularize and subset is None:
            if self._daqp_ws is None:
                self._daqp_ws = DaqpWorkspace(self._daqp)
            return self._daqp_ws.solve(q, lo, hi, cold)
        nu = self.upper_idx.size
        begin = None
        if start is not None:
            begin = [
                (int(self.upper_idx[i]), False) if i < nu else (int(self.lower_idx[i - nu]), True)
                for i in start
            ]
        return run_daqp(self._daqp, q, lo, hi, begin, regularize, subset)

    def _solve_screened(self, w: np.ndarray, start: tuple[int, ...] | None) -> Solution | None:
        """DAQP on a subset of the general rows, grown until no row it omits is violated: for
        a family with many more rows than variables (a tree of 111 nodes has 2220 chance rows
        and 222 variables) DAQP's iterations scan every row it sees. The subset starts with
        the rows of the family's last screened solve, the general rows of ``start`` and the
        rows violated at the solution of that active set; each round adds every omitted row
        violated at DAQP's answer and starts DAQP from its last working set. When none is
        violated, DAQP's answer is the optimum of the whole QP, and the active set of its
        multipliers is verified as usual. None when a round fails or after
        :data:`SCREEN_ROUNDS` rounds. Used only while the Hessian changes (a fixed one keeps
        DAQP's warm workspace, which sees every row).

        When many rows are violated at ``start``'s solution (a large family far from its warm
        set), Clarabel's hint (:mod:`controllers.qp_ipm`) comes first: its set, verified, is
        the answer (path ``"clarabel"``); else it is DAQP's start."""
        general = self._daqp_general_rows()
        # the rows DAQP needed at the family's last screened solve, a good start nearby
        take = np.zeros(general.size, dtype=bool) if self._pool is None else self._pool.copy()
        if start is not None:
            report: dict = {}
            self.verify(start, w, report)
            if self._far(report):
                hint = self._interior_point_hint(w)  # far from the warm set: see qp_ipm
                if hint is not None:
                    out = self.verify(hint, w, report)
                    if out is None:
                        hint, out = self._mend_hint(hint, w, report)
                    if out is not None:  # the next screened solve starts near this optimum
                        self._pool = self._near_rows(np.asarray(out), w, SCREEN_NEAR)
                        return Solution(out, hint, "clarabel")
                    start = hint
            seed = list(set(start) | set(report.get("add", ())))
            take[self._general_of(seed)] = True
        h = np.asarray(w[self.d :])
        begin = start
        for _ in range(SCREEN_ROUNDS):
            subset = np.flatnonzero(take)
            z, y, _ = self.run_daqp(w, begin, 0.0, False, subset)
            if z is None or y is None:  # DAQP gives both or neither
                return None
            slack = h - self.C @ z
            terms = self.absC @ np.abs(z) + np.abs(h)
            violated = slack < -NEAR_ACTIVE_TOL * terms
            if violated.any():  # the violated rows, and those nearly active, join
                violated |= slack < SCREEN_NEAR * terms
            new = np.zeros(general.size, dtype=bool)
            new[self._general_of(np.flatnonzero(violated))] = True
            new &= ~take
            if not new.any():
                self._pool = take
                return self._verified(z, y, w)
            take |= new
            begin = self.rows_of_multipliers(y)
        return None

    def _general_of(self, rows: Any) -> np.ndarray:
        """The positions among DAQP's general rows (:meth:`_daqp_general_rows`) of the
        one-sided rows ``rows`` that are general rows (the others dropped)."""
        pos = self._general_pos
        assert pos is not None  # set by _daqp_general_rows
        of = np.concatenate([self.upper_idx, self.lower_idx])[np.asarray(rows, dtype=np.int64)]
        out = pos[of]
        return out[out >= 0]

    def _near_rows(self, z: np.ndarray, w: np.ndarray, near: float) -> np.ndarray:
        """A mask over DAQP's general rows: those within ``near`` of their terms from active
        at ``z`` (a pool for :meth:`_solve_screened`)."""
        h = np.asarray(w[self.d :])
        slack = h - self.C @ z
        mask = np.zeros(self._daqp_general_rows().size, dtype=bool)
        mask[
            self._general_of(np.flatnonzero(slack < near * (self.absC @ np.abs(z) + np.abs(h))))
        ] = True
        return mask

    def _mend_hint(
        self, rows: tuple[int, ...], w: np.ndarray, report: dict
    ) -> tuple[tuple[int, ...], list[float] | None]:
        """A hint whose KKT test at ``w`` failed with ``report``, mended once: ``(rows, z)``,
        ``z`` None when the mended set fails too (or, here, is not tried: see
        :meth:`controllers.tree_qp.TreeQP._mend_hint`)."""
        return rows, None

    def _far(self, report: dict) -> bool:
        """Whether a failed KKT test's ``report`` (see :func:`controllers.kkt.check_active_set`)
        calls for Clarabel's hint: a large screened family whose Hessian changes (see
        :meth:`_solve_screened`), many rows violated."""
        return bool(
            self.use_daqp
            and self.screen
            and not self._fixed_P
            and self.d >= IPM_MIN_VARIABLES
            and len(report.get("add", ())) >= IPM_MIN_VIOLATED
        )

    def _interior_point_hint(self, w: np.ndarray) -> tuple[int, ...] | None:
        """The active set Clarabel's answer to instance ``w`` indicates
        (:func:`controllers.qp_ipm.interior_point_rows`), or None; not verified."""
        if self._C_csc is None:
            self._C_csc = sp.csc_matrix(self.C)
        rows = interior_point_rows(self.P, self._C_csc, w[: self.d], w[self.d :])
        return None if rows is None or len(rows) > self.d else rows

    def _daqp_general_rows(self) -> np.ndarray:
        """The rows of ``A`` DAQP takes as general constraints (the others, the identity rows
        of a ``simple`` family, are its simple bounds); :attr:`_general_pos` maps a row of
        ``A`` to its position among them (-1)."""
        rows_A = self.A.shape[0]
        general = np.arange(rows_A - self.d if self._daqp_simple else rows_A)
        if self._general_pos is None:
            pos = np.full(rows_A, -1, dtype=np.int64)
            pos[general] = np.arange(general.size)
            self._general_pos = pos
        return general
