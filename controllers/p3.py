"""The data of problem P3 for one (mode, region) family, and its cvxpy reference.

With ``u = K x + nu`` the objective of P3 expands to (eq. eq:exp_noise, Lemma 1)::

    J = x'C x + tr(Pi E W E') + nu'H_nu nu + g'nu + alpha rho,
    C = Q + K'RK + Atilde'Pi Atilde,   H_nu = R + B'Pi B,   g = 2 (R K + B'Pi Atilde) x

and the constraint rows are ``G Atilde x + G B nu - rho <= H_{k+1} - t`` (eq.
constraint:feasibility). In ``z = (nu, rho)`` this is a QP whose matrices depend only on the mode
and on whether ``x_k`` is in C1; its data ``w = [q; h]`` (linear term and one-sided bounds, see
:class:`controllers.qp.QPFamily`) are affine in ``x``: ``w = W x + w0(k)``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .base import frozen
from .qp import EnumerationBudget, QPFamily

if TYPE_CHECKING:  # pragma: no cover
    from .rhc import RecedingHorizonController

__all__ = ["Family", "build_family", "check_magnitudes", "solve_p3_cvxpy"]

#: Clarabel settings of the cvxpy reference.
CLARABEL_SETTINGS: dict[str, Any] = {
    "tol_gap_abs": 1e-11,
    "tol_gap_rel": 1e-11,
    "tol_feas": 1e-11,
    "tol_ktratio": 1e-9,
    "max_iter": 200,
}


@dataclass(frozen=True, eq=False)
class Family:
    """P3 for one ``(mode, x_k in C1)`` pair: ``Pi`` and every matrix of the QP are fixed.

    Arrays are read-only. ``lin = [K; W; C; Atilde; Q]`` gives ``K x``, ``W x``, ``C x``,
    ``Atilde x`` and ``Q x`` in one product (the single-state path); ``w0`` is ``w`` at ``x = 0`` without the band (``H_{k+1} - t`` is
    added per ``k``); ``rho_row`` is the index of the one-sided row ``-rho <= 0`` in the
    engine's ``C``.
    """

    mode: int
    inside: bool
    Pi: np.ndarray  # (n, n)
    K: np.ndarray  # (m, n)
    GA: np.ndarray  # (r, n)  G Atilde
    GB: np.ndarray  # (r, m)
    grad: np.ndarray  # (m, n)  2 (R K + B'Pi Atilde)
    C: np.ndarray  # (n, n)
    H_nu: np.ndarray  # (m, m)
    noise_term: float  # tr(Pi E W E')
    engine: QPFamily
    Q: np.ndarray  # (n, n)
    R: np.ndarray  # (m, m)
    A_tilde: np.ndarray  # (n, n)
    B: np.ndarray  # (n, m)
    lin: np.ndarray  # (m + d + c + 3n, n): rows [K; W; C; Atilde; Q]
    w0: np.ndarray  # (d + c,)
    rho_row: int
    H_list: list = field(default_factory=list)  # H_nu as nested lists (m x m)
    GB_list: list = field(default_factory=list)  # G B as nested lists (r x m)
    R_list: list = field(default_factory=list)  # R as nested lists (m x m)
    Pi_list: list = field(default_factory=list)  # Pi as nested lists (n x n)
    B_list: list = field(default_factory=list)  # B as nested lists (n x m)
    offsets: dict = field(default_factory=dict)  # k -> w0(k)
    #: whether the cost may be computed expanded in nu (x'Cx + nu'H nu + g'nu): its terms cancel
    #: by at most EXPAND_COST_CONDITION (cost_condition), so the expansion keeps ~1e-10 relative
    expand_cost: bool = False


def build_family(
    ctrl: RecedingHorizonController, mode: int, inside: bool, budget: EnumerationBudget
) -> Family:
    """The family ``(mode, inside)`` of the controller's P3 (its QP engine is set up lazily)."""
    model, m, r, n = ctrl.model, ctrl.model.m, ctrl.model.r, ctrl.model.n
    chance = ctrl._chance_constrained
    with np.errstate(over="ignore", invalid="ignore"):  # magnitudes are checked afterwards
        P_row = (model.P_in if inside else model.P_out)[mode]  # eq. (eq:p_tran)
        Pi = np.einsum("j,jab->ab", P_row, ctrl.Psi)  # eq. (eq:exp_noise)
        Pi = 0.5 * (Pi + Pi.T)
        K, At, Bm, R = ctrl.K[mode], ctrl.A_tilde[mode], model.B[mode], model.R[mode]
        H_nu = R + Bm.T @ Pi @ Bm
        H_nu = 0.5 * (H_nu + H_nu.T)
        C = model.Q[mode] + K.T @ R @ K + At.T @ Pi @ At
        grad = 2.0 * (R @ K + Bm.T @ Pi @ At)
        GA, GB = model.G @ At, model.G @ Bm
        noise_term = float(np.trace(Pi @ model.noise_cov[mode]))  # Lemma 1, eq. (eq:lemm1)
    d = m + 1
    P = np.zeros((d, d))
    P[:m, :m] = 2.0 * H_nu  # 1/2 z'P z = nu'(R + B'Pi B) nu
    rows = []
    if chance:
        rows.append(np.hstack([GB, -np.ones((r, 1))]))  # G B nu - rho <= hbar - G Atilde x
    rows.append(np.hstack([np.eye(m), np.zeros((m, 1))]))  # nu in the box U
    rows.append(np.hstack([np.zeros((1, m)), np.ones((1, 1))]))  # rho >= 0 (= 0 unconstrained)
    A = np.vstack(rows)
    nr = r if chance else 0
    upper = np.concatenate([np.ones(nr, bool), np.ones(m, bool), [not chance]])
    lower = np.concatenate([np.zeros(nr, bool), np.ones(m, bool), [True]])
    engine = QPFamily(P, A, lower, upper, ctrl.osqp_settings, budget=budget)
    nb, alpha = ctrl.nu_bound, (ctrl.alpha if chance else 0.0)
    lo = np.concatenate([np.full(nr, -np.inf), np.full(m, -nb), [0.0]])
    hi = np.concatenate([np.zeros(nr), np.full(m, nb), [np.inf if chance else 0.0]])
    h0 = engine.one_sided_bounds(lo, hi)
    w0 = np.concatenate([np.zeros(m), [alpha], h0])
    W = np.zeros((d + engine.c, n))
    W[:m] = grad
    if chance:
        W[d : d + r] = -GA  # eq. (constraint:feasibility)
    fam = Family(
        mode=mode,
        inside=inside,
        Pi=frozen(Pi),
        K=frozen(K),
        GA=frozen(GA),
        GB=frozen(GB),
        grad=frozen(grad),
        C=frozen(C),
        H_nu=frozen(H_nu),
        noise_term=noise_term,
        engine=engine,
        Q=frozen(model.Q[mode]),
        R=frozen(R),
        A_tilde=frozen(At),
        B=frozen(Bm),
        lin=frozen(np.vstack([K, W, C, At, model.Q[mode]])),
        w0=frozen(w0),
        rho_row=engine.c - 1,  # the lower side of the rho row comes last
        H_list=H_nu.tolist(),
        GB_list=GB.tolist(),
        R_list=R.tolist(),
        Pi_list=Pi.tolist(),
        B_list=Bm.tolist(),
    )
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        expand = bool(cost_condition(fam) <= EXPAND_COST_CONDITION)
    return replace(fam, expand_cost=expand)


