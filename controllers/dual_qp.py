"""DAQP, a dense dual active-set QP solver, as a finder of active sets for the engine.

DAQP (https://github.com/darnstrom/daqp) solves ``min 1/2 x'Hx + f'x  s.t.  l <= A x <= u``
by a dual active-set method: it ends on a working set of active constraints, which is what the
engine needs (:mod:`controllers.kkt` then solves that set exactly and verifies it). Its answer
is only a hint: nothing it returns is used unverified.

DAQP works in absolute tolerances, so it sees the QP equilibrated: the variables and the rows
are scaled by a Ruiz equilibration of the KKT matrix ``[[P, A'], [A, 0]]`` (:func:`kkt_scaling`)
and the objective by its largest entry. The rows of ``A`` that are the identity (one per
variable, in order: the box on ``nu`` and ``rho >= 0`` of the receding-horizon QPs) are passed
as DAQP's simple bounds. A singular ``P`` (the slacks have no curvature) is handled by DAQP's
proximal-point iterations. A working set can be given as a warm start.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["REGULARIZE", "DaqpData", "daqp_data", "kkt_scaling", "run_daqp"]

#: DAQP's infinity: bounds beyond it are treated as absent.
DAQP_INF = 1e30

#: DAQP's constraint flags (``sense``): in the working set, and at its lower bound.
_ACTIVE, _LOWER = 1, 2

#: Sweeps of the Ruiz equilibration of the KKT matrix.
RUIZ_SWEEPS = 15

#: Proximal terms of the regularized attempts (see :func:`run_daqp`), tried in turn when DAQP
#: fails on the QP itself or its answer does not verify.
REGULARIZE = (1e-9, 1e-12, 1e-15)


def kkt_scaling(
    P: np.ndarray, A: np.ndarray, sweeps: int = RUIZ_SWEEPS
) -> tuple[np.ndarray, np.ndarray]:
    """``(D, E)``: scalings of the variables (d,) and of the rows of ``A`` (c,) such that every
    column and row of ``[[D P D, D A' E], [E A D, 0]]`` has its largest entry near 1 (Ruiz)."""
    d = P.shape[0]
    D, E = np.ones(d), np.ones(A.shape[0])
    absP, absA = np.abs(P), np.abs(A)
    for _ in range(sweeps):
        Ps = absP * D[:, None] * D[None, :]
        As = absA * E[:, None] * D[None, :]
        col = np.maximum(Ps.max(axis=0, initial=0.0), As.max(axis=0, initial=0.0))
        row = As.max(axis=1, initial=0.0)
        col = np.where(col > 0.0, col, 1.0)
        row = np.where(row > 0.0, row, 1.0)
        if np.all(np.abs(col - 1.0) < 1e-3) and np.all(np.abs(row - 1.0) < 1e-3):
            break
        D /= np.sqrt(col)
        E /= np.sqrt(row)
    return D, E


@dataclass(frozen=True, eq=False)
class DaqpData:
    """The scaled matrices DAQP sees for one ``(P, A)``.

    ``H = cs D P D``; the general rows ``E_g A_g D`` (rows ``general`` of ``A``); with
    ``simple``, the last ``d`` rows of ``A`` are the identity and become simple bounds on the
    scaled variables ``x = z / D``.
    """

    D: np.ndarray
    E: np.ndarray
    cs: float
    H: np.ndarray
    A_gen: np.ndarray
    general: np.ndarray  # rows of A passed as general constraints
    simple: bool
    index: np.ndarray  # DAQP's constraint index of each row of A


def daqp_data(P: np.ndarray, A: np.ndarray, simple: bool) -> DaqpData:
    """:class:`DaqpData` of a family (``simple``: its last ``d`` rows of ``A`` are the identity)."""
    d, c = P.shape[0], A.shape[0]
    D, E = kkt_scaling(P, A)
    H = P * D[:, None] * D[None, :]
    top = float(np.max(np.abs(H), initial=0.0))
    cs = 1.0 / top if top > 0.0 else 1.0
    if simple:
        general = np.arange(c - d)
        index = np.concatenate([d + general, np.arange(d)])
    else:
        general = np.arange(c)
        index = general.copy()
    A_gen = np.ascontiguousarray(A[general] * E[general, None] * D[None, :])
    return DaqpData(D, E, cs, np.ascontiguousarray(H * cs), A_gen, general, simple, index)


def run_daqp(
    data: DaqpData,
    q: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    warm: list[tuple[int, bool]] | None = None,
    regularize: float = 0.0,
) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """DAQP on ``min 1/2 z'Pz + q'z  s.t.  lo <= A z <= hi`` (the rows of :func:`daqp_data`).

    ``warm``: ``(row of A, at its lower side)`` pairs to start from. ``regularize``: 0 for the
    QP itself; else the objective is normalized by its largest linear coefficient and
    ``regularize`` times the identity is added to its Hessian (in the scaled variables). A
    state of size 1e30 makes the linear term 1e30 times the Hessian: DAQP then reports the
    problem infeasible, while the regularized problem (an LP with a small proximal term, whose
    optimal vertex it finds) gives the active set. Returns ``(z, y, status)``: ``y`` holds the
    multipliers in OSQP's form (one per row of ``A``, positive where the upper side is active,
    negative for the lower), ``z = y = None`` unless DAQP reports an optimum.
    """
    import daqp

    D, E, cs = data.D, data.E, data.cs
    d = D.size
    f = np.ascontiguousarray(q * D * cs)
    H = data.H
    settings: dict = {}
    if regularize:
        top = max(1.0, float(np.max(np.abs(f), initial=0.0)))
        f = f / top
        H = H / top + regularize * np.eye(d)
        settings = {"eps_prox": 0.0, "fval_bound": 1e300}
    scale = np.empty_like(lo)
    scale[data.general] = E[data.general]
    if data.simple:
        scale[lo.size - d :] = 1.0 / D
    m = data.index.size
    bu, bl = np.empty(m), np.empty(m)
    with np.errstate(invalid="ignore", over="ignore"):
        bu[data.index] = np.clip(hi * scale, -DAQP_INF, DAQP_INF)
        bl[data.index] = np.clip(lo * scale, -DAQP_INF, DAQP_INF)
    sense = np.zeros(m, dtype=np.int32)
    for a, lower in warm or ():
        sense[data.index[a]] = _ACTIVE | (_LOWER if lower else 0)
    try:
        x, _, flag, info = daqp.solve(
            H, f, data.A_gen, bu, bl, sense, iter_limit=max(1000, 20 * m), **settings
        )
    except Exception as exc:  # noqa: BLE001 - an episode must not crash on a solver error
        return None, None, f"error {type(exc).__name__}: {exc}"
    if flag != 1:
        return None, None, f"exit flag {flag}"
    z = np.asarray(x, dtype=np.float64) * D
    lam = np.asarray(info["lam"], dtype=np.float64)[data.index]
    if not (np.all(np.isfinite(z)) and np.all(np.isfinite(lam))):
        return None, None, "non-finite answer"
    return z, lam * scale, "solved"
