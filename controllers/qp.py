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
2. *OSQP*: the family's ``osqp.OSQP`` object (set up on first use; later only ``update`` and a
   warm-started ``solve``) finds an approximate optimum; the active set it identifies (nonzero
   multipliers, then the rows it leaves nearly active) is re-solved exactly and verified.
3. *Enumeration*: the candidate active sets among the rows OSQP left nearly active; then, when the
   family is small enough (:data:`MAX_CANDIDATES`), every candidate active set.
4. OSQP again from a cold start with ten times the iterations, then steps 2-3.

The caller (the controller) decides what to do when all of this fails (the cvxpy reference, then
a safe default). Every answer this class returns is the exact solution of the equality-
constrained KKT system of a verified active set, so it is a function of the instance and the
active set, not of the path that found it.

Exact solve of an active set
----------------------------
For an active set ``S`` (rows of ``C``), the solution and the multipliers are linear maps of
``w`` (:func:`active_set_maps`). The active rows and the variables are first equilibrated (Ruiz
scaling of ``C_S``; a variable in no active row by its curvature), then the null-space method runs
on the scaled, row-normalized rows: ``C_S' = Q R``, ``z = Q1 R1^{-T} h_S + Q2 y`` with
``(Q2' P Q2) y = -Q2'(q + P z_p)``, and the multipliers from stationarity. Components that do not
depend on a datum get exact zeros in its column (a vertex does not depend on ``q`` at all), so a
huge slack penalty or a loose bound does not leak round-off into the answer. A set is a candidate
only if its scaled rows are linearly independent and the reduced Hessian is positive definite,
relative to its own scale.

Tolerances relative to scale
----------------------------
The KKT test accepts an active set when every primal residual ``C_i z - h_i`` of an inactive row
and every negated multiplier is at most :data:`KKT_TOL` times the magnitude of the terms summed
to compute it. Those magnitudes are carried through every intermediate product with absolute
values (so a cancellation, e.g. a particular solution and a correction of 2.27 each, is not
mistaken for a small term), in the equilibrated variables. The test is therefore invariant under
a scaling of the rows, of the variables or of the objective, and one loose row (a bound of 1e9)
or a huge penalty (1e12) does not widen the tolerance of the others.

Thread safety
-------------
A family holds mutable solver state (the OSQP object, the warm start, caches). It is not
thread-safe by itself: the controllers hold a lock around every call (see
:class:`controllers.base.Controller`).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import lru_cache
from itertools import chain, combinations
from typing import Any

import numpy as np
import osqp
import scipy.sparse as sp

from sdjls_gym.messages import describe
from sdjls_gym.validation import check_mapping

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

#: Relative tolerance of the KKT test: a residual is accepted when it is at most this fraction of
#: the magnitude of the terms summed to compute it.
KKT_TOL = 1e-9

#: Largest number of candidate active sets enumerated up front (all subsets of at most ``d`` of
#: the one-sided rows). Families with more are solved by OSQP and an exact re-solve of the active
#: set it finds, with a local enumeration around it; see :func:`candidate_count`.
MAX_CANDIDATES = 4096

#: Largest number of floats the stacked maps of one family's enumeration may hold (16 MB).
MAX_ENUMERATION_FLOATS = 2_000_000

#: Largest number of floats the enumerations of one controller hold together (128 MB): beyond,
#: the least recently used family's enumeration is dropped (and rebuilt when needed again).
ENUMERATION_BUDGET_FLOATS = 16_000_000

#: Candidate active sets tried around an OSQP solution (subsets of its nearly active rows).
MAX_LOCAL_CANDIDATES = 256

#: Exact active-set maps kept per family (least recently used are dropped).
MAX_CACHED_MAPS = 512

#: A row whose residual at OSQP's solution is within this fraction of its terms counts as nearly
#: active (OSQP's polished solutions are accurate to ~1e-10 relative).
NEAR_ACTIVE_TOL = 1e-6

#: Rank and definiteness thresholds of the exact solve, relative to the scale of the matrices.
_RANK_TOL = 1e-11
_PD_TOL = 1e-12

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
        Nonnegative: ``T |w|`` is the magnitude of the terms summed to compute each residual.
    """

    rows: tuple[int, ...]
    Z: np.ndarray
    R: np.ndarray
    T: np.ndarray
    RZ: np.ndarray = field(init=False, repr=False)  # [R; Z]: residuals and z in one product

    def __post_init__(self) -> None:
        object.__setattr__(self, "RZ", np.vstack([self.R, self.Z]))

    def check(self, w: np.ndarray) -> list[float] | None:
        """``z`` (a list of d floats) if the active set passes the KKT test at ``w``, else None."""
        v = (self.RZ @ w).tolist()
        nr = self.R.shape[0]
        worst = max(v[:nr], default=-math.inf)
        z = v[nr:]
        if not math.isfinite(worst + sum(z)):  # NaN or inf anywhere
            return None
        if worst > 0.0:  # a residual above 0: within round-off of its terms?
            tol = KKT_TOL * (self.T @ np.abs(w))
            if not np.all(np.asarray(v[:nr]) <= tol):
                return None
        return z


def _equilibrate(P: np.ndarray, CS: np.ndarray, sweeps: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Scalings ``(Dc, Dr)`` of the variables and of the active rows: Ruiz equilibration of the
    active rows ``CS`` (every row and every column of ``Dr CS Dc`` then has its largest entry
    near 1); a variable in no active row is scaled by its curvature, ``1 / sqrt(P_ii)``.
    Variables of very different sizes (an offset of 1 next to a slack of 1e12, rows scaled by
    1e-11) then get comparable scaled sizes, and rank and conditioning are judged in them."""
    d, s = P.shape[0], CS.shape[0]
    absC = np.abs(CS)
    Dc, Dr = np.ones(d), np.ones(s)
    used = absC.max(axis=0, initial=0.0) > 0.0
    for _ in range(sweeps):
        scaled = absC * Dr[:, None] * Dc[None, :]
        row = scaled.max(axis=1, initial=0.0)
        col = scaled.max(axis=0, initial=0.0)
        fr = np.sqrt(np.where(row > 0.0, row, 1.0))
        fc = np.sqrt(np.where(col > 0.0, col, 1.0))
        if np.all(np.abs(fr - 1.0) < 1e-6) and np.all(np.abs(fc - 1.0) < 1e-6):
            break
        Dr, Dc = Dr / fr, Dc / fc
    diag = np.abs(np.diag(P))
    free = ~used & (diag > 0.0)
    Dc[free] = 1.0 / np.sqrt(diag[free])
    return Dc, Dr


def active_set_maps(P: np.ndarray, C: np.ndarray, rows: tuple[int, ...]) -> ActiveSetMaps | None:
    """The maps of :class:`ActiveSetMaps` for ``min 1/2 z'Pz + q'z  s.t.  C_S z = h_S``.

    Computed on the equilibrated KKT system (:func:`_equilibrate`; ``z = Dc z~``), by the
    null-space method on row-normalized constraints. Returns None when the active set is not a
    candidate: its rows are linearly dependent, or the reduced Hessian on their null space is not
    positive definite (the minimizer is not unique); both tests are made on the scaled system,
    so they do not depend on the units of the variables or of the rows.
    """
    d, c = P.shape[0], C.shape[0]
    s = len(rows)
    if s > d:
        return None
    idx = np.array(rows, dtype=np.int64)
    CS = C[idx]
    Dc, Dr = _equilibrate(P, CS)
    Pt = P * Dc[:, None] * Dc[None, :]
    Ct = CS * Dr[:, None] * Dc[None, :]
    norms = np.sqrt(np.einsum("ij,ij->i", Ct, Ct)) if s else np.zeros(0)
    if s and not np.all(norms > 0.0):
        return None
    Dn = Dr / norms if s else norms  # the full row scaling of the active rows
    Chat = CS * Dn[:, None] * Dc[None, :]
    select = np.zeros((s, c))
    select[np.arange(s), idx] = 1.0
    eye_q = np.hstack([np.diag(Dc), np.zeros((d, c))])  # q~ = Dc q
    eye_h = np.hstack([np.zeros((c, d)), np.eye(c)])
    if s:
        Q, Rfull = np.linalg.qr(Chat.T, mode="complete")
        R1 = Rfull[:s, :s]
        if not np.all(np.abs(np.diag(R1)) > _RANK_TOL):  # normalized rows: a scale-free test
            return None
        Q1, Q2 = Q[:, :s], Q[:, s:]
        R1inv_T = np.linalg.inv(R1.T)
        Zp_h = Q1 @ (R1inv_T @ (Dn[:, None] * select))  # z~_p = Q1 R1^{-T} D h_S
        # magnitude of the terms summed to compute z~_p, per datum (absolute values carried
        # through every product, so that cancellations are not mistaken for small terms)
        Tp_h = np.abs(Q1) @ (np.abs(R1inv_T) @ (Dn[:, None] * select))
    else:
        Q1, Q2, R1 = np.zeros((d, 0)), np.eye(d), np.zeros((0, 0))
        Zp_h, Tp_h = np.zeros((d, c)), np.zeros((d, c))
    Tp = np.hstack([np.zeros((d, d)), Tp_h])
    k = d - s
    if k:
        M = Q2.T @ Pt @ Q2
        M = 0.5 * (M + M.T)
        eig = np.linalg.eigvalsh(M)
        if not (eig[-1] > 0.0 and eig[0] > _PD_TOL * eig[-1]):
            return None
        Y = -np.linalg.inv(M) @ Q2.T  # y = Y (q~ + P~ z~_p)
        Zt_q = Q2 @ (Y * Dc[None, :])
        Zt_h = Zp_h + Q2 @ (Y @ Pt @ Zp_h)
        Tz = Tp + np.abs(Q2) @ (np.abs(Y) @ (np.abs(eye_q) + np.abs(Pt) @ Tp))
    else:
        Zt_q, Zt_h = np.zeros((d, d)), Zp_h
        Tz = Tp
    Zt = np.hstack([Zt_q, Zt_h])  # z~ = Zt w, (d, d + c)
    Z = Zt * Dc[:, None]  # z = Dc z~
    primal = C @ Z - eye_h
    # the terms of C_i z - h_i: |C_i| Dc times the largest term of any scaled component of z (a
    # component that is zero in exact arithmetic carries the round-off of the others), and |h_i|
    primal_T = (np.abs(C) @ Dc)[:, None] * Tz.max(axis=0, keepdims=True) + eye_h
    # the active rows hold with equality by construction: only the others are tested
    primal[idx] = 0.0
    primal_T[idx] = 0.0
    if s:
        # stationarity P~ z~ + q~ + Chat' lam_hat = 0  =>  lam_hat = -R1^{-1} Q1'(P~ z~ + q~);
        # lam_hat has the sign of the multiplier of the unscaled row
        Lmap = np.linalg.solve(R1, Q1.T)  # (s, d)
        lam = -Lmap @ (Pt @ Zt + eye_q)
        lam_T = np.abs(Lmap) @ (np.abs(Pt) @ Tz + np.abs(eye_q))
        R = np.vstack([primal, -lam])
        T = np.vstack([primal_T, lam_T])
    else:
        R, T = primal, primal_T
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(T)) and np.all(np.isfinite(Z))):
        return None
    return ActiveSetMaps(tuple(int(i) for i in rows), Z, R, T)


