"""Baseline controllers: linear state feedback and the MJLS LQ regulator (coupled Riccati).

Every controller of this package shares the interface of :class:`_FeedbackPolicy`:

* ``act(x, mode, k) -> (u, info)`` for one state, with ``info["nu"]``, ``info["rho"]``,
  ``info["cost"]`` and ``info["status"]``;
* ``predict(observation, state=None, episode_start=None, deterministic=True)`` in the
  stable-baselines3 shape, decoding the environment's observation ``[x, one-hot(mode), k/horizon]``.

The baselines ignore the region ``G x <= H_k`` and the chance constraints entirely; they are
reference points for the receding-horizon controller of :mod:`controllers.rhc`.
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from sdjls_gym.env import decode_observation
from sdjls_gym.model import SDJLSModel, _fmt

__all__ = [
    "LinearFeedbackController",
    "MJLSLQRController",
    "RiccatiConvergenceError",
    "coupled_riccati_residual",
]


class RiccatiConvergenceError(RuntimeError):
    """The coupled Riccati iteration did not converge (subclass of :class:`RuntimeError`)."""


#: Largest state magnitude a controller accepts. The costs it reports (``x'Q x`` and the like)
#: overflow float64 from about 1e154; a state above this bound means the closed loop diverged
#: long ago (the environments terminate at ``divergence_bound``, at most 1e30).
MAX_STATE = 1e100
_TOO_LARGE = (
    f"has an entry of magnitude above {MAX_STATE:.0e}, the largest state a controller accepts "
    "(its costs would overflow float64); a state this large means the closed loop has diverged"
)


def _check_model(model: Any) -> SDJLSModel:
    if not isinstance(model, SDJLSModel):
        raise TypeError(
            f"model must be an sdjls_gym.SDJLSModel, got {type(model).__name__}; build one with "
            "SDJLSModel(...) or a preset such as sdjls_gym.systems.macro()"
        )
    return model


def _check_int(name: str, value: Any, low: int, high: int | None = None) -> int:
    """An int (not a bool) with ``low <= value`` (``< high`` when given)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} = {value!r:.60} must be an int, got {type(value).__name__}")
    value = int(value)
    if value < low or (high is not None and value >= high):
        expected = f"in [{low}, {high})" if high is not None else f">= {low}"
        raise ValueError(f"{name} = {value} is out of range; expected an int {expected}")
    return value


def _check_positive(name: str, value: Any, what: str) -> float:
    """A finite float > 0."""
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(
            f"{name} = {value!r} is a bool; {name} ({what}) must be a finite number > 0"
        )
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} = {value!r:.60} is not a number; {name} ({what}) must be a finite number > 0"
        ) from None
    if not (np.isfinite(out) and out > 0.0):
        raise ValueError(
            f"{name} = {out!r} is invalid; {name} ({what}) must be a finite number > 0"
        )
    return out


def _check_gain(model: SDJLSModel, K: Any, name: str = "K") -> np.ndarray:
    """A finite ``(N, m, n)`` array of mode-dependent feedback gains."""
    try:
        K = np.array(K, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} could not be read as an array of numbers ({exc})") from None
    expected = (model.N, model.m, model.n)
    if K.shape != expected:
        raise ValueError(
            f"{name} has shape {K.shape}; expected {expected} (one m x n gain per mode, "
            f"N={model.N}, m={model.m}, n={model.n})"
        )
    if not np.all(np.isfinite(K)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(K))[0])
        raise ValueError(
            f"{name} has a non-finite entry {K[bad]} at index {bad}; every gain entry must be finite"
        )
    K.setflags(write=False)
    return K


def _check_horizon(horizon: Any) -> int | None:
    if horizon is None:
        return None
    return _check_int("horizon", horizon, 1)


