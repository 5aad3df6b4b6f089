"""The data of problem P3 for one (mode, region) family, its answers, and its cvxpy reference.

With ``u = K x + nu`` the objective of P3 expands to (eq. eq:exp_noise, Lemma 1)::

    J = x'C x + tr(Pi E W E') + nu'H_nu nu + g'nu + alpha rho,
    C = Q + K'RK + Atilde'Pi Atilde,   H_nu = R + B'Pi B,   g = 2 (R K + B'Pi Atilde) x

and the constraint rows are ``G Atilde x + G B nu - rho <= H_{k+1} - t`` (eq.
constraint:feasibility). In ``z = (nu, rho)`` this is a QP whose matrices depend only on the mode
and on whether ``x_k`` is in C1; its data ``w = [q; h]`` (linear term and one-sided bounds, see
:class:`controllers.qp.QPFamily`) are affine in ``x``: ``w = W x + w0(k)``.

Everything here is a function of a :class:`Family` (and of the model's band ``H_k``), built
from the controller's checked parameters (:class:`controllers.horizon.HorizonSettings`):
the instance of a state, the smallest feasible slack of an offset, the cost of an answer
(computed from ``u`` and the next mean themselves where the expansion would cancel), the exact
answer of a verified active set, and P3 written plainly in cvxpy.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from operator import mul
from typing import Any

import numpy as np

from sdjls_gym.dynamics import max_last
from sdjls_gym.model import SDJLSModel

from .base import frozen
from .horizon import HorizonSettings
from .kkt import KKT_TOL
from .qp import EnumerationBudget, QPFamily, Solution
from .qp_ipm import clarabel_tolerances

__all__ = [
    "Family",
    "build_family",
    "check_magnitudes",
    "exact_answer",
    "hbar",
    "instance",
    "min_rho",
    "objective",
    "project_nu",
    "solve_p3_cvxpy",
]

#: Cached offsets ``w0(k)`` per family before the cache is cleared (k is unbounded).
_MAX_OFFSETS = 4096

#: Clarabel settings of the cvxpy reference.
CLARABEL_SETTINGS: dict[str, Any] = {**clarabel_tolerances(1e-11, 200), "tol_ktratio": 1e-9}


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
    chance: bool  # the chance rows are imposed
    alpha: float  # the slack's penalty (0 without chance rows)
    tight: np.ndarray  # (r,) the tightening t[mode] (zeros without chance rows)
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
    s: HorizonSettings,
    tight: np.ndarray | None,
    mode: int,
    inside: bool,
    budget: EnumerationBudget,
) -> Family:
    """The family ``(mode, inside)`` of P3 for the checked parameters ``s`` and the tightening
    ``tight`` (N, r) (None without chance rows); its QP engine is set up lazily."""
    model, m, r, n = s.model, s.model.m, s.model.r, s.model.n
    chance = s.chance
    with np.errstate(over="ignore", invalid="ignore"):  # magnitudes are checked afterwards
        P_row = (model.P_in if inside else model.P_out)[mode]  # eq. (eq:p_tran)
        Pi = np.einsum("j,jab->ab", P_row, s.Psi)  # eq. (eq:exp_noise)
        Pi = 0.5 * (Pi + Pi.T)
        K, At, Bm, R = s.K[mode], s.A_tilde[mode], model.B[mode], model.R[mode]
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
    engine = QPFamily(
        P, A, lower, upper, s.osqp_settings, budget=budget, use_daqp=s.solver == "daqp"
    )
    nb, alpha = s.nu_bound, (s.alpha if chance else 0.0)
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
        chance=chance,
        alpha=alpha,
        tight=frozen(tight[mode] if chance and tight is not None else np.zeros(r)),
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


def check_magnitudes(s: HorizonSettings, families: Iterable[Family], limit: float) -> None:
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
    model = s.model
    if worst <= limit:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            cond = max(cost_condition(fam) for fam in families)
        if cond <= MAX_COST_CONDITION:
            return
        raise ValueError(
            f"the costs of the receding-horizon QP would lose their digits: terms about "
            f"{cond:.1e} times the cost cancel (Psi up to {float(np.max(np.abs(s.Psi))):.3g}, "
            f"model.R up to {float(np.max(np.abs(model.R))):.3g}, model.Q up to "
            f"{float(np.max(np.abs(model.Q))):.3g}); the ratio must be at most "
            f"{MAX_COST_CONDITION:.0e}: bring the input weight R and the terminal weights Psi "
            "closer to the state weight Q"
        )
    sizes = {
        "Psi": s.Psi,
        "K": s.K,
        "model.Q": model.Q,
        "model.R": model.R,
        "model.G": model.G,
        "model.B": model.B,
    }
    text = ", ".join(f"{k} up to {float(np.max(np.abs(v))):.3g}" for k, v in sizes.items())
    assert where is not None  # set whenever worst > 0.0 (the callers' limit is positive)
    raise ValueError(
        f"the receding-horizon QP of mode {where[0]} has an entry of magnitude {worst:.3g} in "
        f"{where[1]} ({text}); every entry must be at most {limit:.0e} in magnitude so that "
        "costs and exact solves stay within float64: scale Psi, K or the model's weights down"
    )


# ---------------------------------------------------------------------------------- answers
def offset(fam: Family, model: SDJLSModel, k: int) -> np.ndarray:
    """``w0(k)`` of the family at time ``k`` (cached)."""
    cache = fam.offsets
    if len(cache) >= _MAX_OFFSETS:
        cache.clear()
    w0 = fam.w0.copy()
    if fam.chance:
        r, d = model.r, fam.engine.d
        # eq. (constraint:feasibility): the constraint is on x_{k+1}, band H_{k+1}
        w0[d : d + r] += model.H(k + 1) - fam.tight
    w0.setflags(write=False)
    cache[k] = w0
    return w0


def instance(
    fam: Family, model: SDJLSModel, x: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(y, w)``: ``y = [K x; W x; C x; Atilde x; Q x]`` and the instance ``w = [q; h]``."""
    m = model.m
    y = fam.lin @ x
    w0 = fam.offsets.get(k)
    if w0 is None:
        w0 = offset(fam, model, k)
    return y, y[m : m + w0.shape[0]] + w0


