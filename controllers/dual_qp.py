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
proximal-point iterations (its default ``eps_prox < 0``: automatic). A working set can be
given as a warm start; a family with a fixed Hessian keeps DAQP's workspace
(:class:`DaqpWorkspace`), set up once and only updated.

DAQP forms ``M = A R^-1`` (``H = R'R``) at every set-up with its own loops, ``m d^2 / 2``
operations, unless the Hessian is diagonal. For a QP of
:data:`WHITEN_MIN_VARIABLES` variables or more, :func:`run_daqp` therefore passes it whitened
(:class:`Whitened`): the variables with curvature are replaced by ``v = R x`` (numpy's
triangular solve, in BLAS), so that DAQP sees a diagonal Hessian; the same constraints and
multipliers, in other coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.sparse as sp

__all__ = [
    "REGULARIZE",
    "WHITEN_MIN_VARIABLES",
    "DaqpData",
    "DaqpWorkspace",
    "Whitened",
    "daqp_data",
    "kkt_scaling",
    "run_daqp",
    "whiten",
]

#: DAQP's infinity: bounds beyond it are treated as absent.
DAQP_INF = 1e30

#: DAQP's constraint flags (``sense``): in the working set, and at its lower bound.
_ACTIVE, _LOWER = 1, 2

#: Sweeps of the Ruiz equilibration of the KKT matrix.
RUIZ_SWEEPS = 15

#: Proximal terms of the regularized attempts (see :func:`run_daqp`), tried in turn when DAQP
#: fails on the QP itself or its answer does not verify.
REGULARIZE = (1e-9, 1e-12, 1e-15)

#: :func:`run_daqp` whitens the QPs of at least this many variables (see the module docstring;
#: the set-up time it saves is in results/speed/HISTORY.md).
WHITEN_MIN_VARIABLES = 32


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
    scaled variables ``x = z / D``. ``order`` lists the rows of ``A`` in DAQP's order (simple
    bounds first) and ``scale`` the factor of each row's bounds in that order.
    """

    D: np.ndarray
    E: np.ndarray
    cs: float
    H: np.ndarray
    A_gen: np.ndarray
    general: np.ndarray  # rows of A passed as general constraints
    simple: bool
    index: np.ndarray  # DAQP's constraint index of each row of A
    order: np.ndarray  # the row of A of each DAQP constraint (the inverse of index)
    scale: np.ndarray  # the scaling of each DAQP constraint's bounds
    f_scale: np.ndarray  # cs D: the scaling of the linear term
    y_scale: np.ndarray  # the scaling of the multiplier of each row of A (scale[index])
    white: Whitened | None = None  # the same QP whitened (see whiten), for run_daqp
    #: A_gen's columns of the curved variables, sparse, per pattern of them (see whiten);
    #: shared with the DaqpData of later Hessians made from this one
    curved_cols: dict = field(default_factory=dict, compare=False, repr=False)


@dataclass(frozen=True, eq=False)
class Whitened:
    """The QP of a :class:`DaqpData` in whitened variables, as DAQP sees it.

    With ``Z`` the variables without curvature (their rows of ``H`` are zero) and ``K`` the
    others, ``H_KK = R'R`` (Cholesky), DAQP's variables are ``[x_Z, v]`` with ``v = R x_K``: its
    Hessian is diagonal (0 on ``x_Z``, which DAQP regularizes by proximal iterations as
    before; 1 on ``v``) and a row ``a`` becomes ``[a_Z, a_K R^-1]``. The simple bounds of
    ``x_Z`` stay DAQP's simple bounds; those of ``x_K`` become general rows (``R^-1``'s rows),
    placed before the general rows of ``A``.
    """

    perm: np.ndarray  # DAQP's variables: [Z, K] (indices of the scaled variables x)
    nz: int  # |Z|
    Rinv: np.ndarray  # (|K|, |K|) upper triangular: x_K = Rinv v
    H: np.ndarray  # diag(0 on Z, 1 on K)
    A_gen: np.ndarray  # DAQP's general rows: [bounds of x_K (if simple)], general rows of A
    index: np.ndarray  # DAQP's constraint index of each row of A
    order: np.ndarray  # the row of A of each DAQP constraint
    scale: np.ndarray  # the scaling of each DAQP constraint's bounds
    first_general: int  # DAQP's index of the first general row of A

    def variables(self, v: np.ndarray) -> np.ndarray:
        """The scaled variables ``x`` of DAQP's answer ``v``."""
        x = np.empty(v.size)
        x[self.perm[: self.nz]] = v[: self.nz]
        x[self.perm[self.nz :]] = self.Rinv @ v[self.nz :]
        return x