class _FeedbackPolicy:
    """Shared plumbing of the controllers: input checks and the stable-baselines3 ``predict``.

    Subclasses implement :meth:`act`. ``predict`` decodes the environment's observation
    ``[x (n), one-hot of the mode (N), k / horizon]`` and calls :meth:`act` for each row.

    Parameters
    ----------
    model : SDJLSModel
    horizon : int, optional
        Episode length used by the environment to scale time in the observation; needed only by
        :meth:`predict`.
    """

    def __init__(self, model: SDJLSModel, horizon: int | None = None) -> None:
        self.model = _check_model(model)
        self.horizon = _check_horizon(horizon)

    # ------------------------------------------------------------------ single decisions
    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """The input ``u_k`` for state ``x``, mode ``mode`` at time ``k``.

        Parameters
        ----------
        x : (n,) array
        mode : int in ``[0, N)``
        k : int >= 0

        Returns
        -------
        u : (m,) float64 array
        info : dict
            At least ``"nu"`` (m,), ``"rho"`` (float), ``"cost"`` (float), ``"status"`` (str).
        """
        raise NotImplementedError

    def _check_inputs(self, x: Any, mode: Any, k: Any) -> tuple[np.ndarray, int, int]:
        model = self.model
        try:
            x = np.array(x, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"x could not be read as an array of numbers ({exc})") from None
        if x.shape != (model.n,):
            raise ValueError(f"x has shape {x.shape}; expected ({model.n},), one state vector")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"x = {_fmt(x)} has a non-finite entry; the state must be finite")
        if np.max(np.abs(x)) > MAX_STATE:
            raise ValueError(f"x = {_fmt(x)} {_TOO_LARGE}")
        mode = _check_int("mode", mode, 0, model.N)
        k = _check_int("k", k, 0)
        return x, mode, k

    def _check_batch_inputs(
        self, x: Any, mode: Any, k: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``x`` (B, n) finite, ``mode`` (B,) ints in [0, N), ``k`` (B,) ints >= 0 (or a scalar)."""
        model = self.model
        try:
            x = np.array(x, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"x could not be read as an array of numbers ({exc})") from None
        if x.ndim != 2 or x.shape[1] != model.n:
            raise ValueError(f"x has shape {x.shape}; expected (B, {model.n}), one state per row")
        if not np.all(np.isfinite(x)):
            raise ValueError("x has a non-finite entry; every state must be finite")
        if x.size and np.max(np.abs(x)) > MAX_STATE:
            row = int(np.argmax(np.max(np.abs(x), axis=1)))
            raise ValueError(f"x[{row}] = {_fmt(x[row])} {_TOO_LARGE}")
        B = x.shape[0]
        out = []
        for name, value, high in (("mode", mode, model.N), ("k", k, None)):
            arr = np.asarray(value)
            if arr.dtype == bool or not np.issubdtype(arr.dtype, np.integer):
                raise ValueError(f"{name} has dtype {arr.dtype}; expected integers")
            arr = np.broadcast_to(arr, (B,)) if arr.ndim == 0 else arr
            if arr.shape != (B,):
                raise ValueError(f"{name} has shape {arr.shape}; expected ({B},) to match x")
            if np.any(arr < 0) or (high is not None and np.any(arr >= high)):
                bad = int(arr[(arr < 0) | (arr >= (high if high is not None else np.inf))][0])
                expected = f"in [0, {high})" if high is not None else ">= 0"
                raise ValueError(f"{name} = {bad} is out of range; expected ints {expected}")
            out.append(arr.astype(np.int64))
        return x, out[0], out[1]

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray | int
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Decisions for a batch of states.

        Parameters
        ----------
        x : (B, n) array
        mode : (B,) int array
        k : (B,) int array or int

        Returns
        -------
        u : (B, m) float64 array
        info : dict of arrays with a leading axis B: at least ``"nu"`` (B, m), ``"rho"``,
            ``"cost"``, ``"status"`` (str objects) and ``"ok"`` (bool, the solver succeeded
            without a fallback). This generic version loops over :meth:`act`; subclasses
            replace it with a vectorized one.
        """
        x, mode, k = self._check_batch_inputs(x, mode, k)
        results = [self.act(xb, int(mb), int(kb)) for xb, mb, kb in zip(x, mode, k, strict=True)]
        info = {
            key: np.array([r[1][key] for r in results], dtype=object if key == "status" else None)
            for key in ("nu", "rho", "cost", "status")
        }
        info["ok"] = np.array([not str(st).startswith("fallback") for st in info["status"]])
        return np.array([r[0] for r in results], dtype=np.float64).reshape(len(results), -1), info

    # ------------------------------------------------------------------ observations
    def decode_observation(self, observation: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Split the environment's observations into states, modes and times.

        Parameters
        ----------
        observation : (n + N + 1,) or (B, n + N + 1) array
            ``[x, one-hot of the mode, k / horizon]``.

        Returns
        -------
        x : (B, n) float64
        mode : (B,) int64
            Argmax of the one-hot part.
        k : (B,) int64
            ``round(observation[..., -1] * horizon)``.

        Raises
        ------
        ValueError
            If ``horizon`` was not given to the constructor, or the observation has the wrong
            shape or non-finite entries.
        """
        model = self.model
        if self.horizon is None:
            raise ValueError(
                f"{type(self).__name__} was built without horizon, so the time k cannot be "
                "decoded from the observation's last entry k / horizon; pass horizon= (the "
                "environment's episode length, e.g. sdjls_gym.systems.macro.HORIZON) to the "
                "constructor"
            )
        obs = np.asarray(observation, dtype=np.float64)
        size = model.n + model.N + 1
        if obs.ndim not in (1, 2) or obs.shape[-1] != size:
            raise ValueError(
                f"observation has shape {obs.shape}; expected ({size},) or (batch, {size}): "
                f"[x ({model.n}), one-hot of the mode ({model.N}), k / horizon (1)]"
            )
        if not np.all(np.isfinite(obs)):
            raise ValueError("observation has a non-finite entry; every entry must be finite")
        x, mode, k = decode_observation(model, obs.reshape(-1, size), self.horizon)
        if np.any(k < 0):
            raise ValueError(
                f"observation's time entry k / horizon = {obs[:, -1].min():.6g} decodes to a "
                "negative time; it must be >= 0"
            )
        return x, mode, k

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """Actions for observations, in the shape of stable-baselines3's ``predict``.

        Parameters
        ----------
        observation : (n + N + 1,) or (B, n + N + 1) array
            ``[x, one-hot of the mode, k / horizon]`` as produced by the environment.
        state, episode_start, deterministic
            Accepted for compatibility and ignored (the controllers are memoryless and
            deterministic).

        Returns
        -------
        actions : (m,) or (B, m) float32 array
        state : the ``state`` argument, unchanged (None)
        """
        single = np.ndim(observation) == 1
        xs, modes, ks = self.decode_observation(observation)
        actions = self.act_batch(xs, modes, ks)[0].astype(np.float32)
        return (actions[0] if single else actions), state


class _LinearPolicy(_FeedbackPolicy):
    """``u = K_theta x`` for gains ``self.K`` (N, m, n); vectorized over batches."""

    K: np.ndarray

    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """``u = K_mode x``; ``info["cost"]`` is the stage cost ``x'Q x + u'R u``."""
        x, mode, k = self._check_inputs(x, mode, k)
        u, info = self.act_batch(x[None], np.array([mode]), np.array([k]))
        return u[0], {key: value[0] for key, value in info.items()}

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray | int
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        x, mode, k = self._check_batch_inputs(x, mode, k)
        u = np.einsum("bij,bj->bi", self.K[mode], x)
        B = x.shape[0]
        info = {
            "nu": np.zeros((B, self.model.m)),
            "rho": np.zeros(B),
            "cost": self.model.stage_cost(x, mode, u),
            "status": np.full(B, "feedback", dtype=object),
            "ok": np.ones(B, dtype=bool),
        }
        return u, info


class LinearFeedbackController(_LinearPolicy):
    """Mode-dependent linear state feedback ``u_k = K_theta x_k`` (``nu_k = 0``).

    The region ``G x <= H_k`` and any chance constraint are ignored.

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n) array
        Gains, e.g. ``PAPER_K`` of the macro example or the output of Proposition 2.
    horizon : int, optional
        Needed only by :meth:`predict`.

    Raises
    ------
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
        self.K = _check_gain(self.model, K)


def _transition_matrix(model: SDJLSModel, transition: Any) -> np.ndarray:
    if isinstance(transition, str):
        if transition == "in":
            return np.array(model.P_in)
        if transition == "out":
            return np.array(model.P_out)
        if transition == "average":
            return 0.5 * (model.P_in + model.P_out)
        raise ValueError(
            f"transition = {transition!r} is not known; expected 'in' (P_in), 'out' (P_out), "
            "'average' ((P_in + P_out) / 2) or an explicit (N, N) stochastic matrix"
        )
    try:
        P = np.array(transition, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"transition could not be read as a matrix ({exc})") from None
    N = model.N
    if P.shape != (N, N):
        raise ValueError(
            f"transition has shape {P.shape}; expected ({N}, {N}), a stochastic matrix for N={N}"
        )
    if not np.all(np.isfinite(P)) or np.any(P < 0.0):
        raise ValueError(f"transition = {_fmt(P)} must have finite entries >= 0")
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
        tol = _check_positive("tol", tol, "relative change at which the Riccati iteration stops")
        max_iter = _check_int("max_iter", max_iter, 1)
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
                    f"{_fmt(P)} is not mean-square stabilisable, so no LQ regulator exists"
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
                f"matrix {_fmt(P)}, or increase max_iter"
            )
        EX = np.einsum("ij,jab->iab", P, X)
        BtE = Bt @ EX
        F = -np.linalg.solve(R + BtE @ B, BtE @ A)
        X.setflags(write=False)
        F.setflags(write=False)
        return X, F, it