def hbar(fam: Family, model: SDJLSModel, k: np.ndarray) -> np.ndarray:
    """``H_{k+1} - t[theta]`` (B, r): the right side of the rows at times ``k`` (B,)."""
    return model.H(k + 1) - fam.tight


def project_nu(s: HorizonSettings, nu: np.ndarray) -> np.ndarray:
    """Remove solver round-off outside ``U``; ``nu`` (..., m)."""
    if s.nu_set == "ball" and s.model.m > 1:
        norm = np.linalg.norm(nu, axis=-1, keepdims=True)
        return nu * np.minimum(1.0, s.nu_bound / np.maximum(norm, 1e-300))
    return np.clip(nu, -s.nu_bound, s.nu_bound)


def min_rho(fam: Family, x: np.ndarray, nu: np.ndarray, hb: np.ndarray) -> np.ndarray:
    """Smallest ``rho >= 0`` (B,) that makes ``nu`` (B, m) feasible in eq.
    (constraint:feasibility) at states ``x`` (B, n) with right sides ``hb`` (B, r) (see
    :func:`hbar`); an excess within round-off of its row's terms is 0."""
    if not fam.chance:
        return np.zeros(nu.shape[0])
    GAx, GBnu = x @ fam.GA.T, nu @ fam.GB.T
    excess = GAx + GBnu - hb
    # round-off of a row's terms is not a use of the slack: a cheap first test with the
    # sizes of the partial sums, then, for the few excesses above it, the terms themselves
    real = excess > KKT_TOL * (np.abs(GAx) + np.abs(GBnu) + np.abs(hb))
    if real.any():
        i, j = np.nonzero(real)
        terms = (
            np.abs(x[i]) @ np.abs(fam.GA).T + np.abs(nu[i]) @ np.abs(fam.GB).T + np.abs(hb[i])
        )[np.arange(i.size), j]
        real[i, j] = excess[i, j] > KKT_TOL * terms
    excess = np.where(real, excess, 0.0)
    return np.maximum(max_last(excess), 0.0)