def whiten(data: DaqpData) -> Whitened | None:
    """:class:`Whitened` of ``data``, or None when the curved block of ``H`` is not numerically positive definite (DAQP then sees
    ``H`` itself and regularizes it)."""
    import scipy.linalg as sl

    H, d, c = data.H, data.D.size, data.index.size
    flat = ~H.any(axis=1)
    Z, K = np.flatnonzero(flat), np.flatnonzero(~flat)
    try:
        R = sl.cholesky(H[np.ix_(K, K)], lower=False, check_finite=False)
    except (np.linalg.LinAlgError, ValueError):
        return None
    diag = np.abs(np.diag(R))
    if K.size and not diag.min() > 1e-7 * diag.max():  # nearly singular: as DAQP would see it
        return None
    Rinv = sl.solve_triangular(R, np.eye(K.size), lower=False, check_finite=False)
    perm = np.concatenate([Z, K])
    nz = Z.size
    cols = data.curved_cols.get(K.tobytes())
    if cols is None:  # a tree's row involves a few nodes' offsets: sparse, and fixed per family
        block = data.A_gen[:, K]
        cols = sp.csr_array(block) if np.count_nonzero(block) < 0.2 * block.size else block
        data.curved_cols.clear()
        data.curved_cols[K.tobytes()] = cols
    gen = np.empty((data.A_gen.shape[0], d))
    gen[:, :nz] = data.A_gen[:, Z]
    gen[:, nz:] = cols @ Rinv
    Hw = np.zeros((d, d))
    Hw[np.arange(nz, d), np.arange(nz, d)] = 1.0
    if data.simple:  # rows c - d + i are the bounds of x_i
        bounds_K = np.zeros((K.size, d))
        bounds_K[:, nz:] = Rinv
        A_gen = np.vstack([bounds_K, gen])
        order = np.concatenate([c - d + Z, c - d + K, data.general])
    else:
        A_gen, order = gen, data.general.copy()
    index = np.empty(c, dtype=np.int64)
    index[order] = np.arange(c)
    return Whitened(
        perm,
        nz,
        Rinv,
        Hw,
        np.ascontiguousarray(A_gen),
        index,
        order,
        data.y_scale[order],
        c - data.general.size,
    )


def daqp_data(
    P: np.ndarray,
    A: np.ndarray,
    simple: bool,
    scaling: tuple[np.ndarray, np.ndarray] | DaqpData | None = None,
) -> DaqpData:
    """:class:`DaqpData` of a family (``simple``: its last ``d`` rows of ``A`` are the
    identity). ``scaling``: ``(D, E)`` to use instead of :func:`kkt_scaling` of ``P`` (the
    scaling of an earlier Hessian of the same family: only a hint's quality depends on it), or
    the :class:`DaqpData` of that Hessian, whose scaled rows are then reused (only what depends
    on ``P`` is computed)."""
    d, c = P.shape[0], A.shape[0]
    base = scaling if isinstance(scaling, DaqpData) else None
    if isinstance(scaling, DaqpData):
        D, E = scaling.D, scaling.E
    else:
        D, E = kkt_scaling(P, A) if scaling is None else scaling
    H = P * D[:, None] * D[None, :]
    top = float(np.max(np.abs(H), initial=0.0))
    cs = 1.0 / top if top > 0.0 else 1.0
    if base is not None:
        data = replace(base, cs=cs, H=np.ascontiguousarray(H * cs), f_scale=D * cs, white=None)
    else:
        if simple:
            general = np.arange(c - d)
            index = np.concatenate([d + general, np.arange(d)])
        else:
            general = np.arange(c)
            index = general.copy()
        A_gen = np.ascontiguousarray(A[general] * E[general, None] * D[None, :])
        order = np.argsort(index)
        row_scale = E.copy()
        if simple:
            row_scale[c - d :] = 1.0 / D
        data = DaqpData(
            D,
            E,
            cs,
            np.ascontiguousarray(H * cs),
            A_gen,
            general,
            simple,
            index,
            order,
            row_scale[order],
            D * cs,
            row_scale,
        )
    if d < WHITEN_MIN_VARIABLES:
        return data
    return replace(data, white=whiten(data))


class DaqpWorkspace:
    """DAQP's workspace (``daqp.Model``) for a family with a fixed Hessian: set up on first use,
    then only updated (``f`` and the bounds). DAQP starts each solve from the working set of the
    last one, the warm start of the family. Not thread-safe (the controller's lock covers it);
    not picklable (the family drops it and sets it up again on use).
    """

    def __init__(self, data: DaqpData) -> None:
        self.data = data
        self._model: Any = None

    def solve(
        self, q: np.ndarray, lo: np.ndarray, hi: np.ndarray, cold: bool = False
    ) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        """DAQP on ``min 1/2 z'Pz + q'z  s.t.  lo <= A z <= hi`` (``lo``, ``hi`` per row of
        ``A``); ``cold`` starts from an empty working set. Returns ``(z, y, status)`` as
        :func:`run_daqp`."""
        import daqp

        data = self.data
        f = q * data.f_scale
        with np.errstate(invalid="ignore", over="ignore"):
            bu = np.minimum(hi[data.order] * data.scale, DAQP_INF)
            bl = np.maximum(lo[data.order] * data.scale, -DAQP_INF)
        try:
            model = self._model
            if model is None:
                model = daqp.Model()
                flag, _ = model.setup(data.H, f, data.A_gen, bu, bl)
                if flag < 0:
                    return None, None, f"setup exit flag {flag}"
                self._model = model
            elif cold:
                model.update(f=f, bupper=bu, blower=bl, sense=np.zeros(bu.size, dtype=np.int32))
            else:
                model.update(f=f, bupper=bu, blower=bl)
            x, _, flag, info = model.solve()
        except Exception as exc:  # noqa: BLE001 - an episode must not crash on a solver error
            self._model = None
            return None, None, f"error {type(exc).__name__}: {exc}"
        return _answer(data, x, flag, info)


