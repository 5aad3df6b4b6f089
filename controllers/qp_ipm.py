"""An interior-point hint for the engine's large families: Clarabel on the one-sided QP, and the
active set its answer indicates.

When the warm active set of a large family (a scenario tree of hundreds of variables) is far from
the optimum, as at the first solve of a decision at a new state (tens to hundreds of rows
violated at its solution), DAQP travels from it one row at a time: hundreds of iterations. An
interior-point method takes some twenty iterations whatever the distance, less time on such a
family (results/speed/HISTORY.md has the measurements). Clarabel (https://clarabel.org) is
already a dependency, as cvxpy's solver. Its answer is only a hint: the rows whose multiplier exceeds
their slack (the usual indicator of an interior-point method, which tells the active rows from
the others as the barrier vanishes) are re-solved exactly and verified by
:mod:`controllers.kkt`, or given to DAQP as its start when they do not verify (a set a few
rows from the optimum: a few iterations).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

__all__ = [
    "IPM_MIN_VARIABLES",
    "IPM_MIN_VIOLATED",
    "IPM_SETTINGS",
    "clarabel_tolerances",
    "interior_point_rows",
]


def clarabel_tolerances(tol: float, max_iter: int) -> dict[str, Any]:
    """Clarabel's settings with one tolerance ``tol`` on the duality gap (absolute and relative)
    and on feasibility, and at most ``max_iter`` iterations."""
    return {"tol_gap_abs": tol, "tol_gap_rel": tol, "tol_feas": tol, "max_iter": max_iter}


#: Families of at least this many variables (and screened: many more rows than variables) may
#: take the hint; below, DAQP's iterations are cheap enough.
IPM_MIN_VARIABLES = 64

#: The hint is taken when at least this many rows are violated at the solution of the warm
#: active set: many at the first solve at a new state, none at the later solves of the
#: fixed-point iterations (a few rows to drop: DAQP's business).
IPM_MIN_VIOLATED = 8

#: Clarabel's settings for the hint: tolerances at which the indicator has separated the
#: active rows (but for a few weakly active ones; see :meth:`controllers.tree_qp.TreeQP._mend_hint`).
IPM_SETTINGS = clarabel_tolerances(1e-8, max_iter=100)


def interior_point_rows(
    P: np.ndarray, C: sp.csc_matrix, q: np.ndarray, h: np.ndarray
) -> tuple[int, ...] | None:
    """The rows of ``C z <= h`` that Clarabel's answer to ``min 1/2 z'Pz + q'z`` indicates as
    active (multiplier above slack), sorted; None when Clarabel fails or is not solved.

    ``C``: the one-sided rows in CSC form (a family keeps it); rows with an infinite ``h`` are
    left out."""
    import clarabel

    finite = np.isfinite(h)
    rows = np.flatnonzero(finite)
    if rows.size == 0:
        return ()
    A = C if rows.size == h.size else C[rows]
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    for key, value in IPM_SETTINGS.items():
        setattr(settings, key, value)
    try:
        solver = clarabel.DefaultSolver(
            sp.csc_matrix(np.triu(P)),
            np.asarray(q, dtype=np.float64),
            A,
            np.asarray(h[rows], dtype=np.float64),
            [clarabel.NonnegativeConeT(int(rows.size))],
            settings,
        )
        sol = solver.solve()
    except Exception:  # noqa: BLE001 - a hint only: DAQP runs without it
        return None
    if str(sol.status) != "Solved":
        return None
    lam, slack = np.asarray(sol.z), np.asarray(sol.s)
    if lam.size != rows.size or not (np.all(np.isfinite(lam)) and np.all(np.isfinite(slack))):
        return None
    return tuple(rows[lam > slack].tolist())
