"""The rows of problem P3 on a belief for a set of kept modes, and the answers read from them.

The QP of :mod:`controllers.belief_qp` in ``z = (nu, rho)`` has the rows, in the order of P3's
family (:mod:`controllers.p3`): ``[G B_i, -1] z <= H_{k+1} - t_i - G (A_i + B_i K(pi)) x`` for
each kept mode ``i`` (ascending; eq. constraint:feasibility), the box ``|nu_j| <= nu_bound``
(upper sides, then lower sides) and ``rho >= 0``. :class:`KeptRows` holds them for one kept set
(for one kept mode they are P3's); :func:`answer_rho` and :func:`min_rho` read the slack of an
answer, and :func:`solve_belief_cvxpy` is the QP written with cvxpy (the rescue of the fast path
and the solver of a Euclidean ball ``U``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dual_qp import DAQP_INF
from .kkt import KKT_TOL
from .p3 import CLARABEL_SETTINGS
from .qp_daqp import Solution, active_set_of_multipliers

__all__ = ["KeptRows", "answer_rho", "daqp_rows", "kept_rows", "min_rho", "solve_belief_cvxpy"]


@dataclass(frozen=True, eq=False)
class KeptRows:
    """The rows of the QP for one set of kept modes (arrays read-only).

    ``A`` holds the two-sided rows ``[G B_i, -1]`` (each kept mode), ``[I, 0]`` (the box),
    ``[0, 1]`` (``rho``), the last ``d`` rows the identity; ``C = [A[upper_idx]; -A[lower_idx]]``
    the one-sided rows of the KKT test; ``upper_of`` / ``lower_of`` the one-sided index of each
    row's side (-1: absent); ``rho_row`` the index of ``-rho <= 0`` in ``C``.
    """

    modes: tuple[int, ...]
    A: np.ndarray
    C: np.ndarray
    absC: np.ndarray
    upper_idx: np.ndarray
    lower_idx: np.ndarray
    upper_of: np.ndarray
    lower_of: np.ndarray
    pivots: np.ndarray
    n_chance: int
    rho_row: int

    @property
    def d(self) -> int:
        """Variables of the QP, ``m + 1``."""
        return int(self.A.shape[1])

    def two_sided(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``lo <= A z <= hi`` of the one-sided right sides ``h`` (inf where absent)."""
        rows = self.A.shape[0]
        lo, hi = np.full(rows, -np.inf), np.full(rows, np.inf)
        nu = self.upper_idx.size
        hi[self.upper_idx] = h[:nu]
        lo[self.lower_idx] = -h[nu:]
        return lo, hi

    def rows_of_multipliers(self, y: np.ndarray) -> tuple[int, ...] | None:
        """The one-sided active set of multipliers ``y`` (one per row of ``A``, positive where
        the upper side is active, negative for the lower), or None when it cannot be one
        (:func:`controllers.qp_daqp.active_set_of_multipliers`)."""
        return active_set_of_multipliers(y, self.upper_of, self.lower_of, self.d)


def kept_rows(GB: np.ndarray, modes: tuple[int, ...]) -> KeptRows:
    """:class:`KeptRows` of the kept ``modes`` for the rows ``G B_i`` (N, r, m)."""
    r, m = GB.shape[1], GB.shape[2]
    s = len(modes)
    chance = np.hstack([np.concatenate([GB[i] for i in modes]), -np.ones((r * s, 1))])
    box = np.hstack([np.eye(m), np.zeros((m, 1))])
    slack = np.hstack([np.zeros((1, m)), np.ones((1, 1))])
    A = np.vstack([chance, box, slack])
    upper = np.concatenate([np.ones(r * s + m, bool), [False]])
    lower = np.concatenate([np.zeros(r * s, bool), np.ones(m + 1, bool)])
    upper_idx, lower_idx = np.flatnonzero(upper), np.flatnonzero(lower)
    C = np.vstack([A[upper_idx], -A[lower_idx]])
    upper_of = np.full(A.shape[0], -1, dtype=np.int64)
    lower_of = np.full(A.shape[0], -1, dtype=np.int64)
    upper_of[upper_idx] = np.arange(upper_idx.size)
    lower_of[lower_idx] = upper_idx.size + np.arange(lower_idx.size)
    pivots = np.zeros(m + 1, dtype=bool)
    pivots[m] = True  # rho: no curvature
    arrays = (A, C, np.abs(C), upper_idx, lower_idx, upper_of, lower_of, pivots)
    for a in arrays:
        a.setflags(write=False)
    return KeptRows(tuple(modes), *arrays, n_chance=r * s, rho_row=C.shape[0] - 1)