#: Largest cost_condition at which the cost is computed expanded in nu (error ~ 1e6 * 2.2e-16).
EXPAND_COST_CONDITION = 1e6

#: Largest ratio of the cost's cancelling terms to the cost itself (see :func:`cost_condition`):
#: the cost of an answer is then exact to about ``ratio * 2.2e-16**2 <= 5e-10`` relative.
MAX_COST_CONDITION = 1e22


def cost_condition(fam: Family) -> float:
    """How much of the cost ``J`` cancels, per unit ``|x|^2``: the weights of ``u = K x + nu``
    and of the next mean ``Atilde x + B nu``, at the unconstrained optimum ``nu = -L x``, against
    the cost that remains, ``S = Q + (K - L)'R(K - L) + (Atilde - B L)'Pi(Atilde - B L)``. A
    rounding ``eps`` of ``u`` and of the mean changes ``J`` by about ``eps**2`` times it, relative
    (a dominant input weight R makes the optimal ``u`` cancel ``K x`` almost exactly)."""
    G = fam.R @ fam.K + fam.B.T @ fam.Pi @ fam.A_tilde
    L = np.linalg.solve(fam.H_nu, G)
    KL, AL = fam.K - L, fam.A_tilde - fam.B @ L
    S = fam.Q + KL.T @ fam.R @ KL + AL.T @ fam.Pi @ AL
    norm = lambda M: float(np.linalg.norm(M, 2)) if M.size else 0.0  # noqa: E731
    big = (
        norm(fam.H_nu) * (norm(fam.K) + norm(L)) ** 2
        + norm(fam.Pi) * (norm(fam.A_tilde) + norm(fam.B) * norm(L)) ** 2
    )
    small = norm(0.5 * (S + S.T))
    return np.inf if small == 0.0 else big / small


