"""One parametric-QP engine for every receding-horizon controller.

A QP *family* has a fixed Hessian ``P`` and constraint matrix ``A`` while the linear term and the
bounds change from one instance to the next (OSQP's form)::

    minimize  1/2 z' P z + q' z     subject to   l <= A z <= u,       z in R^d

In one-sided form the constraints are ``C z <= h`` (a row of ``A`` with a finite upper bound, and
minus a row with a finite lower bound); an instance is the vector ``w = [q; h]``. The receding-
horizon controllers (problem P3 and the scenario tree) build one family per (mode, region) pair
and solve it at every step.

How an instance is solved (:meth:`QPFamily.solve`)
--------------------------------------------------
1. *Warm start*: the active set of the family's last solution is re-solved exactly and kept if
   it passes the KKT test.
2. *DAQP* (families built with ``use_daqp``, the scenario tree's): a dense dual active-set solver
   (:mod:`controllers.dual_qp`), started from the last active set, then cold, then on a
   regularized objective; the active set of its answer is re-solved exactly and verified.
3. *OSQP*: the family's ``osqp.OSQP`` object (set up on first use; later only ``update`` and a
   warm-started ``solve``) finds an approximate optimum; the active set it identifies (nonzero
   multipliers, then the rows it leaves nearly active) is re-solved exactly and verified.
4. *Enumeration*: the candidate active sets among the rows OSQP left nearly active (the search
   of :mod:`controllers.qp_search`, within a budget of factorizations per instance; after DAQP
   too); then, when the family is small enough (:data:`MAX_CANDIDATES`), every candidate.
5. OSQP again from a cold start with ten times the iterations, then steps 3-4 (``osqp_runs``: 2
   OSQP runs by default, fewer for families where its iterations are hopeless); then, for a
   large family whose solver is OSQP (``daqp_after_osqp``), DAQP started from the rows OSQP's
   last iterate leaves nearly active.

The caller (the controller) decides what to do when all of this fails (the cvxpy reference, then
a safe default). Every answer this class returns is the exact solution of the equality-
constrained KKT system of a verified active set, so it is a function of the instance and the
active set, not of the path that found it.

Exact solve of an active set, and the KKT test
----------------------------------------------
Both are :mod:`controllers.kkt`, the one verification of every receding-horizon QP: the active
rows and the variables are equilibrated, the null-space method solves the active set, and the
answer is accepted when every row holds at the returned ``z`` to :data:`KKT_TOL` of its own
terms and every multiplier is nonnegative to :data:`KKT_TOL` of the magnitude of its terms. A
family with a fixed Hessian keeps the solution's maps per active set
(:func:`controllers.kkt_maps.active_set_maps`); the scenario tree, whose Hessian changes at every
solve, solves each instance (:func:`controllers.kkt.check_active_set`) with the same numbers.

Thread safety
-------------
A family holds mutable solver state (the OSQP object, the warm start, caches). It is not
thread-safe by itself: the controllers hold a lock around every call (see
:class:`controllers.base.Controller`).
"""

from __future__ import annotations

import math
from functools import lru_cache
from operator import attrgetter
from typing import Any

import numpy as np
import osqp
import scipy.sparse as sp

from sdjls_gym.messages import describe
from sdjls_gym.validation import check_mapping

from .active_set import ActiveSetQP, candidate_maps
from .dual_qp import DaqpData, DaqpWorkspace
from .kkt import KKT_TOL
from .kkt_maps import ActiveSetMaps, active_set_maps
from .lru import BudgetedLRU
from .qp_daqp import SCREEN_RATIO, DaqpSolving, Solution, active_set_of_multipliers
from .qp_search import LocalSearch

__all__ = [
    "DEFAULT_OSQP_SETTINGS",
    "KKT_TOL",
    "MAX_CANDIDATES",
    "ActiveSetMaps",
    "QPFamily",
    "Solution",
    "active_set_maps",
    "check_osqp_settings",
    "candidate_count",
]

#: Largest number of candidate active sets enumerated up front (all subsets of at most ``d`` of
#: the one-sided rows). Families with more are solved by OSQP and an exact re-solve of the active
#: set it finds, with a local enumeration around it; see :func:`candidate_count`.
MAX_CANDIDATES = 4096