class EnumerationBudget:
    """The enumerations of several families (one controller's) kept within
    :data:`ENUMERATION_BUDGET_FLOATS`; least recently used first out. Not thread-safe (the
    controller's lock covers it); pickles empty."""

    def __init__(self, limit: int = ENUMERATION_BUDGET_FLOATS) -> None:
        self.limit = limit
        self._held: OrderedDict[int, tuple[QPFamily, int]] = OrderedDict()
        self._total = 0

    def __getstate__(self) -> dict[str, Any]:
        return {"limit": self.limit}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["limit"])

    def use(self, family: QPFamily, size: int) -> None:
        """Record that ``family`` holds an enumeration of ``size`` floats (now the most recently
        used) and drop the least recently used others while the total is above the limit."""
        key = id(family)
        if key in self._held:
            self._held.move_to_end(key)
            return
        self._held[key] = (family, size)
        self._total += size
        while self._total > self.limit and len(self._held) > 1:
            _, (old, s) = self._held.popitem(last=False)
            old._enum = None
            self._total -= s


@dataclass(frozen=True)
class Solution:
    """An exact, verified solution of one instance: ``z`` and its active set ``rows``."""

    z: list[float]
    rows: tuple[int, ...]
    path: str  # "warm", "osqp", "osqp_retry", "enumeration"


