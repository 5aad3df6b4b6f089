"""Solving the scenario tree's QP: the engine with per-instance exact solves, and cvxpy.

:class:`TreeQP` is the :class:`controllers.qp.QPFamily` of a tree family: the warm active set,
then DAQP (:mod:`controllers.dual_qp`; warm-started from the last active set, then cold), then,
for small trees only, OSQP; when the family's Hessian has not changed since its first value
(``steps=1``, or jumps that do not depend on the state), the full enumeration of P3. Every
answer is the exact re-solve of an active set, verified by the one KKT test of
:mod:`controllers.kkt`. :func:`solve_tree_cvxpy` is the reference: the same tree written plainly
in cvxpy, node by node from the model's matrices, and solved by Clarabel;
:func:`solve_condensed_cvxpy` is the rescue of the fast path (its condensed QP in cvxpy). The
answers of both are verified by the same test before they are called solved.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from .horizon import HorizonSettings
from .kkt import (
    ActiveSetFactor,
    active_set_factor,
    check_active_set,
    reduce_hessian,
    solve_stacked,
)
from .kkt_maps import stacked_maps
from .lru import BudgetedLRU
from .p3 import CLARABEL_SETTINGS
from .qp import QPFamily, Solution
from .qp_ipm import clarabel_tolerances

__all__ = [
    "FACTOR_CACHE_FLOATS",
    "OSQP_MAX_VARIABLES",
    "TREE_CLARABEL_SETTINGS",
    "TreeQP",
    "solve_condensed_cvxpy",
    "solve_tree_cvxpy",
]

#: Floats of the active-set factors one family keeps (least recently used dropped first; 32 MB).
FACTOR_CACHE_FLOATS = 4_000_000

#: Floats of the reduced Hessians one family keeps, by the Hessian's token and the active set
#: (least recently used dropped first; 8 MB): see :meth:`TreeQP.update_P`.
REDUCED_CACHE_FLOATS = 1_000_000

#: Active sets a family remembers (the warm one and those optimal before it, distinct, most
#: recent first), tried in turn when the warm one fails (:meth:`TreeQP.warm_solve`): the state
#: moves within a few regions of the optimum, so the optimum is usually one of the most recent
#: sets (results/speed/HISTORY.md).
RECENT_SETS = 4

#: The earlier sets are tried while they pay: during a family's first :data:`RECENT_TRIAL`
#: tries, then while at least one try in :data:`RECENT_PAYOFF` verifies, and otherwise once
#: in :data:`RECENT_PAYOFF` warm failures (to notice when they pay again). On a large tree at
#: new states they seldom verify, and each failed try is an exact solve of the whole QP. The
#: repair from the warm set is tried by the same rule (results/speed/HISTORY.md).
RECENT_TRIAL = 16
RECENT_PAYOFF = 8

#: Largest stacked maps (floats) a pair of Hessian and active set gets (0.8 MB; see
#: :meth:`TreeQP.verify`): the tree at ``steps=3`` of the example needs 17 000, a 111-node tree
#: millions, which would cost more to build than the tests they would save.
STACKED_MAPS_FLOATS = 100_000

#: Largest number of primal-dual active-set steps of :meth:`TreeQP.local` after its candidates
#: fail.
REPAIR_STEPS = 20

#: The same from the warm start (:meth:`TreeQP.warm_solve`), before DAQP runs: a repair that
#: succeeds takes one step, and every further step of one that fails is an exact solve wasted
#: before DAQP (results/speed/HISTORY.md).
WARM_REPAIR_STEPS = 2

#: OSQP runs (after DAQP) only for trees of at most this many QP variables: on larger trees its
#: iterations cost more than the cvxpy rescue it would precede, so DAQP failing there goes to
#: cvxpy. With ``solver="osqp"`` a larger tree runs OSQP once (to a looser tolerance than its
#: default, which ADMM reaches only after very many iterations), then DAQP from its iterate
#: (results/speed/HISTORY.md).
OSQP_MAX_VARIABLES = 64

#: Clarabel settings of the cvxpy reference: tighter than P3's, since the offsets of nodes of
#: small path probability weigh little in the objective and are determined only to about
#: ``sqrt(tolerance / probability)``.
TREE_CLARABEL_SETTINGS: dict[str, Any] = {**CLARABEL_SETTINGS, **clarabel_tolerances(1e-12, 500)}


def _pays(stats: list[int]) -> bool:
    """Whether a warm try is due, by its record ``stats`` (tries, hits, warm failures skipped
    since the last try; see :data:`RECENT_PAYOFF`): counts the skip when it is not."""
    tries, hits, skipped = stats
    if tries < RECENT_TRIAL or hits * RECENT_PAYOFF >= tries or skipped >= RECENT_PAYOFF:
        stats[2] = 0
        return True
    stats[2] += 1
    return False


def _factor_floats(factor: ActiveSetFactor | None) -> int:
    return 0 if factor is None else factor.floats


@dataclass(eq=False)
class _Reduced:
    """What one pair of Hessian and active set keeps (:meth:`TreeQP.verify`): the reduced
    Hessian (None: not a candidate), the tests it served and, from the second test on, the
    stacked maps of :func:`controllers.kkt_maps.stacked_maps` (None until then, or when a
    number is not finite). ``floats``: their size, the maps counted before they are built."""

    red: tuple | None
    floats: int
    mappable: bool = False  # whether the maps are within STACKED_MAPS_FLOATS
    uses: int = 0
    maps: tuple[np.ndarray, np.ndarray] | None = None


def _reduce(fac: ActiveSetFactor, P: np.ndarray) -> _Reduced:
    red = reduce_hessian(fac, P)
    if red is None:
        return _Reduced(None, 0)
    held = sum(a.size for a in red[:4] if a is not None) + sum(a.size for a in red[4].values())
    maps = 4 * (P.shape[0] + fac.idx.size) * (P.shape[0] + fac.n_rows)
    mappable = maps <= STACKED_MAPS_FLOATS
    return _Reduced(red, held + (maps if mappable else 0), mappable)


def _reduced_floats(entry: _Reduced) -> int:
    return entry.floats


class TreeQP(QPFamily):
    """A :class:`controllers.qp.QPFamily` whose exact active-set solves are per instance.

    The engine's exact solve (:func:`controllers.qp.active_set_maps`) builds linear maps from the
    instance to the solution, worth their cost when many instances share a Hessian. The tree's
    Hessian changes with the probabilities (:meth:`QPFamily.update_P`), so :meth:`verify` solves the
    KKT system of the active set for the one instance instead, by the same null-space method
    (row-normalized constraints, scale-free rank and definiteness tests) and accepts it by the same
    KKT test: each residual at most :data:`controllers.qp.KKT_TOL` times the magnitude of the terms
    summed to compute it (a running bound of absolute values through the same factors). The factors
    that depend only on the active set (the QR factors of its rows) are cached, within
    :data:`FACTOR_CACHE_FLOATS` floats. Per Hessian given with a token (:meth:`update_P`) and active
    set, the reduced Hessian is cached too and, from the pair's second test on, the exact solve as
    two matrices (:func:`controllers.kkt_maps.stacked_maps`, within :data:`STACKED_MAPS_FLOATS`),
    all within :data:`REDUCED_CACHE_FLOATS`: the closed loop meets the same probabilities, hence the
    same Hessian, and the same active set at most decisions (wherever the chance rows are active).
    Everything else (OSQP, local search) is the engine's; the warm start is :meth:`warm_solve`.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        #: whether P has been set (update_P) since construction; the enumeration is allowed
        #: while P keeps its first value
        self._has_P = False
        self._may_enumerate = self.can_enumerate

    def _reset_state(self) -> None:
        super()._reset_state()
        # not functools: the budget is in floats
        self._factors: BudgetedLRU[tuple, ActiveSetFactor | None] = BudgetedLRU(
            FACTOR_CACHE_FLOATS, _factor_floats
        )
        self._freed: tuple[bytes, list] | None = None  # see _slack_bounds
        self._reduced: BudgetedLRU[tuple, _Reduced] = BudgetedLRU(
            REDUCED_CACHE_FLOATS, _reduced_floats
        )
        self._token: int | None = None  # the token of the Hessian P (None: not cached)
        self._recent: list[tuple[int, ...]] = []  # see RECENT_SETS
        self._recent_stats = [0, 0, 0]  # tries, hits, warm failures without a try
        self._repair_stats = [0, 0, 0]  # the same for the repair (see _pays)
        self._pivot_key = self.pivots.tobytes()
        self._osqp_P: np.ndarray | None = None  # the Hessian the OSQP object holds (None: P)

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        for key in (
            "_factors",
            "_osqp_P",
            "_freed",
            "_reduced",
            "_token",
            "_recent",
            "_recent_stats",
            "_repair_stats",
        ):
            state.pop(key, None)
        return state

    def share_records(self, records: dict[str, list[int]]) -> None:
        """Keep the records of the warm tries (see :func:`_pays`) in ``records`` (keys
        ``"recent"`` and ``"repair"``), shared by the families of one controller: they behave
        alike, and a family built late then starts from what the others learned, not from a
        trial of its own (:data:`RECENT_TRIAL` tries, most of them failed exact solves).
        Not kept through pickling (a family unpickled keeps its own records)."""
        self._recent_stats = records.setdefault("recent", [0, 0, 0])
        self._repair_stats = records.setdefault("repair", [0, 0, 0])

    def update_P(self, P: np.ndarray, token: int | None = None) -> None:
        """:meth:`QPFamily.update_P`, with the OSQP object brought up to date only when OSQP
        runs next (most solves are answered by the warm active set without OSQP). An unchanged
        ``P`` changes nothing; the first ``P`` keeps the full enumeration allowed (the family's
        constructor only had a placeholder). ``token``: an integer that names this ``P`` and
        no other (the caller's promise: ``P`` is read-only and the token never reused for
        another), under which the reduced Hessians of its active sets are cached; None: not
        cached."""
        if self._has_P and (P is self.P or np.array_equal(P, self.P)):
            self._token = token
            return
        self._token = None  # until P is replaced (update_P may raise)
        if self._osqp is not None and self._osqp_P is None:
            self._osqp_P = self.P
        solver, self._osqp = self._osqp, None
        try:
            super().update_P(P)  # checks P, replaces it, clears the caches
        finally:
            self._osqp = solver
        if not self._has_P:
            self._has_P = True
            self.can_enumerate = self._may_enumerate
        self._pivot_key = self.pivots.tobytes()
        self._token = token

    def run_osqp(self, w: np.ndarray, retry: bool = False) -> tuple:
        if self._osqp is not None and self._osqp_P is not None:
            target, self.P = self.P, self._osqp_P
            super().update_P(target)  # OSQP updated in place (same pattern) or dropped
        self._osqp_P = None
        return super().run_osqp(w, retry)

    def _factor(self, rows: tuple[int, ...]) -> ActiveSetFactor | None:
        """The active set's factor (:func:`controllers.kkt.active_set_factor`, a function of the
        rows and of which variables have no curvature; cached within
        :data:`FACTOR_CACHE_FLOATS`), or None when its rows are dependent."""
        return self._factors.get((rows, self._pivot_key), self._new_factor, rows)

    def _new_factor(self, rows: tuple[int, ...]) -> ActiveSetFactor | None:
        self.factorizations += 1
        return active_set_factor(self.C, rows, self.pivots)

    def _new_reduction(self, fac: ActiveSetFactor) -> _Reduced:
        self.factorizations += 1
        return _reduce(fac, self.P)

    def verify(
        self, rows: tuple[int, ...], w: np.ndarray, report: dict | None = None
    ) -> list[float] | None:
        """``z`` if the active set ``rows`` gives the optimum of instance ``w``, else None: the
        engine's one KKT test (:func:`controllers.kkt.check_active_set`, the numbers of
        :meth:`controllers.kkt_maps.ActiveSetMaps.check`) for the one instance. ``report``: see
        :func:`controllers.kkt.check_active_set`."""
        if report is not None:
            report.update(add=[], drop=[])
        if len(rows) > self.d:
            return None
        fac = self._factor(rows)
        if fac is None:
            return None
        red, maps = self._reduction(fac, count=True)
        if red is None:  # not a candidate
            return None
        return check_active_set(fac, self.P, self.C, w, self.absC, report, red, maps)

    def _reduction(self, fac: ActiveSetFactor, count: bool = False) -> tuple:
        """``(red, maps)`` of the active set of ``fac`` with the current ``P``: its reduced
        Hessian (None: not a candidate) and its stacked maps (None until the pair's second
        test, counted with ``count``); kept under the Hessian's token, computed afresh without
        one."""
        if self._token is None:
            self.factorizations += 1
            return reduce_hessian(fac, self.P), None
        entry = self._reduced.get((self._token, fac.rows), self._new_reduction, fac)
        if count and entry.red is not None:
            entry.uses += 1
            if entry.uses == 2 and entry.mappable:  # a pair tested again: worth its maps
                entry.maps = stacked_maps(fac, entry.red, self.P)
        return entry.red, entry.maps

    def direction(self, rows: tuple[int, ...], dw: np.ndarray) -> np.ndarray | None:
        """The change of the exact solution of the active set ``rows`` for the change ``dw`` of
        the instance (the same linear map; no test), or None."""
        fac = self._factor(rows)
        if fac is None:
            return None
        red, maps = self._reduction(fac)
        if red is None:
            return None
        with np.errstate(over="ignore", invalid="ignore"):
            W2 = np.concatenate([dw, np.abs(dw)])[:, None]
            dz = solve_stacked(fac, red, self.P, W2, maps)[0][: self.d, 0]
        return dz if np.all(np.isfinite(dz)) else None

    def warm_solve(self, w: np.ndarray) -> Solution | None:
        """The last active set, then the sets optimal before it (:data:`RECENT_SETS`, while they
        pay: :data:`RECENT_PAYOFF`), then up to :data:`WARM_REPAIR_STEPS` primal-dual
        active-set steps from the last one (see :meth:`repair`; by the same rule): the
        probabilities of a fixed-point iteration, or the next state of a closed loop, move the
        optimum's active set by a few rows, often back to a set met before, which these tries
        find at the cost of a few exact solves. Neither is tried when the last set is far from
        the optimum on a large family (:meth:`_far`): Clarabel's hint comes first there."""
        rows = self.warm
        assert rows is not None  # solve() calls this only with a warm active set
        recent = self._recent
        if rows in recent:
            recent.remove(rows)
        recent.insert(0, rows)
        del recent[RECENT_SETS:]
        report: dict = {}
        out = self.verify(rows, w, report)
        if out is not None:
            return Solution(out, rows, "warm")
        if self._far(report):  # a distant optimum: Clarabel's hint, before DAQP, finds it
            return None
        stats = self._recent_stats  # tries, hits, skipped
        if _pays(stats):
            for other in recent[1:]:
                stats[0] += 1
                out = self.verify(other, w)
                if out is not None:
                    stats[1] += 1
                    return Solution(out, other, "recent")
        if not _pays(self._repair_stats):
            return None
        self._repair_stats[0] += 1
        sol = self.repair(set(rows), w, report, WARM_REPAIR_STEPS)
        if sol is None:
            return None
        self._repair_stats[1] += 1
        return Solution(sol.z, sol.rows, "repair")

    def repair(
        self,
        rows: set[int],
        w: np.ndarray,
        report: dict,
        steps: int = REPAIR_STEPS,
        budget: bool = False,
    ) -> Solution | None:
        """Up to ``steps`` primal-dual active-set steps from the active set
        ``rows``, whose KKT test at ``w`` failed with ``report`` (see
        :func:`controllers.kkt.check_active_set`): the rows whose multipliers are negative leave
        the set, the violated rows join it (the most violated first, up to ``d`` rows), and the
        new set is verified. None when no set verifies (or a set repeats), or, with ``budget``,
        once the instance's budget of factorizations is spent (:meth:`open_budget`)."""
        seen = {tuple(sorted(rows))}
        freed = self._slack_bounds()
        for _ in range(steps):
            if not (report["add"] or report["drop"]):
                return None
            if budget and self.over_budget():
                return None
            kept = rows.difference(report["drop"])
            add = report["add"][: max((self.d - len(kept)) // 2, 1)]
            # a violated row joins with its slack free (its bound rho >= 0 leaves the set)
            rows = kept.union(add).difference(*[freed[i] for i in add])
            key = tuple(sorted(rows))
            if key in seen:
                return None
            seen.add(key)
            out = self.verify(key, w, report)
            if out is not None:
                return Solution(out, key, "repair")
        return None

    def _mend_hint(
        self, rows: tuple[int, ...], w: np.ndarray, report: dict
    ) -> tuple[tuple[int, ...], list[float] | None]:
        """Clarabel's hint (see :mod:`controllers.qp_ipm`) with every row violated at its
        solution joined, when none of its multipliers is negative: the indicator misses a few
        weakly active rows, and joining them makes most hints verify
        (results/speed/HISTORY.md)."""
        if report["drop"] or not report["add"] or len(rows) + len(report["add"]) > self.d:
            return rows, None
        key = tuple(sorted(set(rows).union(report["add"])))  # the slacks' bounds stay
        out = self.verify(key, w)
        return (rows, None) if out is None else (key, out)

    def _slack_bounds(self) -> list[tuple[int, ...]]:
        """Per one-sided row, the bound rows on the slacks it involves (variables without
        curvature, :attr:`pivots`); cached per pattern of slacks."""
        if self._freed is None or self._freed[0] != self._pivot_key:
            single = np.count_nonzero(self.C, axis=1) == 1
            bound_of: dict[int, list[int]] = {}
            for i in np.flatnonzero(single).tolist():
                bound_of.setdefault(int(np.flatnonzero(self.C[i])[0]), []).append(i)
            on = (self.C != 0.0) & self.pivots[None, :]
            freed = [
                tuple(b for j in np.flatnonzero(on[i]).tolist() for b in bound_of.get(j, ()))
                if not single[i]
                else ()
                for i in range(self.c)
            ]
            self._freed = (self._pivot_key, freed)
        return self._freed[1]

    def local(self, z: np.ndarray, w: np.ndarray, y: np.ndarray | None = None) -> Solution | None:
        """:meth:`QPFamily.local`, then up to :data:`REPAIR_STEPS` primal-dual active-set
        steps from the rows the solver left nearly active: the rows whose multipliers are
        negative leave the set and the violated rows join it (the most violated first, up to
        ``d`` rows), and the new set is verified. A node of tiny path probability, or the
        stages whose costs a huge state dwarfs, can need rows that the solver, blind to their
        weight, left otherwise."""
        sol = super().local(z, w, y)
        if sol is not None:
            return sol
        rows = set(self.near_active(z, w, loose=True).tolist())
        if len(rows) > self.d or self.over_budget():
            return None
        report: dict = {}
        key = tuple(sorted(rows))
        out = self.verify(key, w, report)
        if out is not None:
            return Solution(out, key, "")
        sol = self.repair(rows, w, report, budget=True)
        return None if sol is None else Solution(sol.z, sol.rows, "")


def solve_condensed_cvxpy(
    P: np.ndarray, w: np.ndarray, engine: QPFamily
) -> tuple[np.ndarray, np.ndarray] | None:
    """The condensed QP ``min 1/2 z'Pz + q'z  s.t.  C z <= h`` with cvxpy + Clarabel (the
    fallback of the fast path): ``(z, y)`` or None, with ``y`` the multipliers in OSQP's form
    (one per row of ``A``: positive where its upper side is active, negative for the lower), a
    hint for :meth:`controllers.qp.QPFamily.local`."""
    import cvxpy as cp

    d = engine.d
    z = cp.Variable(d)
    objective = 0.5 * cp.quad_form(z, cp.psd_wrap(P)) + w[:d] @ z
    rows = engine.C @ z <= w[d:]
    problem = cp.Problem(cp.Minimize(objective), [rows])
    try:
        problem.solve(solver=cp.CLARABEL, **CLARABEL_SETTINGS)
    except Exception:  # noqa: BLE001 - an episode must not crash on a solver error
        return None
    # an inaccurate answer is still a useful hint: the caller verifies its active set exactly
    if problem.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or z.value is None:
        return None
    if not np.all(np.isfinite(z.value)) or rows.dual_value is None:
        return None
    lam = np.asarray(rows.dual_value, dtype=np.float64).reshape(-1)
    y = np.zeros(engine.A.shape[0])
    nu = engine.upper_idx.size
    np.add.at(y, engine.upper_idx, lam[:nu])
    np.subtract.at(y, engine.lower_idx, lam[nu:])
    return np.asarray(z.value, dtype=np.float64), np.nan_to_num(y)


def solve_tree_cvxpy(s: HorizonSettings, steps: int, fam: Any, x: np.ndarray, k: int, pr: Any):
    """The tree written plainly with cvxpy (node by node, from the model's matrices), solved
    by Clarabel: ``(nu (M, m), rho (M,), value)`` or None."""
    import cvxpy as cp

    model, tree = s.model, fam.tree
    M, m, n = tree.size, model.m, model.n
    nu = cp.Variable((M, m))
    rho = cp.Variable(M, nonneg=True)
    At, B, K = s.A_tilde, model.B, s.K
    noise = model.noise_cov
    means: list[Any] = [None] * M
    covs = [np.zeros((n, n))] * M
    objective = 0.0
    constraints = [cp.abs(nu) <= s.nu_bound]
    for i in range(M):
        th, a = int(tree.mode[i]), int(tree.parent[i])
        if a < 0:
            means[i] = x
        else:
            tp = int(tree.mode[a])
            means[i] = At[tp] @ means[a] + B[tp] @ nu[a]  # eq. (sys:stabilized_input)
            covs[i] = At[tp] @ covs[a] @ At[tp].T + noise[tp]
        mean, cov = means[i], covs[i]
        u = K[th] @ mean + nu[i]
        stage = (
            cp.quad_form(mean, model.Q[th])
            + float(np.trace(model.Q[th] @ cov))
            + cp.quad_form(u, model.R[th])
            + float(np.trace(K[th].T @ model.R[th] @ K[th] @ cov))
        )
        weight = float(pr.weight[i])
        objective = objective + weight * (stage + s.alpha * rho[i])
        mean_next = At[th] @ mean + B[th] @ nu[i]
        cov_next = At[th] @ cov @ At[th].T + noise[th]
        band = model.H0 + (k + tree.stage[i] + 1) * model.H_rate
        constraints.append(model.G @ mean_next <= band - fam.tightening[i] + rho[i])
        if tree.stage[i] == steps - 1:
            for j in range(model.N):
                bj = float(pr.branch[i, j])
                if bj > 0.0:
                    term = cp.quad_form(mean_next, s.Psi[j]) + float(np.trace(s.Psi[j] @ cov_next))
                    objective = objective + weight * bj * term
    with warnings.catch_warnings():  # node by node on purpose: the reference stays plain
        warnings.filterwarnings("ignore", "Objective contains too many subexpressions")
        problem = cp.Problem(cp.Minimize(objective), constraints)
    for options in (TREE_CLARABEL_SETTINGS, CLARABEL_SETTINGS):  # tight, then P3's
        try:
            problem.solve(solver=cp.CLARABEL, **options)
        except Exception:  # noqa: BLE001 - an episode must not crash on a solver error
            continue
        if problem.status == cp.OPTIMAL and nu.value is not None and rho.value is not None:
            break
    else:
        return None
    nu_v = np.asarray(nu.value, dtype=np.float64).reshape(M, m)
    rho_v = np.asarray(rho.value, dtype=np.float64).reshape(M)
    value = float(problem.value)
    if not (np.all(np.isfinite(nu_v)) and np.all(np.isfinite(rho_v)) and math.isfinite(value)):
        return None
    return nu_v, rho_v, value
