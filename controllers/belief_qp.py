"""The QP of problem P3 on a belief: its rows for a set of kept modes, and its verified solve.

In ``z = (nu, rho)`` the belief controller's problem (:mod:`controllers.belief`) is::

    min 1/2 z'P z + q'z   s.t.   C z <= h,     P = [[2 H(pi), 0], [0, 0]]

with the rows, in the order of P3's family (:mod:`controllers.p3`), ``[G B_i, -1]`` for each
kept mode ``i`` (ascending), the box ``|nu_j| <= nu_bound`` (upper sides, then lower sides) and
``rho >= 0``. For one kept mode this is exactly P3's QP. The Hessian ``H(pi)`` changes with the
belief at every decision. With one input (``m = 1``) it is a positive number and the instance is
divided by it (the objective scaled: the same minimizer and active set), so that each kept set
has a fixed Hessian and the exact maps of its active sets (:mod:`controllers.kkt_maps`) are
cached as P3's are; with more inputs the exact solution of an active set is computed for the one
instance (:func:`controllers.kkt.check_active_set`), with the factor that depends only on the
rows cached. Either way the test is the one KKT test of every receding-horizon QP.

How an instance is solved (:meth:`BeliefQP.solve`): with one input, the kept set's last active
set and the sets optimal before it, then DAQP in a workspace kept per kept set; with more, DAQP's
``daqp.solve`` on the QP as it is, warm-started from the last set (cheaper than testing a warm
set that fails), then the warm sets and a few primal-dual steps from them; then the engine's
equilibrated DAQP (:func:`controllers.dual_qp.run_daqp`, then on regularized objectives), or
OSQP with ``"osqp"``, each answer's active set verified (its multipliers', then subsets of the
rows it leaves nearly active); then every candidate active set (at most
:data:`controllers.qp.MAX_CANDIDATES`). Every answer is the exact solution of an active set that
passed the KKT test. ``"active_set"`` enumerates at every call.
"""

from __future__ import annotations

from collections.abc import Iterator
from itertools import chain, combinations
from typing import Any

import numpy as np
import osqp
import scipy.sparse as sp

from .belief_rows import KeptRows, daqp_rows, kept_rows
from .dual_qp import DAQP_INF, REGULARIZE, DaqpWorkspace, daqp_data, run_daqp
from .kkt import ActiveSetFactor, HessianFreeMaps, active_set_factor, check_active_set
from .kkt_maps import ActiveSetMaps, active_set_maps, hessian_free_maps
from .lru import BudgetedLRU
from .qp import MAX_CANDIDATES, Solution, candidate_count
from .qp_daqp import NEAR_ACTIVE_TOL, DaqpAnswer, active_set_of_multipliers, first_verified
from .qp_search import MAX_LOCAL_CANDIDATES

__all__ = ["FACTOR_CACHE_FLOATS", "RECENT_SETS", "REPAIR_STEPS", "SCREEN_TOL", "BeliefQP"]

#: Floats of the active-set factors kept (least recently used dropped first; 16 MB).
FACTOR_CACHE_FLOATS = 2_000_000

#: Active sets remembered per kept set (the last and those optimal before it), tried in turn.
RECENT_SETS = 3

#: The loose relative tolerance of :meth:`BeliefQP.screen` (a guess far from passing the KKT
#: test is not worth the test).
SCREEN_TOL = 1e-7

#: Primal-dual active-set steps from a warm guess that fails the screen.
REPAIR_STEPS = 2


def _floats(entry: Any) -> int:
    """Floats held by a cached factor or maps (1 for a set that is not a candidate)."""
    if entry is None:
        return 1
    if isinstance(entry, ActiveSetFactor):
        return max(1, entry.floats)
    if isinstance(entry, HessianFreeMaps):
        return max(1, entry.Fz.size + entry.Fl.size)
    return max(1, entry.RZ.size + entry.T.size)


def _maps(P: np.ndarray, kr: KeptRows, rows: tuple[int, ...]) -> ActiveSetMaps | None:
    return active_set_maps(P, kr.C, rows, pivots=kr.pivots)