#: Largest number of floats the stacked maps of one family's enumeration may hold (16 MB).
MAX_ENUMERATION_FLOATS = 2_000_000

#: Largest number of floats the enumerations of one controller hold together (128 MB): beyond,
#: the least recently used family's enumeration is dropped (and rebuilt when needed again).
ENUMERATION_BUDGET_FLOATS = 16_000_000

#: Exact active-set maps kept per family (least recently used are dropped).
MAX_CACHED_MAPS = 512

#: Active sets of a family tested at once on a batch (:meth:`QPFamily.seen`): the most recently
#: used of its cached maps.
SEEN_SETS = 64

#: OSQP's infinity: bounds beyond it are clipped by OSQP.
OSQP_INFTY = float(osqp.constant("OSQP_INFTY"))


#: Settings of the OSQP fast path; tight enough that OSQP identifies the active set.
#: Override any of them with ``osqp_settings=`` of the controllers.
DEFAULT_OSQP_SETTINGS: dict[str, Any] = {
    "eps_abs": 1e-10,
    "eps_rel": 1e-10,
    "eps_prim_inf": 1e-12,
    "eps_dual_inf": 1e-12,
    "max_iter": 20000,
    "polishing": True,
    "polish_refine_iter": 10,
    "warm_starting": True,
    "verbose": False,
}


def check_osqp_settings(settings: Any) -> dict[str, Any]:
    """The default settings updated by ``settings`` (a dict or None), probed on a one-variable
    problem so that OSQP itself rejects unknown names or bad values, with a ValueError."""
    merged = dict(DEFAULT_OSQP_SETTINGS)
    merged.update(check_mapping("osqp_settings", settings))
    try:  # let OSQP itself reject unknown names or bad values, on a one-variable problem
        probe = osqp.OSQP()
        one = sp.csc_matrix(np.ones((1, 1)))
        probe.setup(one, np.zeros(1), one, -np.ones(1), np.ones(1), **merged)
    except Exception as exc:  # OSQP raises ValueError/TypeError/OSQPException
        raise ValueError(
            f"osqp_settings = {describe(settings, 120)} were rejected by OSQP ({exc}); see "
            "https://osqp.org/docs/interfaces/solver_settings.html for the valid names"
        ) from None
    return merged