def daqp_rows(kr: KeptRows) -> tuple:
    """What :meth:`controllers.belief_qp.BeliefQP` gives DAQP's ``daqp.solve`` for a kept set, and how to read it back:
    the chance rows (writable: DAQP takes writable buffers), the one-sided row of each DAQP
    constraint's upper and lower side (-1: absent; DAQP orders the simple bounds first), and
    each one-sided row's DAQP constraint and working-set flag (1 active, 2 at its lower side),
    and the template of the lower sides (``-DAQP_INF`` where a constraint has none)."""
    nc = kr.n_chance
    rows_A = kr.A.shape[0]
    order = np.concatenate([np.arange(nc, rows_A), np.arange(nc)])  # DAQP j -> row of A
    upper_of, lower_of = kr.upper_of[order], kr.lower_of[order]
    position = np.empty(rows_A, dtype=np.int64)
    position[order] = np.arange(rows_A)  # row of A -> DAQP j
    one_sided = np.concatenate([kr.upper_idx, kr.lower_idx])  # one-sided row -> row of A
    index = position[one_sided]
    bits = np.where(np.arange(one_sided.size) >= kr.upper_idx.size, 3, 1).astype(np.int32)
    lower = np.full(kr.d + nc, -DAQP_INF)  # the lower sides: set per instance where they exist
    return np.array(kr.A[:nc]), upper_of.tolist(), lower_of.tolist(), index, bits, lower


def answer_rho(kr: KeptRows, sol: Solution, nu: np.ndarray, w: np.ndarray) -> float:
    """``rho`` of the exact answer ``sol`` with offset ``nu`` (``z[:m]`` in ``U``): 0 when
    ``rho >= 0`` is in the active set (the rows then hold to the KKT test's tolerance), else the
    largest excess of a kept row over its right side (eq. constraint:feasibility), as P3's
    :func:`controllers.p3.exact_answer`."""
    if kr.rho_row in sol.rows:
        return 0.0
    m = kr.d - 1
    excess = float((kr.C[: kr.n_chance, :m] @ nu - w[kr.d : kr.d + kr.n_chance]).max())
    return max(excess, 0.0)


def min_rho(kr: KeptRows, nu: np.ndarray, w: np.ndarray) -> float:
    """The smallest ``rho >= 0`` that makes the offset ``nu`` (m,) feasible in the kept rows of
    instance ``w``; an excess within :data:`controllers.kkt.KKT_TOL` of its row's terms is 0."""
    m, d = kr.d - 1, kr.d
    GB = kr.C[: kr.n_chance, :m]
    h = np.asarray(w[d : d + kr.n_chance])
    lhs = GB @ nu
    excess = lhs - h
    terms = np.abs(GB) @ np.abs(nu) + np.abs(h)
    excess = np.where(excess > KKT_TOL * terms, excess, 0.0)
    return float(max(excess.max(initial=0.0), 0.0))


def solve_belief_cvxpy(
    P: np.ndarray, w: np.ndarray, kr: KeptRows, nu_bound: float, ball: bool
) -> tuple[np.ndarray | None, str]:
    """The QP of instance ``w`` with Hessian ``P`` (the kept rows ``kr``) written with cvxpy
    and solved by Clarabel, ``U`` the box or (``ball``) the Euclidean ball: ``(nu, status)``,
    ``nu`` None unless Clarabel reports an optimal, finite answer. The rescue of the fast path
    (its answer is verified by the caller) and the solver of the ball."""
    import cvxpy as cp

    d = kr.d
    m = d - 1
    nu, rho = cp.Variable(m), cp.Variable(nonneg=True)
    H = 0.5 * P[:m, :m]
    objective = cp.quad_form(nu, 0.5 * (H + H.T)) + w[:m] @ nu + w[m] * rho
    GB = kr.C[: kr.n_chance, :m]
    rows = [GB @ nu - rho <= w[d : d + kr.n_chance]]
    rows.append(cp.norm(nu, 2) <= nu_bound if ball else cp.abs(nu) <= nu_bound)
    problem = cp.Problem(cp.Minimize(objective), rows)
    try:
        problem.solve(solver=cp.CLARABEL, **CLARABEL_SETTINGS)
    except Exception as exc:  # noqa: BLE001 - an episode must not crash on a solver error
        return None, f"error {type(exc).__name__}: {exc}"
    status = str(problem.status)
    value = None if nu.value is None else np.asarray(nu.value, dtype=np.float64).reshape(-1)
    if status != cp.OPTIMAL or value is None or not np.all(np.isfinite(value)):
        return None, status
    return value, status
