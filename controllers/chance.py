"""Probabilistic -> deterministic constraint tightening (section 4 of the paper).

The chance constraint on the next state, ``Pr{G_j x_{k+1} <= H_{k+1, j} | F_k} >= xi``, with
``x_{k+1} ~ N(Atilde_theta x_k + B_theta nu_k, E_theta W E_theta')``, is replaced by the
deterministic constraint on the mean of the next state::

    G_j (Atilde_theta x_k + B_theta nu_k) <= H_{k+1, j} - t[theta, j]

where ``t = tightening(model, xi, constraint)`` is computed once per model and level ``xi``.

Three kinds of tightening are offered:

``"individual"``
    Each row separately holds with probability ``>= xi``, eq. (constraint:univariate_final); the
    tightening ``t = Phi^{-1}(xi) * sqrt(G_j E_i W E_i' G_j')`` is exact, eq.
    (constraint:det_univariate) with ``G_j E_i w ~ N(0, G_j E_i W E_i' G_j')``.
``"joint"``
    All rows hold together with probability ``>= xi``, eq. (constraint:multivariate_final),
    through the inscribed-ellipsoid argument of Lemma 1, eq. (constraint:chi_square), generalised
    to ``E`` and ``W``: ``t = sqrt(F^{-1}_{chi2, p}(xi)) * ||W^{1/2} E_i' G_j'||_2`` with ``p`` the
    number of noise inputs. For ``E = W = I`` this is the paper's ``delta * ||G_j||_2``.
``"bonferroni"``
    All rows hold together with probability ``>= xi`` through the union bound: every row is
    tightened to the individual level ``1 - (1 - xi) / r``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import special, stats

from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import check_choice, check_int, check_probability

from .base import check_model

__all__ = [
    "CONSTRAINT_KINDS",
    "tightening",
    "tightened_set_empty",
    "row_satisfaction_probability",
]

#: The kinds of chance constraint understood by :func:`tightening`.
CONSTRAINT_KINDS = ("individual", "joint", "bonferroni")


def check_xi(xi: Any) -> float:
    """``xi`` as a float strictly between 0 and 1 (TypeError for a non-number, ValueError out
    of range; the message names ``xi``)."""
    return check_probability(
        "xi",
        xi,
        what="the chance-constraint level; xi = 0 imposes nothing and xi = 1 cannot be met "
        "under Gaussian noise",
    )


def _row_std(model: SDJLSModel) -> np.ndarray:
    """(N, r) standard deviation of ``G_j E_i w``: ``sqrt(G_j E_i W E_i' G_j')``."""
    var = np.einsum("jn,inm,jm->ij", model.G, model.noise_cov, model.G)
    return np.sqrt(np.clip(var, 0.0, None))


def tightening(model: SDJLSModel, xi: float, constraint: str = "individual") -> np.ndarray:
    """Amount by which each row of ``G x <= H`` is tightened in each mode.

    Parameters
    ----------
    model : SDJLSModel
        The system; uses ``G`` (r, n), ``E`` (N, n, p) and ``W`` (p, p).
    xi : float
        Chance-constraint level, strictly between 0 and 1.
    constraint : {"individual", "joint", "bonferroni"}
        Which chance constraint the tightening guarantees (see the module docstring).

    Returns
    -------
    t : (N, r) ndarray
        ``t[i, j]``: subtract it from ``H_{k+1, j}`` in the constraint on the mean of ``x_{k+1}``
        when the current mode is ``i``. Negative for ``xi < 0.5`` with ``"individual"``.

    Raises
    ------
    ValueError
        If ``xi`` is not strictly between 0 and 1 or ``constraint`` is not a known kind.
    TypeError
        If ``model`` is not an :class:`SDJLSModel`.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro
    >>> tightening(macro(), 0.85).round(4)[0]
    array([1.0364, 1.0364])
    """
    model = check_model(model)
    xi = check_xi(xi)
    constraint = check_choice("constraint", constraint, CONSTRAINT_KINDS)

    if constraint == "individual":
        # eq. (constraint:det_univariate): F^{-1}_{G_j E_i w}(xi), G_j E_i w ~ N(0, G_j E_i W E_i' G_j')
        return special.ndtri(xi) * _row_std(model)
    if constraint == "bonferroni":
        # union bound: each row at level 1 - (1 - xi) / r, so all rows hold with prob. >= xi
        return special.ndtri(1.0 - (1.0 - xi) / model.r) * _row_std(model)
    # eq. (constraint:chi_square), Lemma 1 with w = W^{1/2} v, v ~ N(0, I_p): the ellipsoid
    # ||v|| <= delta, delta^2 = F^{-1}_{chi2, p}(xi), must lie in {v : G_j E_i W^{1/2} v <= slack_j}
    delta = math.sqrt(stats.chi2.ppf(xi, df=model.p))
    rows = np.einsum("jn,inp,pq->ijq", model.G, model.E, model.W_sqrt)  # (N, r, p): G_j E_i W^{1/2}
    return delta * np.linalg.norm(rows, axis=-1)


def tightened_set_empty(
    model: SDJLSModel, xi: float, k_next: int, constraint: str = "individual"
) -> np.ndarray:
    """Whether the tightened set ``{y : G y <= H_{k_next} - t[i]}`` is empty, per mode ``i``.

    When it is empty, no next-state mean satisfies the deterministic constraints of the
    receding-horizon QP, whatever the state and the offset ``nu``: the QP is feasible only through
    its slack, ``rho > 0`` at that step. With the band of the macroeconomic example (two opposite
    rows, ``2 + k/2 <= x(2) <= 5 + k/2``, 3 wide, each row tightened by the same ``t``), this
    happens as soon as ``t > 1.5``; the slack then absorbs the excess, ``rho = rho' + t - 1.5``,
    and the minimizing ``nu`` no longer depends on ``xi``.

    Parameters
    ----------
    model : SDJLSModel
    xi : float
        Chance-constraint level, strictly between 0 and 1.
    k_next : int
        Time of the next state (it selects the band ``H_{k_next}``), ``>= 0``.
    constraint : {"individual", "joint", "bonferroni"}
        Which tightening (see :func:`tightening`).

    Returns
    -------
    (N,) bool ndarray
        ``True`` where the tightened set is empty when the current mode is ``i``; decided by a
        linear feasibility problem (``scipy.optimize.linprog``, HiGHS).

    Raises
    ------
    ValueError
        If ``xi`` or ``constraint`` is invalid, ``k_next < 0``, or the LP solver fails.
    TypeError
        If ``k_next`` is not an int, or ``model`` is not an :class:`SDJLSModel`.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro
    >>> tightened_set_empty(macro(), 0.85, 1), tightened_set_empty(macro(), 0.85, 1, "joint")
    (array([False, False, False]), array([ True,  True,  True]))
    """
    from scipy.optimize import linprog

    model = check_model(model)
    xi = check_xi(xi)
    constraint = check_choice("constraint", constraint, CONSTRAINT_KINDS)
    k_next = check_int("k_next", k_next, low=0)
    t = tightening(model, xi, constraint)
    H = model.H(k_next)
    out = np.empty(model.N, dtype=bool)
    for i in range(model.N):
        res = linprog(
            np.zeros(model.n),
            A_ub=model.G,
            b_ub=H - t[i],
            bounds=[(None, None)] * model.n,
            method="highs",
        )
        if res.status not in (0, 2):  # 0: a feasible point, 2: infeasible
            raise ValueError(
                f"the feasibility LP of the tightened set failed (mode {i}, xi = {xi}, "
                f"k_next = {k_next}): {res.message}"
            )
        out[i] = res.status == 2
    return out


def row_satisfaction_probability(
    model: SDJLSModel,
    mean_next: np.ndarray,
    mode: int | np.ndarray,
    k_next: int | np.ndarray,
) -> np.ndarray:
    """Exact ``Pr{G_j x_{k+1} <= H_{k+1, j}}`` for ``x_{k+1} ~ N(mean_next, E_mode W E_mode')``.

    Parameters
    ----------
    model : SDJLSModel
    mean_next : (..., n) array
        Mean of the next state, ``Atilde_theta x_k + B_theta nu_k``.
    mode : int or (...) int array
        The current mode ``theta_k`` (it selects the noise matrix ``E_theta``).
    k_next : int or int array broadcastable to the batch shape
        The time ``k + 1`` of the next state (it selects the band ``H_{k+1}``).

    Returns
    -------
    (..., r) ndarray
        Probability that each row holds. A row whose variance ``G_j E W E' G_j'`` is 0 is
        deterministic: 1.0 if ``G_j mean_next <= H_{k+1, j}``, else 0.0.
    """
    model = check_model(model)
    mean_next = np.asarray(mean_next, dtype=np.float64)
    if mean_next.ndim < 1 or mean_next.shape[-1] != model.n:
        raise ValueError(
            f"mean_next has shape {mean_next.shape}; expected (..., {model.n}), the mean of the "
            "next state"
        )
    mode = np.asarray(mode)
    if not np.issubdtype(mode.dtype, np.integer) or np.any((mode < 0) | (mode >= model.N)):
        raise ValueError(f"mode = {mode!r} must be an integer (array) in [0, {model.N})")
    var = np.einsum("jn,...nm,jm->...j", model.G, model.noise_cov[mode], model.G)
    slack = model.H(k_next) - mean_next @ model.G.T  # (..., r)
    var, slack = np.broadcast_arrays(var, slack)
    positive = var > 0.0
    std = np.sqrt(np.where(positive, var, 1.0))
    return np.where(positive, stats.norm.cdf(slack / std), np.where(slack >= 0.0, 1.0, 0.0))