@lru_cache(maxsize=64)
def _triu_csc(d: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the upper triangle of a (d, d) matrix in CSC order."""
    cols, rows = np.tril_indices(d)  # (a, b), a >= b, by a then b: column a, row b
    rows.setflags(write=False)
    cols.setflags(write=False)
    return rows, cols


def candidate_count(rows: int, d: int) -> int:
    """Number of subsets of at most ``d`` of ``rows`` one-sided constraints."""
    return sum(math.comb(rows, s) for s in range(min(rows, d) + 1))


def _forget_enumeration(family: QPFamily) -> None:
    family._enum = None


class EnumerationBudget(BudgetedLRU[int, "QPFamily"]):
    """The enumerations of several families (one controller's) kept within
    :data:`ENUMERATION_BUDGET_FLOATS`; least recently used first out (its enumeration dropped,
    built again when needed). Not thread-safe (the controller's lock covers it); pickles empty.

    Not ``functools``: the budget is in floats, and dropping a family frees its enumeration."""

    def __init__(self, limit: int = ENUMERATION_BUDGET_FLOATS) -> None:
        super().__init__(limit, attrgetter("enumeration_floats"), _forget_enumeration)

    def use(self, family: QPFamily) -> None:
        """Record that ``family`` holds its enumeration (now the most recently used) and drop
        the least recently used others' while the total is above the limit."""
        self.get(id(family), lambda: family)


class QPFamily(DaqpSolving, LocalSearch):
    """A QP family ``min 1/2 z'Pz + q'z  s.t.  l <= A z <= u`` with fixed ``P`` and ``A``.

    Parameters
    ----------
    P : (d, d) symmetric positive semidefinite
    A : (c, d)
    lower_finite, upper_finite : (c,) bool
        Which sides of each constraint exist.
    osqp_settings : dict
        Settings of the OSQP object (see :data:`controllers.rhc.DEFAULT_OSQP_SETTINGS`).
    enumerate_all : bool
        Whether a full enumeration may be built (when the family is small enough).
    budget : EnumerationBudget, optional
        The memory budget the family's enumeration shares with others.
    use_daqp : bool
        Whether DAQP (:mod:`controllers.dual_qp`) looks for the active set before OSQP.
    osqp_runs : int
        OSQP runs at most: 2 (a run, then a cold retry with ten times the iterations), 1 or 0.
    daqp_after_osqp : bool
        Whether DAQP, started from the rows OSQP's last iterate leaves nearly active, follows
        OSQP when no answer of it verified (a large family whose solver is OSQP: there ADMM
        takes tens of thousands of iterations to the tolerances the exact re-solve needs).

    Attributes
    ----------
    factorizations : int
        The work of the exact solves: QR factors of active rows and reduced Hessians computed
        (not taken from a cache) since the family was built or unpickled.
    osqp_iterations : int
        OSQP's iterations since then.

    Notes
    -----
    Not thread-safe (see the module docstring). Picklable: the OSQP object and the caches are
    dropped and rebuilt on use.
    """

    def __init__(
        self,
        P: np.ndarray,
        A: np.ndarray,
        lower_finite: np.ndarray,
        upper_finite: np.ndarray,
        osqp_settings: dict[str, Any],
        enumerate_all: bool = True,
        budget: EnumerationBudget | None = None,
        use_daqp: bool = False,
        osqp_runs: int = 2,
        daqp_after_osqp: bool = False,
    ) -> None:
        self.P = np.asarray(P, dtype=np.float64)
        self.A = np.asarray(A, dtype=np.float64)
        self.d = self.P.shape[0]
        self.upper_idx = np.flatnonzero(np.asarray(upper_finite, dtype=bool))
        self.lower_idx = np.flatnonzero(np.asarray(lower_finite, dtype=bool))
        # one-sided rows C z <= h: A_i z <= u_i, then -A_i z <= -l_i
        self.C = np.vstack([self.A[self.upper_idx], -self.A[self.lower_idx]])
        self.c = self.C.shape[0]
        self.absC = np.abs(self.C)
        # OSQP sees every row of A scaled to unit largest entry (the same constraints; OSQP's
        # absolute tolerances then mean the same thing for every row)
        norms = np.abs(self.A).max(axis=1) if self.A.size else np.zeros(0)
        self._row_scale = np.where(norms > 0.0, 1.0 / np.where(norms > 0.0, norms, 1.0), 1.0)
        self.osqp_settings = dict(osqp_settings)
        self.n_candidates = candidate_count(self.c, self.d)
        # floats of the stacked maps (residuals, their term scales, solutions) and of the two
        # cached candidate ranges of ActiveSetQP.solve
        self.enumeration_floats = (
            self.n_candidates * (4 * (self.c + self.d) + 2 * self.d) * (self.d + self.c)
        )
        self.can_enumerate = bool(
            enumerate_all
            and self.n_candidates <= MAX_CANDIDATES
            and self.enumeration_floats <= MAX_ENUMERATION_FLOATS
        )
        self.budget = budget if budget is not None else EnumerationBudget()
        self.use_daqp = bool(use_daqp)
        self.osqp_runs = int(osqp_runs)
        self.daqp_after_osqp = bool(daqp_after_osqp)
        d = self.d
        # DAQP takes the identity rows of A (one per variable, in order) as simple bounds
        self._daqp_simple = bool(
            self.A.shape[0] >= d and np.array_equal(self.A[self.A.shape[0] - d :], np.eye(d))
        )
        # the one-sided index of each row's upper and lower side (-1: absent), and the gathers
        # that give OSQP's bounds l, u from [h; inf]
        rows_A, n_up = self.A.shape[0], self.upper_idx.size
        self._upper_of = np.full(rows_A, -1, dtype=np.int64)
        self._lower_of = np.full(rows_A, -1, dtype=np.int64)
        self._upper_of[self.upper_idx] = np.arange(n_up)
        self._lower_of[self.lower_idx] = n_up + np.arange(self.lower_idx.size)
        self._hi_gather = np.where(self._upper_of >= 0, self._upper_of, self.c)
        self._lo_gather = np.where(self._lower_of >= 0, self._lower_of, self.c)
        #: whether P has kept its first value (update_P not called): DAQP's workspace is kept
        self._fixed_P = True
        #: whether DAQP first sees a subset of the general rows (see _solve_screened): for
        #: families with more than SCREEN_RATIO rows per variable
        self.screen = bool(self.c > SCREEN_RATIO * d)
        self._general_pos: np.ndarray | None = None
        self._pool: np.ndarray | None = None  # the subset of the last screened solve
        self._C_csc: sp.csc_matrix | None = None  # C for Clarabel's hint (built on first use)
        #: the variables without curvature (zero rows of P: the slacks), which the exact solve
        #: of an active set takes from their rows (see controllers.kkt.active_set_factor)
        self.pivots = np.asarray(~self.P.any(axis=1), dtype=bool)
        self._reset_state()

    def _reset_state(self) -> None:
        # not functools: seen() reads the cached maps in order of use, update_P clears them
        self._maps: BudgetedLRU[tuple[int, ...], ActiveSetMaps | None] = BudgetedLRU(
            MAX_CACHED_MAPS
        )
        self._seen: tuple[tuple, ActiveSetQP] | None = None  # seen(): its key and its stack
        self._osqp: osqp.OSQP | None = None
        self._enum: Any = None  # the ActiveSetQP of a full enumeration, built on first use
        self._daqp: DaqpData | None = None  # DAQP's scaled data for the current P
        #: DAQP's data for an earlier P, whose scaling and scaled rows update_P reuses
        self._daqp_scaling: DaqpData | None = None
        self._daqp_ws: DaqpWorkspace | None = None  # DAQP's workspace (fixed P only)
        self.warm: tuple[int, ...] | None = None
        self.factorizations = 0
        self.osqp_iterations = 0
        self._osqp_last: np.ndarray | None = None  # OSQP's last finite iterate
        self.open_budget()

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        for key in (
            "_maps",
            "_seen",
            "_osqp",
            "_osqp_last",
            "_enum",
            "_daqp",
            "_daqp_ws",
            "_daqp_scaling",
            "warm",
        ):
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._reset_state()

    def update_P(self, P: np.ndarray) -> None:
        """Replace the Hessian by ``P`` (d, d), for a family whose Hessian changes between
        instances while its sparsity does not (the scenario tree: path probabilities weight
        the stage costs).

        The OSQP object, when set up, is updated in place (``update(Px=...)``) if the upper
        triangle of ``P`` has the nonzero pattern the object was set up with, and otherwise
        dropped (set up again on next use). The cached active-set maps (functions of ``P``) are
        cleared and the full enumeration is forbidden from now on (it is built for one ``P``).
        The warm start (an active set) is kept: it is verified again with the new ``P``.

        Raises
        ------
        ValueError
            ``P`` is not a finite ``(d, d)`` array.
        """
        P = np.asarray(P, dtype=np.float64)
        if P.shape != (self.d, self.d) or not np.all(np.isfinite(P)):
            raise ValueError(
                f"P has shape {P.shape}; expected a finite ({self.d}, {self.d}) array, the "
                "Hessian of the family"
            )
        solver = self._osqp
        if solver is not None:
            # the upper triangle in CSC order (column by column, rows ascending); OSQP keeps the
            # nonzero pattern of triu(self.P) it was set up with, and update_P keeps it unchanged
            rows, cols = _triu_csc(self.d)
            old, new = self.P[rows, cols], P[rows, cols]
            nonzero = new != 0.0
            if np.array_equal(old != 0.0, nonzero):
                try:
                    solver.update(Px=new[nonzero])
                except Exception:  # noqa: BLE001 - set up again on next use instead
                    self._osqp = None
            else:
                self._osqp = None
        self.P = P
        self.pivots = np.asarray(~P.any(axis=1), dtype=bool)
        self._maps.clear()
        self._seen = None
        self._enum = None
        if self._daqp is not None:  # DAQP's scaling and scaled rows are kept (costly to redo)
            self._daqp_scaling = self._daqp
        self._daqp = None
        self._daqp_ws = None
        self._fixed_P = False
        self.can_enumerate = False

    # ------------------------------------------------------------------ data
    def one_sided_bounds(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """``h`` of ``C z <= h`` for bounds ``l, u`` of shape ``(..., c)``."""
        return np.concatenate([upper[..., self.upper_idx], -lower[..., self.lower_idx]], axis=-1)

    def bounds(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``l, u`` (c,) of OSQP's form from ``h`` (infinite where a side is absent)."""
        padded = np.append(h, np.inf)
        return -padded[self._lo_gather], padded[self._hi_gather]

    def rows_of_multipliers(self, y: np.ndarray) -> tuple[int, ...] | None:
        """The active set (one-sided rows, sorted) of multipliers ``y`` in OSQP's form (one per
        row of ``A``: positive where its upper side is active, negative for the lower, 0 where
        inactive, as DAQP reports them); None when a side that does not exist is active or
        there are more than ``d`` rows (:func:`controllers.qp_daqp.active_set_of_multipliers`)."""
        return active_set_of_multipliers(y, self._upper_of, self._lower_of, self.d)

    # ------------------------------------------------------------------ exact solves
    def maps(self, rows: tuple[int, ...]) -> ActiveSetMaps | None:
        """The exact maps of an active set (cached, least recently used dropped first)."""
        return self._maps.get(rows, self._new_maps, rows)

    def _new_maps(self, rows: tuple[int, ...]) -> ActiveSetMaps | None:
        self.factorizations += 2  # its QR factor and its reduced Hessian
        return active_set_maps(self.P, self.C, rows, pivots=self.pivots)

    def seen(self) -> ActiveSetQP | None:
        """The active sets this family has met (the :data:`SEEN_SETS` most recently used of
        the cached exact maps) as an :class:`controllers.active_set.ActiveSetQP`, to test them
        on a batch at once; None when there is none. Largest sets first (as the enumeration)."""
        found = [(rows, m) for rows, m in reversed(self._maps.items()) if m is not None]
        found = found[:SEEN_SETS]
        if not found:
            return None
        found.sort(key=lambda item: (-len(item[0]), item[0]))
        key = tuple(rows for rows, _ in found)
        if self._seen is None or self._seen[0] != key:
            self._seen = (key, ActiveSetQP(self.C, [m for _, m in found]))
        return self._seen[1]

    def verify(
        self, rows: tuple[int, ...], w: np.ndarray, report: dict | None = None
    ) -> list[float] | None:
        """``z`` if the active set ``rows`` gives the optimum of instance ``w``, else None.
        ``report``: filled only by families that test one instance at a time (see
        :meth:`controllers.tree_qp.TreeQP.verify`); left as it is here."""
        maps = self.maps(rows)
        return None if maps is None else maps.check(w)

    def enumeration(self) -> Any:
        """The full enumeration (:class:`controllers.active_set.ActiveSetQP`), or None when the
        family is too large (see :data:`MAX_CANDIDATES`)."""
        if not self.can_enumerate:
            return None
        if self._enum is None:
            self._enum = ActiveSetQP(self.C, candidate_maps(self.P, self.C))
        self.budget.use(self)
        return self._enum

    # ------------------------------------------------------------------ OSQP
    def run_osqp(
        self, w: np.ndarray, retry: bool = False
    ) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        """OSQP on instance ``w``: ``(z, y, status)``, ``z = y = None`` on failure."""
        q = np.array(w[: self.d])
        lo, hi = self.bounds(np.asarray(w[self.d :]))
        lo, hi = lo * self._row_scale, hi * self._row_scale
        try:
            if not np.all(np.maximum(lo, -OSQP_INFTY) <= np.minimum(hi, OSQP_INFTY)):
                raise ValueError("bounds rejected by OSQP (l > u after clipping)")
            if retry or self._osqp is None:
                settings = dict(self.osqp_settings)
                if retry:
                    settings["max_iter"] = 10 * int(settings["max_iter"])
                solver = osqp.OSQP()
                solver.setup(
                    sp.csc_matrix(np.triu(self.P)),
                    q,
                    sp.csc_matrix(self.A * self._row_scale[:, None]),
                    lo,
                    hi,
                    **settings,
                )
                if not retry:
                    self._osqp = solver
            else:
                solver = self._osqp
                solver.update(q=q, l=lo, u=hi)
            res = solver.solve(raise_error=False)
        except Exception as exc:  # noqa: BLE001 - an episode must not crash on a solver error
            self._osqp = None
            return None, None, f"error {type(exc).__name__}: {exc}"
        z = np.asarray(res.x, dtype=np.float64)
        status = str(res.info.status)
        self.osqp_iterations += int(res.info.iter)
        self._osqp_last = z if np.all(np.isfinite(z)) else None
        if res.info.status_val != osqp.SolverStatus.OSQP_SOLVED or not np.all(np.isfinite(z)):
            self._osqp = None  # do not warm start from a failed iterate
            return None, None, status
        return z, np.asarray(res.y, dtype=np.float64) * self._row_scale, status

    # ------------------------------------------------------------------ the chain
    def solve(
        self, w: np.ndarray, *, warm: bool = True, notes: list[str] | None = None
    ) -> Solution | None:
        """The exact solution of instance ``w`` by the chain of the module docstring, or None.

        ``notes`` collects what failed on the way (for the caller's status message).
        """
        notes = [] if notes is None else notes
        self.open_budget()
        sol = None
        if warm and self.warm is not None:
            sol = self.warm_solve(w)
        if sol is None and self.use_daqp:
            sol = self._solve_daqp(w, self.warm if warm else None, notes)
        if sol is None:
            return self._solve_osqp(w, notes)
        self.warm = sol.rows
        return sol

    def _solve_osqp(self, w: np.ndarray, notes: list[str]) -> Solution | None:
        """The chain after DAQP: OSQP (and its retry), the enumeration after OSQP's first
        answer, DAQP from OSQP's last iterate, the enumeration if it has not run."""
        enumerated = False
        for retry in (False, True)[: self.osqp_runs]:
            z, y, status = self.run_osqp(w, retry)
            if z is None:
                notes.append(f"osqp {'retry ' if retry else ''}status {status!r}")
            else:
                sol = self.local(z, w, y)
                if sol is not None:
                    self.warm = sol.rows
                    if retry:
                        notes.append("retried")
                    return Solution(sol.z, sol.rows, "osqp_retry" if retry else "osqp")
            if not enumerated:
                enumerated = True
                sol = self._enumerate_noted(w, notes, z is None)
                if sol is not None:
                    return sol
        if self.daqp_after_osqp and self._osqp_last is not None:
            sol = self._daqp_from(self._osqp_last, w, notes)
            if sol is not None:
                self.warm = sol.rows
                return sol
        if not enumerated:
            return self._enumerate_noted(w, notes, True)
        return None

    def warm_solve(self, w: np.ndarray) -> Solution | None:
        """The answer from the last active set :attr:`warm` (not None): that set, if it passes
        the KKT test at ``w``."""
        rows = self.warm
        assert rows is not None  # solve() calls this only with a warm active set
        z = self.verify(rows, w)
        return None if z is None else Solution(z, rows, "warm")

    def _enumerate_noted(self, w: np.ndarray, notes: list[str], note: bool) -> Solution | None:
        sol = self.enumerate_one(w)
        if sol is not None:
            self.warm = sol.rows
        elif self.can_enumerate and note:
            notes.append("no enumerated active set verified")
        return sol

    def enumerate_one(self, w: np.ndarray) -> Solution | None:
        """Full enumeration for one instance (None if the family is too large or nothing
        verifies): the lowest-index candidate that passes the KKT test. The candidates' maps
        are the family's own (:func:`controllers.kkt_maps.active_set_maps` of this ``P``, ``C``
        and pivots; the enumeration is forbidden once ``P`` changes), so the test that chose
        the candidate is :meth:`verify`'s and is not run twice."""
        enum = self.enumeration()
        if enum is None:
            return None
        found = enum.solve_one(w)
        if found is None:
            return None
        rows, z = found
        return Solution(z, rows, "enumeration")