class QPFamily:
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
        self._reset_state()

    def _reset_state(self) -> None:
        self._maps: dict[tuple[int, ...], ActiveSetMaps | None] = {}
        self._osqp: osqp.OSQP | None = None
        self._enum: Any = None  # the ActiveSetQP of a full enumeration, built on first use
        self.warm: tuple[int, ...] | None = None

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        for key in ("_maps", "_osqp", "_enum", "warm"):
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
        self._maps.clear()
        self._enum = None
        self.can_enumerate = False

    # ------------------------------------------------------------------ data
    def one_sided_bounds(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """``h`` of ``C z <= h`` for bounds ``l, u`` of shape ``(..., c)``."""
        return np.concatenate([upper[..., self.upper_idx], -lower[..., self.lower_idx]], axis=-1)

    def bounds(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``l, u`` (c,) of OSQP's form from ``h`` (infinite where a side is absent)."""
        lo = np.full(self.A.shape[0], -np.inf)
        hi = np.full(self.A.shape[0], np.inf)
        nu = self.upper_idx.size
        hi[self.upper_idx] = h[:nu]
        lo[self.lower_idx] = -h[nu:]
        return lo, hi

    # ------------------------------------------------------------------ exact solves
    def maps(self, rows: tuple[int, ...]) -> ActiveSetMaps | None:
        """The exact maps of an active set (cached; the cache is emptied when it is full)."""
        cache = self._maps
        out = cache.get(rows, False)
        if out is False:
            if len(cache) >= MAX_CACHED_MAPS:
                cache.clear()
            out = cache[rows] = active_set_maps(self.P, self.C, rows)
        return out

    def verify(self, rows: tuple[int, ...], w: np.ndarray) -> list[float] | None:
        """``z`` if the active set ``rows`` gives the optimum of instance ``w``, else None."""
        maps = self.maps(rows)
        return None if maps is None else maps.check(w)

    def enumeration(self) -> Any:
        """The full enumeration (:class:`controllers.active_set.ActiveSetQP`), or None when the
        family is too large (see :data:`MAX_CANDIDATES`)."""
        if not self.can_enumerate:
            return None
        if self._enum is None:
            from .active_set import ActiveSetQP

            self._enum = ActiveSetQP(self.P, self.C)
        self.budget.use(self, self.enumeration_floats)
        return self._enum

    def _near_active(self, z: np.ndarray, w: np.ndarray, loose: bool = False) -> np.ndarray:
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
        looser test of nearly active rows. At most :data:`MAX_LOCAL_CANDIDATES` sets in all."""
        tried: set[tuple[int, ...]] = set()
        nears = [self._near_active(z, w, loose) for loose in (False, True)]
        guesses: list[tuple[int, ...]] = []
        for near in nears:  # the cheap guesses of both tests first
            if y is not None:
                guesses.append(self._rows_from_duals(y, near))
            if near.size <= self.d:
                guesses.append(tuple(near.tolist()))
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
            if count > MAX_LOCAL_CANDIDATES:
                return None
            out = self.verify(rows, w)
            if out is not None:
                return Solution(out, rows, "")
        return None

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
        if warm and self.warm is not None:
            z = self.verify(self.warm, w)
            if z is not None:
                return Solution(z, self.warm, "warm")
        enumerated = False
        for retry in (False, True):
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
                sol = self.enumerate_one(w)
                if sol is not None:
                    self.warm = sol.rows
                    return sol
                if self.can_enumerate and z is None:
                    notes.append("no enumerated active set verified")
        return None

    def enumerate_one(self, w: np.ndarray) -> Solution | None:
        """Full enumeration for one instance (None if the family is too large or nothing
        verifies): the lowest-index candidate that passes the KKT test."""
        enum = self.enumeration()
        if enum is None:
            return None
        rows = enum.solve_one(w)
        if rows is None:
            return None
        z = self.verify(rows, w)
        return None if z is None else Solution(z, rows, "enumeration")