def run_daqp(
    data: DaqpData,
    q: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    warm: list[tuple[int, bool]] | None = None,
    regularize: float = 0.0,
    subset: np.ndarray | None = None,
) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """DAQP on ``min 1/2 z'Pz + q'z  s.t.  lo <= A z <= hi`` (the rows of :func:`daqp_data`).

    ``subset``: the general rows DAQP sees (sorted indices into ``data.general``; the simple
    bounds always), None for all; the omitted rows get multiplier 0 in ``y``.

    ``warm``: ``(row of A, at its lower side)`` pairs to start from. ``regularize``: 0 for the
    QP itself; else the objective is normalized by its largest linear coefficient and
    ``regularize`` times the identity is added to its Hessian (in the scaled variables). A
    state of size 1e30 makes the linear term 1e30 times the Hessian: DAQP then reports the
    problem infeasible, while the regularized problem (an LP with a small proximal term, whose
    optimal vertex it finds) gives the active set. Returns ``(z, y, status)``: ``y`` holds the
    multipliers in OSQP's form (one per row of ``A``, positive where the upper side is active,
    negative for the lower), ``z = y = None`` unless DAQP reports an optimum. DAQP sees the QP
    whitened (:attr:`DaqpData.white`) when it is available and ``regularize`` is 0.
    """
    import daqp

    D, cs = data.D, data.cs
    d = D.size
    f = np.ascontiguousarray(q * D * cs)
    white = data.white if not regularize else None
    H = data.H if white is None else white.H
    settings: dict = {}
    if regularize:
        top = max(1.0, float(np.max(np.abs(f), initial=0.0)))
        f = f / top
        H = H / top + regularize * np.eye(d)
        settings = {"eps_prox": 0.0, "fval_bound": 1e300}
    index, order, scale = data.index, data.order, data.scale
    A_gen, first = data.A_gen, d if data.simple else 0  # DAQP's first general row of A
    if white is not None:
        index, order, scale = white.index, white.order, white.scale
        A_gen, first = white.A_gen, white.first_general
        nz = white.nz
        f = np.concatenate([f[white.perm[:nz]], white.Rinv.T @ f[white.perm[nz:]]])
    m = index.size
    with np.errstate(invalid="ignore", over="ignore"):
        bu = np.clip(hi[order] * scale, -DAQP_INF, DAQP_INF)
        bl = np.clip(lo[order] * scale, -DAQP_INF, DAQP_INF)
    sense = np.zeros(m, dtype=np.int32)
    for a, lower in warm or ():
        sense[index[a]] = _ACTIVE | (_LOWER if lower else 0)
    if subset is not None:  # DAQP's constraints: the bounds, then the general rows of A
        keep = np.concatenate([np.arange(first), first + subset])
        ms = m - A_gen.shape[0]  # DAQP's simple bounds (no rows of A_gen)
        A_gen = A_gen[keep[ms:] - ms]
        bu, bl, sense = bu[keep], bl[keep], sense[keep]
    try:
        x, _, flag, info = daqp.solve(
            H, f, A_gen, bu, bl, sense, iter_limit=max(1000, 20 * bu.size), **settings
        )
    except Exception as exc:  # noqa: BLE001 - an episode must not crash on a solver error
        return None, None, f"error {type(exc).__name__}: {exc}"
    if subset is not None and flag == 1:
        lam = np.zeros(m)
        lam[keep] = info["lam"]
        info = {**info, "lam": lam}
    if flag == 1 and white is not None:
        x = white.variables(np.asarray(x))
    return _answer(data, x, flag, info, index)


def _answer(
    data: DaqpData, x: Any, flag: int, info: dict, index: np.ndarray | None = None
) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """``(z, y, status)`` of a DAQP run: the unscaled solution and the multipliers in OSQP's
    form (one per row of ``A``), or ``None, None`` and the reason."""
    if flag != 1:
        return None, None, f"exit flag {flag}"
    z = x * data.D
    y = info["lam"][data.index if index is None else index] * data.y_scale
    if not (np.isfinite(z).all() and np.isfinite(y).all()):
        return None, None, "non-finite answer"
    return z, y, "solved"