class BeliefQP:
    """The belief controller's QPs, one row structure per kept set, and their verified solve.

    Parameters
    ----------
    GB : (N, r, m) array
        ``G B_i`` of every mode.
    osqp_settings : dict
        OSQP's settings for ``method="osqp"``.

    Notes
    -----
    With one input (``m = 1``) the Hessian is ``diag(2 h, 0)`` with ``h > 0``: the instance is
    divided by ``h`` (the objective scaled, the same minimizer and active set), so that every
    kept set has a fixed Hessian ``diag(2, 0)``, and the exact maps of its active sets
    (:func:`controllers.kkt_maps.active_set_maps`, the same KKT test) are cached as P3's are.
    With more inputs each active set is solved for the one instance
    (:func:`controllers.kkt.check_active_set`), after a cheap screen of the warm guesses (a
    dense solve of its KKT system, a loose test) that keeps the full test for the likely one;
    an active set whose rows fix every variable (the most common) is solved by two cached
    products (:class:`controllers.kkt.HessianFreeMaps`): its solution does not depend on the
    Hessian, which enters its multipliers through ``P z`` only.

    Holds solver state (warm active sets, caches): not thread-safe by itself, the controller's
    lock covers it. Pickles without its caches (rebuilt on use).
    """

    def __init__(self, GB: np.ndarray, osqp_settings: dict[str, Any]) -> None:
        self.GB = GB
        self.osqp_settings = dict(osqp_settings)
        m = GB.shape[2]
        self.fixed = m == 1  # one input: the scaled instance has a fixed Hessian
        self.P1 = np.diag([2.0, 0.0]) if self.fixed else None
        self._reset_state()

    def _reset_state(self) -> None:
        self._structures: dict[tuple[int, ...], KeptRows] = {}
        self._factors: BudgetedLRU[tuple, Any] = BudgetedLRU(FACTOR_CACHE_FLOATS, _floats)
        self._recent: dict[tuple[int, ...], list[tuple[int, ...]]] = {}
        self._daqp: dict[tuple[int, ...], Any] = {}  # per kept set: DaqpWorkspace or DaqpData
        self._daqp_rows: dict[tuple[int, ...], tuple] = {}  # see belief_rows.daqp_rows

    def __getstate__(self) -> dict[str, Any]:
        return {"GB": self.GB, "osqp_settings": self.osqp_settings, "fixed": self.fixed,
                "P1": self.P1}  # fmt: skip

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._reset_state()

    def rows(self, modes: tuple[int, ...]) -> KeptRows:
        """The :class:`KeptRows` of ``modes`` (built once)."""
        kr = self._structures.get(modes)
        if kr is None:
            kr = self._structures[modes] = kept_rows(self.GB, modes)
        return kr

    def normalize(self, P: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(P, w)`` as the solve sees them: with one input, ``(diag(2, 0), w / h)`` on the
        linear part (``h = P[0, 0] / 2 > 0``); else unchanged."""
        if not self.fixed:
            return P, w
        scale = 0.5 * float(P[0, 0])
        w = w.copy()
        w[:2] /= scale
        assert self.P1 is not None
        return self.P1, w

    # ------------------------------------------------------------------ the KKT test
    def verify(
        self, kr: KeptRows, rows: tuple[int, ...], P: np.ndarray, w: np.ndarray
    ) -> list[float] | None:
        """``z`` if the active set ``rows`` gives the optimum of the (normalized) instance
        ``w = [q; h]`` with Hessian ``P``, else None: the one KKT test of :mod:`controllers.kkt`
        (the cached maps with one input, :func:`controllers.kkt.check_active_set` else)."""
        if len(rows) > kr.d:
            return None
        if self.fixed:
            maps = self._factors.get((kr.modes, rows, "maps"), _maps, P, kr, rows)
            return None if maps is None else maps.check(w)
        fac = self._factors.get((kr.modes, rows), active_set_factor, kr.C, rows, kr.pivots)
        if fac is None:
            return None
        # rows that fix every variable: two cached products (the Hessian changes per decision)
        free = self._factors.get((kr.modes, rows, "free"), hessian_free_maps, fac, kr.d)
        return check_active_set(fac, P, kr.C, w, kr.absC, maps=free)

    def screen(
        self, kr: KeptRows, rows: tuple[int, ...], P: np.ndarray, w: np.ndarray
    ) -> tuple[bool, list[int], list[int]]:
        """A cheap, loose test of a guess: ``(passes, add, drop)`` from the dense KKT system of
        the active set ``rows`` (rows violated beyond :data:`SCREEN_TOL` of their terms, most
        violated first; active rows whose multipliers are negative beyond it). Only a guess
        that passes goes to :meth:`verify`; nothing is accepted on it."""
        d, idx = kr.d, list(rows)
        s = len(idx)
        if s > d:
            return False, [], []
        CS = kr.C[idx]
        K = np.zeros((d + s, d + s))
        K[:d, :d], K[:d, d:], K[d:, :d] = P, CS.T, CS
        h = w[d:]
        try:
            sol = np.linalg.solve(K, np.concatenate([-w[:d], h[idx]]))
        except np.linalg.LinAlgError:
            return False, [], []
        if not np.isfinite(sol).all():
            return False, [], []
        z, lam = sol[:d], sol[d:]
        excess = kr.C @ z - h
        tol = SCREEN_TOL * (kr.absC @ np.abs(z) + np.abs(h))
        excess[idx] = 0.0
        add = np.flatnonzero(excess > tol)
        scale = float(np.max(np.abs(P) @ np.abs(z) + np.abs(w[:d])))
        drop = [r for r, v in zip(idx, (lam * kr.absC[idx].max(axis=1)).tolist(), strict=True)
                if v < -SCREEN_TOL * scale]  # fmt: skip
        order = add[np.argsort(-(excess[add] / np.maximum(tol[add], 1e-300)), kind="stable")]
        return not (add.size or drop), order.tolist(), drop

    def _guess(
        self, kr: KeptRows, rows: tuple[int, ...], P: np.ndarray, w: np.ndarray, path: str
    ) -> Solution | None:
        """A warm guess: verified directly with fixed maps, else after :meth:`screen` and up to
        :data:`REPAIR_STEPS` primal-dual active-set steps (negative multipliers leave, the most
        violated row joins)."""
        if self.fixed:
            z = self.verify(kr, rows, P, w)
            return None if z is None else Solution(z, rows, path)
        seen = set()
        for _ in range(REPAIR_STEPS + 1):
            seen.add(rows)
            ok, add, drop = self.screen(kr, rows, P, w)
            if ok:
                z = self.verify(kr, rows, P, w)
                return None if z is None else Solution(z, rows, path)
            new = set(rows) - set(drop)
            for r in add:
                if len(new) < kr.d:
                    new.add(r)
                    break
            rows = tuple(sorted(new))
            if rows in seen or not (add or drop):
                return None
            path = "repair"
        return None

    # ------------------------------------------------------------------ the chain
    def solve(
        self,
        kr: KeptRows,
        P: np.ndarray,
        w: np.ndarray,
        *,
        method: str = "daqp",
        warm: bool = True,
        notes: list[str] | None = None,
    ) -> Solution | None:
        """The exact, verified solution of instance ``w`` with Hessian ``P``, or None.

        ``method``: ``"daqp"`` or ``"osqp"`` (which solver finds the active set after the warm
        guesses) or ``"active_set"`` (the enumeration alone). ``Solution.path`` is ``"warm"``,
        ``"recent"``, ``"repair"``, ``"daqp"``, ``"osqp"`` or ``"enumeration"``; ``notes``
        receives what failed on the way. ``z`` solves the instance as given (the normalization
        of one input changes the objective's scale, not its minimizer)."""
        notes = [] if notes is None else notes
        P, w = self.normalize(P, w)
        recent = self._recent.setdefault(kr.modes, [])
        sol = None
        if method != "active_set":
            sol = self._found(kr, P, w, method, recent if warm else [], notes)
        if sol is None:
            sol = self.enumerate(kr, P, w)
            if sol is None:
                notes.append("no enumerated active set verified")
                return None
        if sol.rows in recent:
            recent.remove(sol.rows)
        recent.insert(0, sol.rows)
        del recent[RECENT_SETS:]
        return sol

    def _found(
        self,
        kr: KeptRows,
        P: np.ndarray,
        w: np.ndarray,
        method: str,
        recent: list[tuple[int, ...]],
        notes: list[str],
    ) -> Solution | None:
        """The ``recent`` sets and the solver of ``method``: with one input the cached maps make
        the recent sets cheap to test, so they come first; with more, the solver warm-started
        from the last set is cheaper than testing a set that fails, so they come after it."""
        sol = self._recent_guess(kr, recent, P, w) if self.fixed else None
        if sol is None and method == "daqp":
            sol = self._daqp_solve(kr, P, w, recent[0] if recent else None, notes)
        elif sol is None:
            sol = self._osqp_solve(kr, P, w, notes)
        if sol is None and not self.fixed:
            sol = self._recent_guess(kr, recent, P, w)
        return sol

    def _recent_guess(
        self, kr: KeptRows, recent: list[tuple[int, ...]], P: np.ndarray, w: np.ndarray
    ) -> Solution | None:
        """The first of the ``recent`` sets that :meth:`_guess` verifies (the last one's path
        ``"warm"``, the others' ``"recent"``), or None."""
        for i, rows in enumerate(recent):
            sol = self._guess(kr, rows, P, w, "warm" if i == 0 else "recent")
            if sol is not None:
                return sol
        return None

    def _daqp_solve(
        self,
        kr: KeptRows,
        P: np.ndarray,
        w: np.ndarray,
        start: tuple[int, ...] | None,
        notes: list[str],
    ) -> Solution | None:
        """DAQP, each answer's active set verified (its multipliers', then :meth:`_local`):
        with one input, its workspace kept per kept set (fixed Hessian; warm from its last
        solve, then cold); with more, :meth:`_daqp_direct` warm-started from ``start``, then
        the equilibrated QP (:func:`controllers.dual_qp.run_daqp`); then on regularized
        objectives."""
        d = kr.d
        held = self._daqp.get(kr.modes)
        attempts: list[tuple[str, float]] = []
        if self.fixed:
            if held is None:
                held = self._daqp[kr.modes] = DaqpWorkspace(daqp_data(P, kr.A, True))
            data = held.data
            attempts += [("workspace", 0.0), ("cold", 0.0)]
        else:
            sol = self._daqp_direct(kr, P, w, start)
            if sol is not None:
                return sol
            data = self._daqp[kr.modes] = daqp_data(P, kr.A, True, held)
            attempts.append(("scaled", 0.0))
        attempts += [("scaled", mu) for mu in REGULARIZE]
        lo, hi = kr.two_sided(w[d:])
        q = np.asarray(w[:d])

        def runs() -> Iterator[DaqpAnswer]:
            for how, mu in attempts:
                if how == "scaled":
                    yield run_daqp(data, q, lo, hi, None, mu)
                else:
                    assert held is not None  # the workspace of a fixed Hessian
                    yield held.solve(q, lo, hi, cold=how == "cold")

        return first_verified(runs(), lambda z, y: self._settle(kr, P, w, z, y, "daqp"), notes)

    def _daqp_direct(
        self, kr: KeptRows, P: np.ndarray, w: np.ndarray, start: tuple[int, ...] | None
    ) -> Solution | None:
        """DAQP's public ``daqp.solve`` on the QP as it is (the box and ``rho >= 0`` as its
        simple bounds), warm-started from the active set ``start``: the cheapest hint for a
        small, well-scaled QP; its active set verified."""
        import daqp

        d, nc = kr.d, kr.n_chance
        h = np.asarray(w[d:])
        m = d - 1
        held = self._daqp_rows.get(kr.modes)
        if held is None:
            held = self._daqp_rows[kr.modes] = daqp_rows(kr)
        rows, upper_of, lower_of, index, bits, lower = held
        bu = np.empty(d + nc)  # the box's upper sides, rho's (none), the chance rows'
        bu[:m] = h[nc : nc + m]
        bu[m] = DAQP_INF
        np.minimum(h[:nc], DAQP_INF, out=bu[d:])
        bl = lower.copy()  # the box's lower sides, rho >= 0, none for the chance rows
        np.negative(h[nc + m : nc + 2 * m], out=bl[:m])
        bl[m] = -h[-1]
        sense = np.zeros(d + nc, dtype=np.int32)
        if start:
            at = list(start)
            sense[index[at]] = bits[at]
        try:
            x, _, flag, info = daqp.solve(np.array(P), np.array(w[:d]), rows, bu, bl, sense)
        except Exception:  # noqa: BLE001 - only a hint: the equilibrated attempts follow
            return None
        z = np.asarray(x, dtype=np.float64)
        if flag != 1 or not np.isfinite(z).all():
            return None
        found = active_set_of_multipliers(np.asarray(info["lam"]), upper_of, lower_of, d)
        if found is not None:
            out = self.verify(kr, found, P, w)
            if out is not None:
                return Solution(out, found, "daqp")
        sol = self._local(kr, P, w, z)
        return None if sol is None else Solution(sol.z, sol.rows, "daqp")

    def _osqp_solve(
        self, kr: KeptRows, P: np.ndarray, w: np.ndarray, notes: list[str]
    ) -> Solution | None:
        """OSQP (set up for this Hessian), then its answer's active set verified."""
        d = kr.d
        lo, hi = kr.two_sided(w[d:])
        settings = dict(self.osqp_settings)
        for attempt in range(2):
            if attempt:
                settings["max_iter"] = 10 * int(settings["max_iter"])
            try:
                solver = osqp.OSQP()
                solver.setup(
                    sp.csc_matrix(np.triu(P)),
                    np.array(w[:d]),
                    sp.csc_matrix(kr.A),
                    np.maximum(lo, -1e30),
                    np.minimum(hi, 1e30),
                    **settings,
                )
                res = solver.solve(raise_error=False)
            except Exception as exc:  # noqa: BLE001 - an episode must not crash on a solver error
                notes.append(f"osqp error {type(exc).__name__}: {exc}")
                return None
            z = np.asarray(res.x, dtype=np.float64)
            if res.info.status_val == osqp.SolverStatus.OSQP_SOLVED and np.isfinite(z).all():
                sol = self._settle(kr, P, w, z, np.asarray(res.y, dtype=np.float64), "osqp")
                if sol is not None:
                    return sol
                notes.append("osqp answer did not verify")
            else:
                notes.append(f"osqp status {str(res.info.status)!r}")
        return None

    def _settle(
        self,
        kr: KeptRows,
        P: np.ndarray,
        w: np.ndarray,
        z: np.ndarray,
        y: np.ndarray | None,
        path: str,
    ) -> Solution | None:
        """The verified active set of a solver's answer ``z`` (multipliers ``y`` in OSQP's form,
        or None): the active set of the multipliers, then :meth:`local`."""
        rows = None if y is None else kr.rows_of_multipliers(y)
        if rows is not None:
            out = self.verify(kr, rows, P, w)
            if out is not None:
                return Solution(out, rows, path)
        sol = self._local(kr, P, w, z)
        return None if sol is None else Solution(sol.z, sol.rows, path)

    def local(self, kr: KeptRows, P: np.ndarray, w: np.ndarray, z: np.ndarray) -> Solution | None:
        """The verified active set around an approximate solution ``z`` of instance ``w`` with
        Hessian ``P`` (e.g. the cvxpy reference's), by :meth:`_local`; None if none verifies."""
        P, w = self.normalize(P, w)
        return self._local(kr, P, w, z)

    def _local(self, kr: KeptRows, P: np.ndarray, w: np.ndarray, z: np.ndarray) -> Solution | None:
        """The rows nearly active at an approximate solution ``z`` (within
        :data:`controllers.qp_daqp.NEAR_ACTIVE_TOL` of their terms, then of the row's size times
        the largest component) and their subsets, largest first: at most
        :data:`controllers.qp_search.MAX_LOCAL_CANDIDATES` sets tried."""
        d = kr.d
        h = np.asarray(w[d:])
        slack = h - kr.C @ z
        zmax = float(np.max(np.abs(z), initial=0.0))
        floor = kr.absC.sum(axis=1) * zmax
        nears = [
            np.flatnonzero(slack <= NEAR_ACTIVE_TOL * (terms + np.abs(h)))
            for terms in (kr.absC @ np.abs(z) + 1e-6 * floor, floor)
        ]
        subsets = (
            rows
            for near in nears
            for size in range(min(near.size, d), -1, -1)
            for rows in combinations(near.tolist(), size)
        )
        tried: set[tuple[int, ...]] = set()
        for rows in subsets:
            if rows in tried:
                continue
            tried.add(rows)
            if len(tried) > MAX_LOCAL_CANDIDATES:
                return None
            out = self.verify(kr, rows, P, w)
            if out is not None:
                return Solution(out, rows, "")
        return None

    def enumerate(self, kr: KeptRows, P: np.ndarray, w: np.ndarray) -> Solution | None:
        """Every candidate active set (largest first, then lexicographic; the first that
        verifies), when there are at most :data:`controllers.qp.MAX_CANDIDATES`; else None."""
        c, d = kr.C.shape[0], kr.d
        if candidate_count(c, d) > MAX_CANDIDATES:
            return None
        sets = chain.from_iterable(
            combinations(range(c), size) for size in range(min(d, c), -1, -1)
        )
        for rows in sets:
            out = self.verify(kr, rows, P, w)
            if out is not None:
                return Solution(out, rows, "enumeration")
        return None
