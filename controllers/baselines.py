"""Baseline controllers: linear state feedback and the MJLS LQ regulator (coupled Riccati).

Both share the interface of :class:`controllers.base.Controller` (``act``, ``act_batch``,
``predict``). Their decision does not depend on the time ``k``, so ``predict`` needs no horizon.

The baselines ignore the region ``G x <= H_k`` and the chance constraints entirely; they are
reference points for the receding-horizon controller of :mod:`controllers.rhc`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sdjls_gym.errors import RiccatiConvergenceError
from sdjls_gym.messages import describe
from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import check_array, check_choice, check_int, check_positive

from .base import Controller, check_gain

__all__ = [
    "LinearFeedbackController",
    "MJLSLQRController",
    "coupled_riccati_residual",
]


class _LinearPolicy(Controller):
    """``u = K_theta x + nu`` for gains ``self.K`` (N, m, n) and the offsets of
    :meth:`_offsets` (none here); vectorized over batches."""

    K: np.ndarray
    _needs_time = False  # predict() needs no horizon
    #: ``info["status"]`` of every decision
    _status = "feedback"

    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """``u = K_mode x`` (plus the policy's offset ``info["nu"]``, if it has one);
        ``info["cost"]`` is the stage cost ``x'Q x + u'R u``."""
        x, mode, k = self._check_inputs(x, mode, k)
        u, info = self.act_batch(x[None], np.array([mode]), np.array([k]))
        return u[0], {key: value[0] for key, value in info.items()}

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray | int
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Inputs for a batch (see :meth:`Controller.act_batch`), one offset drawn per row."""
        x, mode, k = self._check_batch_inputs(x, mode, k)
        B = x.shape[0]
        nu = self._offsets(B)
        u = np.einsum("bij,bj->bi", self.K[mode], x)
        if nu is None:
            nu = np.zeros((B, self.model.m))
        else:
            u = u + nu
        info = {
            "nu": nu,
            "rho": np.zeros(B),
            "cost": self.model.stage_cost(x, mode, u),
            "status": np.full(B, self._status, dtype=object),
            "ok": np.ones(B, dtype=bool),
        }
        return u, info

    def _offsets(self, size: int) -> np.ndarray | None:
        """The offsets ``nu`` (size, m) of a batch, or None (no offset: ``nu = 0``)."""
        return None


class LinearFeedbackController(_LinearPolicy):
    """Mode-dependent linear state feedback ``u_k = K_theta x_k`` (``nu_k = 0``).

    The region ``G x <= H_k`` and any chance constraint are ignored.

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n) array
        Gains, e.g. ``PAPER_K`` of the macro example or the output of Proposition 2.
    horizon : int, optional
        Accepted for symmetry with the receding-horizon controllers; unused (the decision does
        not depend on ``k``).

    Raises
    ------
    TypeError
        If ``K`` has entries that are not numbers.
    ValueError
        If ``K`` has the wrong shape or a non-finite entry.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro, PAPER_K
    >>> u, info = LinearFeedbackController(macro(), PAPER_K).act([2.0, 2.0], 0, 0)
    >>> u
    array([-1.4])
    """

    def __init__(self, model: SDJLSModel, K: np.ndarray, horizon: int | None = None) -> None:
        super().__init__(model, horizon)
        self.K = check_gain(self.model, K)


def _transition_matrix(model: SDJLSModel, transition: Any) -> np.ndarray:
    if isinstance(transition, str):
        which = check_choice("transition", transition, ("in", "out", "average"))
        if which == "in":
            return np.array(model.P_in)
        if which == "out":
            return np.array(model.P_out)
        return 0.5 * (model.P_in + model.P_out)
    N = model.N
    P = check_array(
        "transition",
        transition,
        shape=(N, N),
        what=f"'in', 'out', 'average' or an explicit stochastic matrix for N={N}",
    )
    if np.any(P < 0.0):
        raise ValueError(f"transition = {describe(P)} has a negative entry; expected entries >= 0")
    sums = P.sum(axis=1)
    if np.any(np.abs(sums - 1.0) > 1e-9):
        i = int(np.argmax(np.abs(sums - 1.0)))
        raise ValueError(
            f"transition row {i} sums to {sums[i]:.12g}; each row of a transition matrix must "
            "sum to 1"
        )
    return P


def coupled_riccati_residual(
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, P: np.ndarray, X: np.ndarray
) -> np.ndarray:
    """Residual of the coupled algebraic Riccati equations of a Markov jump linear system.

    ``res_i = Q_i + A_i' E_i A_i - A_i' E_i B_i (R_i + B_i' E_i B_i)^{-1} B_i' E_i A_i - X_i``
    with ``E_i = sum_j P[i, j] X_j`` (Costa, Fragoso and Marques 2005, ch. 4).

    Parameters
    ----------
    A : (N, n, n)
    B : (N, n, m)
    Q : (N, n, n)
    R : (N, m, m)
    P : (N, N) transition matrix
    X : (N, n, n)

    Returns
    -------
    (N, n, n) ndarray
    """
    EX = np.einsum("ij,jab->iab", P, X)
    At = A.transpose(0, 2, 1)
    BtE = B.transpose(0, 2, 1) @ EX  # (N, m, n)
    S = R + BtE @ B
    BtEA = BtE @ A
    return Q + At @ EX @ A - BtEA.transpose(0, 2, 1) @ np.linalg.solve(S, BtEA) - X


class MJLSLQRController(_LinearPolicy):
    """Infinite-horizon LQ regulator of the Markov jump linear system (coupled Riccati).

    The state-dependent switching of the SDJLS is replaced by a fixed Markov chain with
    transition matrix ``P`` (``transition``), and the coupled algebraic Riccati equations
    (Costa, Fragoso and Marques 2005)::

        X_i = Q_i + A_i' E_i(X) A_i - A_i' E_i(X) B_i (R_i + B_i' E_i(X) B_i)^{-1} B_i' E_i(X) A_i
        E_i(X) = sum_j P[i, j] X_j

    are solved by value iteration from ``X = Q`` until the relative change (max-abs norm) is
    below ``tol``. The control is ``u = F_i x`` with
    ``F_i = -(R_i + B_i' E_i(X) B_i)^{-1} B_i' E_i(X) A_i``. The region ``G x <= H_k``, the chance
    constraints and the noise are ignored (certainty equivalence: additive noise does not change
    the optimal gain).

    Parameters
    ----------
    model : SDJLSModel
    transition : {"average", "in", "out"} or (N, N) array
        ``"in"``: ``P_in``; ``"out"``: ``P_out``; ``"average"``: ``(P_in + P_out) / 2``; or an
        explicit row-stochastic matrix.
    horizon : int, optional
        Needed only by :meth:`predict`.
    tol : float
        Relative change at which the iteration stops.
    max_iter : int
        Maximum number of iterations.

    Attributes
    ----------
    X : (N, n, n) ndarray
        Solution of the coupled Riccati equations.
    F : (N, m, n) ndarray
        Gains ``u = F_i x``.
    transition_matrix : (N, N) ndarray
    iterations : int

    Raises
    ------
    ValueError
        Bad ``transition``, ``tol`` or ``max_iter``.
    RiccatiConvergenceError
        (a :class:`RuntimeError`) if the iteration diverges or does not converge within
        ``max_iter`` iterations, which happens when the MJLS is not mean-square stabilisable.
    """

    def __init__(
        self,
        model: SDJLSModel,
        transition: str | np.ndarray = "average",
        horizon: int | None = None,
        tol: float = 1e-12,
        max_iter: int = 100000,
    ) -> None:
        super().__init__(model, horizon)
        self.transition_matrix = _transition_matrix(self.model, transition)
        tol = check_positive("tol", tol, "relative change at which the Riccati iteration stops")
        max_iter = check_int("max_iter", max_iter, low=1)
        self.X, self.F, self.iterations = self._solve(tol, max_iter)
        self.K = self.F  # u = F_i x

    def _solve(self, tol: float, max_iter: int) -> tuple[np.ndarray, np.ndarray, int]:
        model, P = self.model, self.transition_matrix
        A, B, Q, R = model.A, model.B, model.Q, model.R
        At, Bt = A.transpose(0, 2, 1), B.transpose(0, 2, 1)
        X = np.array(Q)
        change = np.inf
        for it in range(1, max_iter + 1):
            EX = np.einsum("ij,jab->iab", P, X)  # E_i(X)
            BtE = Bt @ EX
            BtEA = BtE @ A
            F = -np.linalg.solve(R + BtE @ B, BtEA)
            X_new = Q + At @ EX @ A + BtEA.transpose(0, 2, 1) @ F
            X_new = 0.5 * (X_new + X_new.transpose(0, 2, 1))
            scale = float(np.max(np.abs(X_new)))
            if not np.isfinite(scale) or scale > 1e200:
                raise RiccatiConvergenceError(
                    f"the coupled Riccati iteration diverged after {it} iterations (max |X| = "
                    f"{scale:.3g}); the Markov jump linear system (A, B) with transition matrix "
                    f"{describe(P)} is not mean-square stabilisable, so no LQ regulator exists"
                )
            change = float(np.max(np.abs(X_new - X)))
            X = X_new
            if change <= tol * max(scale, np.finfo(float).tiny):
                break
        else:
            raise RiccatiConvergenceError(
                f"the coupled Riccati iteration did not converge in max_iter = {max_iter} "
                f"iterations (last relative change {change / max(scale, 1e-300):.3g} > tol = "
                f"{tol:g}); the MJLS is probably not mean-square stabilisable with transition "
                f"matrix {describe(P)}, or increase max_iter"
            )
        EX = np.einsum("ij,jab->iab", P, X)
        BtE = Bt @ EX
        F = -np.linalg.solve(R + BtE @ B, BtE @ A)
        X.setflags(write=False)
        F.setflags(write=False)
        return X, F, it