def check_magnitudes(
    ctrl: RecedingHorizonController, families: Iterable[Family], limit: float
) -> None:
    """ValueError unless every matrix of every family is finite and at most ``limit`` in
    magnitude (beyond, the costs of states up to ``MAX_STATE`` overflow float64 and the exact
    solves lose every digit); the message names the inputs and their sizes."""
    worst, where = 0.0, None
    for fam in families:
        for name in ("Pi", "GA", "GB", "grad", "C", "H_nu"):
            arr = getattr(fam, name)
            v = float(np.max(np.abs(arr))) if arr.size else 0.0
            if not np.isfinite(v) or v > worst:
                worst, where = (np.inf if not np.isfinite(v) else v), (fam.mode, name)
        if not np.isfinite(fam.noise_term):
            worst, where = np.inf, (fam.mode, "noise_term")
    model = ctrl.model
    if worst <= limit:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            cond = max(cost_condition(fam) for fam in families)
        if cond <= MAX_COST_CONDITION:
            return
        raise ValueError(
            f"the costs of the receding-horizon QP would lose their digits: terms about "
            f"{cond:.1e} times the cost cancel (Psi up to {float(np.max(np.abs(ctrl.Psi))):.3g}, "
            f"model.R up to {float(np.max(np.abs(model.R))):.3g}, model.Q up to "
            f"{float(np.max(np.abs(model.Q))):.3g}); the ratio must be at most "
            f"{MAX_COST_CONDITION:.0e}: bring the input weight R and the terminal weights Psi "
            "closer to the state weight Q"
        )
    sizes = {
        "Psi": ctrl.Psi,
        "K": ctrl.K,
        "model.Q": model.Q,
        "model.R": model.R,
        "model.G": model.G,
        "model.B": model.B,
    }
    text = ", ".join(f"{k} up to {float(np.max(np.abs(v))):.3g}" for k, v in sizes.items())
    raise ValueError(
        f"the receding-horizon QP of mode {where[0]} has an entry of magnitude {worst:.3g} in "
        f"{where[1]} ({text}); every entry must be at most {limit:.0e} in magnitude so that "
        "costs and exact solves stay within float64: scale Psi, K or the model's weights down"
    )


def solve_p3_cvxpy(
    ctrl: RecedingHorizonController, fam: Family, x: np.ndarray, k: int
) -> tuple[np.ndarray | None, float, float, str]:
    """P3 written plainly with cvxpy, solved by Clarabel; ``(nu, rho, value, status)``, with
    ``nu = None`` unless Clarabel reports an optimal, finite answer."""
    import cvxpy as cp

    model, mode = ctrl.model, fam.mode
    nu = cp.Variable(model.m)
    u = fam.K @ x + nu  # eq. (eq:stabilization_input)
    mean_next = ctrl.A_tilde[mode] @ x + model.B[mode] @ nu  # eq. (sys:stabilized_input)
    objective = (
        float(x @ model.Q[mode] @ x)
        + cp.quad_form(u, model.R[mode])
        + cp.quad_form(mean_next, fam.Pi)
        + fam.noise_term
    )
    constraints = []
    if ctrl.nu_set == "ball":
        constraints.append(cp.norm(nu, 2) <= ctrl.nu_bound)
    else:
        constraints.append(cp.abs(nu) <= ctrl.nu_bound)
    rho = None
    if ctrl._chance_constrained:
        rho = cp.Variable(nonneg=True)
        objective = objective + ctrl.alpha * rho
        hbar = model.H(k + 1) - ctrl.tightening[mode]
        constraints.append(model.G @ mean_next <= hbar + rho)  # eq. (constraint:feasibility)
    problem = cp.Problem(cp.Minimize(objective), constraints)
    try:
        problem.solve(solver=cp.CLARABEL, **CLARABEL_SETTINGS)
    except Exception as exc:  # noqa: BLE001 - an episode must not crash on a solver error
        return None, np.nan, np.nan, f"error {type(exc).__name__}: {exc}"
    status = str(problem.status)
    nu_val = None if nu.value is None else np.asarray(nu.value, dtype=np.float64).reshape(-1)
    rho_val = 0.0 if rho is None else (np.nan if rho.value is None else float(rho.value))
    value = np.nan if problem.value is None else float(problem.value)
    ok = (
        status == cp.OPTIMAL
        and nu_val is not None
        and np.all(np.isfinite(nu_val))
        and np.isfinite(rho_val)
        and np.isfinite(value)
    )
    return (nu_val if ok else None), rho_val, value, status