def objective(fam: Family, x: np.ndarray, nu: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """``J_k`` (B,) of P3 at ``(nu, rho)``, every constant term included (see
    :func:`cost_one` for the two ways of writing it)."""
    if fam.expand_cost:
        return (
            np.sum((x @ fam.C) * x, axis=1)
            + fam.noise_term
            + np.sum((nu @ fam.H_nu) * nu, axis=1)
            + np.sum((x @ fam.grad.T) * nu, axis=1)
            + fam.alpha * rho
        )
    u = x @ fam.K.T + nu
    mean = x @ fam.A_tilde.T + nu @ fam.B.T
    return (
        np.sum((x @ fam.Q) * x, axis=1)
        + np.sum((u @ fam.R) * u, axis=1)
        + np.sum((mean @ fam.Pi) * mean, axis=1)
        + fam.noise_term
        + fam.alpha * rho
    )


def cost_one(fam: Family, x: list, y: list, nu: list, rho: float) -> float:
    """``J_k`` of P3 for one state, in plain floats from ``y = [K x; W x; C x; Atilde x; Q x]``:
    ``x'Qx + u'Ru + mean'Pi mean + tr(Pi E W E') + alpha rho`` with ``u = K x + nu`` and
    ``mean = Atilde x + B nu``. Expanded in ``nu`` (``x'Cx + nu'H nu + g'nu + ...``, cheaper)
    where the family's terms do not cancel (``fam.expand_cost``), else written with ``u`` and
    ``mean`` themselves, so that large weights do not cancel (a dominant R makes u small)."""
    m, n = len(nu), len(x)
    start = len(y) - 2 * n
    if fam.expand_cost:
        xCx = sum(map(mul, x, y[start - n : start]))
        nuHnu = sum(v * sum(map(mul, row, nu)) for v, row in zip(nu, fam.H_list, strict=True))
        g = y[m : 2 * m]  # the first m entries of W x are the gradient
        return xCx + fam.noise_term + nuHnu + sum(map(mul, g, nu)) + fam.alpha * rho
    u = [a + b for a, b in zip(y[:m], nu, strict=True)]
    mean = [
        a + sum(map(mul, row, nu)) for a, row in zip(y[start : start + n], fam.B_list, strict=True)
    ]
    xQx = sum(map(mul, x, y[start + n :]))
    uRu = sum(v * sum(map(mul, row, u)) for v, row in zip(u, fam.R_list, strict=True))
    mPm = sum(v * sum(map(mul, row, mean)) for v, row in zip(mean, fam.Pi_list, strict=True))
    return xQx + uRu + mPm + fam.noise_term + fam.alpha * rho


def exact_answer(
    fam: Family, nu_bound: float, x: np.ndarray, y: list[float], w: np.ndarray, sol: Solution
) -> tuple[list[float], float, float]:
    """``(nu, rho, cost)`` from the exact solution of a verified active set.

    A function of ``(x, k, active set)`` and the family only (plain float arithmetic on the
    data of the single-state path), so the answer does not depend on which path found it.
    ``rho`` is 0 when the bound ``rho >= 0`` is in the active set (the rows then hold to the
    tolerance of the KKT test, relative to each row), else the largest excess of a row
    (eq. constraint:feasibility). The cost ``J_k`` has every constant term.
    """
    m = fam.K.shape[0]
    nu = [min(max(v, -nu_bound), nu_bound) for v in sol.z[:m]]  # round-off outside U
    rho = 0.0
    if fam.chance and fam.rho_row not in sol.rows:
        wl = w.tolist()
        d = m + 1
        h = wl[d : d + len(fam.GB_list)]  # H_{k+1} - t - G Atilde x
        excess = max(sum(map(mul, row, nu)) - hj for row, hj in zip(fam.GB_list, h, strict=True))
        rho = max(excess, 0.0)
    return nu, rho, cost_one(fam, x.tolist(), y, nu, rho)


def solve_p3_cvxpy(
    s: HorizonSettings, fam: Family, x: np.ndarray, k: int
) -> tuple[np.ndarray | None, float, float, str]:
    """P3 written plainly with cvxpy, solved by Clarabel; ``(nu, rho, value, status)``, with
    ``nu = None`` unless Clarabel reports an optimal, finite answer."""
    import cvxpy as cp

    model, mode = s.model, fam.mode
    nu = cp.Variable(model.m)
    u = fam.K @ x + nu  # eq. (eq:stabilization_input)
    mean_next = s.A_tilde[mode] @ x + model.B[mode] @ nu  # eq. (sys:stabilized_input)
    objective = (
        float(x @ model.Q[mode] @ x)
        + cp.quad_form(u, model.R[mode])
        + cp.quad_form(mean_next, fam.Pi)
        + fam.noise_term
    )
    constraints = []
    if s.nu_set == "ball":
        constraints.append(cp.norm(nu, 2) <= s.nu_bound)
    else:
        constraints.append(cp.abs(nu) <= s.nu_bound)
    rho = None
    if fam.chance:
        rho = cp.Variable(nonneg=True)
        objective = objective + s.alpha * rho
        right = model.H(k + 1) - fam.tight
        constraints.append(model.G @ mean_next <= right + rho)  # eq. (constraint:feasibility)
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
