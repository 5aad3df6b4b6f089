"""``ModeFilter``: the belief of a mode that is not observed (Hamilton's recursion).

An environment made with ``observe="state"`` shows ``x_k`` and ``k`` but not ``theta_k``. The
state is observed exactly, so the law of the mode given the observed states and inputs is a
vector of N probabilities, the *belief*, updated at each step by Hamilton's filter with the
paper's state-dependent jumps (section 2; modes numbered from 0)::

    x_{k+1} = A_{theta_k} x_k + B_{theta_k} u_k + E_{theta_k} w_k,   w_k ~ N(0, W)   eq. (sys:djls_noise)
    Pr{theta_{k+1} = j | theta_k = i, x_k} = P_in[i, j] if G x_k <= H_k, else P_out[i, j]  eq. (eq:p_tran)

With ``alpha_k(i) = Pr{theta_k = i | x_0..x_k, u_0..u_{k-1}}``, one step reads::

    l_k(i)         = N(x_{k+1}; A_i x_k + B_i u_k, Sigma_i),    Sigma_i = E_i W E_i'
    beta_k(i)      = alpha_k(i) l_k(i) / sum_j alpha_k(j) l_k(j)        theta_k given x_{k+1}
    alpha_{k+1}(j) = sum_i beta_k(i) Pi_k[i, j],    Pi_k = P_in if G x_k <= H_k else P_out

The order is the environments' (:meth:`sdjls_gym.SDJLSModel.step`): the matrices of
``theta_k`` produce ``x_{k+1}``, and ``theta_{k+1}`` is drawn from row ``theta_k`` of the
matrix chosen by the region of ``x_k`` at time ``k``. So ``x_{k+1}`` tells about ``theta_k``
(and about ``theta_{k+1}`` only through it): first the likelihood, then the jump. The means
and the region test are the model's own functions (``next_state``, ``in_region``), so the
filter agrees with the environments on every step. The input ``u_k`` is the one applied
(``info["u"]``, clipped to the action box); it may depend on the past states (a policy's
output) but not on the hidden mode.

The recursion runs on logarithms (log-sum-exp): a belief of 1e-400 is kept,
not rounded to 0, so later evidence can still raise it.

**Singular noise covariances.** ``Sigma_i = V diag(s) V'`` may be singular (``E_i`` with fewer
columns than ``n``, a singular ``W``, ``E_i = 0``). A direction whose eigenvalue is at most
:data:`RANK_RTOL` times the mode's largest counts as outside the range of ``Sigma_i`` (a zero
``Sigma_i`` has an empty range; its rank ``d_i`` is 0). The residual ``r_i = x_{k+1} - A_i x_k
- B_i u_k`` then splits in two:

* its part outside the range must vanish: beyond ``range_rtol`` times the size of the terms of
  the step, ``|| |A_i| |x_k| + |B_i| |u_k| + |x_{k+1}| ||`` (the rounding a computed state
  carries), mode ``i`` cannot produce ``x_{k+1}`` and ``l_k(i) = 0``;
* its part in the range has the Gaussian density on that range,
  ``exp(-r' Sigma_i^+ r / 2) / sqrt((2 pi)^d_i pdet(Sigma_i))``.

The belief is the limit of the filter with covariances ``Sigma_i + eps I`` as ``eps -> 0``:
among the modes of positive belief that can produce ``x_{k+1}``, those of the smallest rank
take all the mass (their density is larger by ``eps^(-(d_j - d_i) / 2)``), weighed by their
densities on the range; a deterministic mode (``d_i = 0``) that fits takes it all. With every
``Sigma_i`` nonsingular (every task of the suite) this is the plain Gaussian likelihood.

**A belief that would become all zero** (no mode of positive belief can produce ``x_{k+1}``:
each is outside its range, or its log-likelihood overflowed float64) raises
:class:`~sdjls_gym.errors.ImpossibleObservationError` and leaves the filter's belief as it
was; never NaN. Call :meth:`ModeFilter.reset` to start again from a prior.

Thread safety: :meth:`ModeFilter.step_batch` and :meth:`ModeFilter.initial_belief` are pure
(they read arrays fixed at construction) and may be called from several threads;
:meth:`ModeFilter.reset` and :meth:`ModeFilter.step` change the filter's belief: one filter per
trajectory, not shared between threads.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from controllers.base import check_model
from sdjls_gym.errors import ImpossibleObservationError
from sdjls_gym.messages import describe
from sdjls_gym.model import SDJLSModel
from sdjls_gym.model_checks import ROW_SUM_TOL
from sdjls_gym.validation import MAX_INDEX, check_array, check_int, check_int_array, check_number

__all__ = ["DEFAULT_RANGE_RTOL", "RANK_RTOL", "ModeFilter"]

#: An eigenvalue of ``Sigma_i`` at most this times the mode's largest is outside the range
#: (a standard deviation below 1e-6 of the largest; eigh's rounding is about 1e-16).
RANK_RTOL = 1e-12

#: Default tolerance on the part of a residual outside the range of a singular ``Sigma_i``,
#: relative to the size of the terms of the step: states rounded to float32 (the
#: observation's ``x``, relative error 6e-8 per entry) still fit; exact states fit to 1e-15.
DEFAULT_RANGE_RTOL = 1e-6


def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    """``log(sum(exp(a), axis))`` with the axis kept (size 1), ``-inf`` for an all ``-inf``
    slice (``a`` has no NaN and no ``+inf``). Written out, a measured hot path:
    ``scipy.special.logsumexp``'s argument handling took half of a :meth:`ModeFilter.step`
    (results/speed/HISTORY.md)."""
    top = np.max(a, axis=axis, keepdims=True)
    shift = np.where(top > -np.inf, top, 0.0)
    with np.errstate(divide="ignore"):  # log 0 = -inf: every entry -inf
        return np.log(np.sum(np.exp(a - shift), axis=axis, keepdims=True)) + shift


class ModeFilter:
    """The exact Bayesian filter of a hidden mode given exact states and inputs.

    See the module for the equations, the rule for singular noise covariances and the error of
    a belief that would become all zero.

    Parameters
    ----------
    model : SDJLSModel
        The environment's model (``env.unwrapped.model``).
    range_rtol : float
        Tolerance on the part of a residual outside the range of a singular noise covariance,
        relative to the size of the terms of the step (:data:`DEFAULT_RANGE_RTOL`: float32
        states fit). Not used when every covariance is nonsingular.

    Attributes
    ----------
    model : SDJLSModel
    range_rtol : float
    ranks : (N,) int array
        The rank of each mode's noise covariance ``E_i W E_i'`` (see :data:`RANK_RTOL`).

    Examples
    --------
    The mode hidden from the observation, followed by the filter from the states and inputs:

    >>> import gymnasium as gym, numpy as np, sdjls_gym
    >>> from controllers import ModeFilter
    >>> env = gym.make("SDJLS-Macro-v0", observe="state")
    >>> obs, info = env.reset(seed=0)
    >>> obs.shape  # [x (2), k / horizon]
    (3,)
    >>> mode_filter = ModeFilter(env.unwrapped.model)
    >>> mode_filter.reset().tolist()  # theta_0: the model's mode0 = 0
    [1.0, 0.0, 0.0]
    >>> x, k = info["state"], info["k"]
    >>> obs, reward, terminated, truncated, info = env.step(np.array([1.0], dtype=np.float32))
    >>> belief = mode_filter.step(x, info["u"], info["state"], k)  # theta_1 given x_0, x_1
    >>> belief.round(3).tolist()  # theta_0 = 0 is known: row 0 of P_in, x_0 in the band
    [0.6, 0.3, 0.1]
    """

    def __init__(self, model: SDJLSModel, *, range_rtol: float = DEFAULT_RANGE_RTOL) -> None:
        self.model = check_model(model)
        self.range_rtol = check_number(
            "range_rtol", range_rtol, low=0.0, what="relative tolerance outside the range"
        )
        s, V = np.linalg.eigh(model.noise_cov)  # (N, n), (N, n, n): Sigma_i = V diag(s) V'
        in_range = s > RANK_RTOL * s[:, -1:]
        safe = np.where(in_range, s, 1.0)
        # rows of V' scaled: z = whiten_i r has the covariance I on the range, 0 elsewhere
        self._whiten = np.where(
            in_range[:, :, None], V.transpose(0, 2, 1) / np.sqrt(safe)[..., None], 0.0
        )
        self._outside = np.where(in_range[:, :, None], 0.0, V.transpose(0, 2, 1))
        self.ranks = in_range.sum(axis=1)
        self._log_norm = -0.5 * (self.ranks * np.log(2 * np.pi) + np.log(safe).sum(axis=1))
        self._abs_AB = (np.abs(model.A), np.abs(model.B))
        with np.errstate(divide="ignore"):  # log 0 = -inf: a jump that cannot happen
            self._log_P = np.log(np.stack([model.P_out, model.P_in]))  # [inside]
        for array in (self._whiten, self._outside, self.ranks, self._log_norm, self._log_P):
            array.setflags(write=False)
        self._log_belief: np.ndarray | None = None

    # ------------------------------------------------------------------ beliefs
    def initial_belief(self, prior: Any = None) -> np.ndarray:
        """The belief of ``theta_0``: ``prior``, or the model's ``mode0`` when None.

        Parameters
        ----------
        prior : (N,) array, optional
            Probabilities (entries >= 0, summing to 1 within 1e-9; normalized).

        Returns
        -------
        (N,) float64 array (one-hot for an int ``mode0``). Changes nothing.
        """
        N = self.model.N
        if prior is None:
            mode0 = self.model.mode0
            return np.eye(N)[mode0] if isinstance(mode0, int) else mode0 / mode0.sum()
        prior = check_array("prior", prior, shape=(N,), what="the belief of theta_0")
        return self._probabilities("prior", prior[None])[0]

    def reset(self, prior: Any = None) -> np.ndarray:
        """Start a trajectory: the belief becomes :meth:`initial_belief` ``(prior)``.

        Returns
        -------
        (N,) float64 array, the belief of ``theta_0``.
        """
        belief = self.initial_belief(prior)
        with np.errstate(divide="ignore"):
            self._log_belief = np.log(belief)
        return belief

    @property
    def belief(self) -> np.ndarray:
        """(N,) the current belief (a copy); :meth:`reset` first."""
        return np.exp(self._current())

    @property
    def log_belief(self) -> np.ndarray:
        """(N,) the logarithm of the current belief, kept by the filter (``-inf``: zero)."""
        return self._current().copy()

    def _current(self) -> np.ndarray:
        if self._log_belief is None:
            raise RuntimeError("call reset() before step() or reading the belief")
        return self._log_belief

    # ------------------------------------------------------------------ steps
    def step(self, x: Any, u: Any, x_next: Any, k: Any) -> np.ndarray:
        """The belief of ``theta_{k+1}`` given the states up to ``x_next`` and the inputs.

        Parameters
        ----------
        x : (n,) array
            ``x_k``, the state before the step (``info["state"]`` of the previous step).
        u : (m,) array
            ``u_k``, the input applied (``info["u"]``).
        x_next : (n,) array
            ``x_{k+1}`` (``info["state"]`` of the step).
        k : int
            The time index of ``x`` (the region ``G x <= H_k`` chooses the jump).

        Returns
        -------
        (N,) float64 array; the filter keeps it for the next step.

        Raises
        ------
        ImpossibleObservationError
            (a :class:`ValueError`) No mode of positive belief can produce ``x_next``; the
            belief is left as it was.
        ValueError, TypeError
            An argument of the wrong shape, not finite, or ``k`` not an int in ``[0, 2**53]``
            (the message names it).
        """
        model = self.model
        x = check_array("x", x, shape=(model.n,), what="the state x_k")
        u = check_array("u", u, shape=(model.m,), what="the applied input u_k")
        x_next = check_array("x_next", x_next, shape=(model.n,), what="the state x_{k+1}")
        k = check_int("k", k, low=0, high=MAX_INDEX, what="the time index of x")
        log_belief = self._log_step(
            self._current()[None], x[None], u[None], x_next[None], np.array([k])
        )[0]
        self._log_belief = log_belief
        return np.exp(log_belief)

    def step_batch(
        self, belief: Any, x: Any, u: Any, x_next: Any, k: Any, *, log: bool = False
    ) -> np.ndarray:
        """:meth:`step` for a batch of trajectories, each with its own belief; pure.

        Parameters
        ----------
        belief : (B, N) or (N,) array
            The beliefs of ``theta_k`` (one for every row when (N,)); logarithms with ``log``.
        x, x_next : (B, n) arrays
        u : (B, m) array
        k : int or (B,) int array
        log : bool
            ``belief`` and the result are logarithms (``-inf`` for zero): tiny beliefs kept.

        Returns
        -------
        (B, N) float64 array, the beliefs of ``theta_{k+1}`` (logarithms with ``log``). The
        filter's own belief (:meth:`step`) is untouched.

        Raises
        ------
        ImpossibleObservationError
            A row whose ``x_next`` no mode of positive belief can produce (the first is named).
        ValueError, TypeError
            Arguments of the wrong shapes or values (named): beliefs that are not probability
            vectors (entries >= 0 summing to 1 within 1e-9), states or inputs not finite.
        """
        model = self.model
        x = check_array("x", x, shape=(None, model.n), what="the states x_k, one per row")
        B = x.shape[0]
        u = check_array("u", u, shape=(B, model.m), what="the applied inputs, one per row")
        x_next = check_array("x_next", x_next, shape=(B, model.n), what="the states x_{k+1}")
        times = check_int_array("k", k, low=0, high=MAX_INDEX)
        if times.ndim == 0:
            times = np.full(B, times, dtype=np.int64)
        if times.shape != (B,):
            raise ValueError(f"k has shape {times.shape}; expected an int or ({B},) to match x")
        beliefs = check_array("belief", belief, finite=False, what="the beliefs of theta_k")
        if beliefs.shape == (model.N,):
            beliefs = np.broadcast_to(beliefs, (B, model.N))
        if beliefs.shape != (B, model.N):
            raise ValueError(
                f"belief has shape {beliefs.shape}; expected ({model.N},) or ({B}, {model.N})"
            )
        if log:
            log_beliefs = self._logarithms("belief", beliefs)
            return self._log_step(log_beliefs, x, u, x_next, times)
        with np.errstate(divide="ignore"):
            log_beliefs = np.log(self._probabilities("belief", beliefs))
        return np.exp(self._log_step(log_beliefs, x, u, x_next, times))

    # ------------------------------------------------------------------ the recursion
    def _log_step(
        self, log_alpha: np.ndarray, x: np.ndarray, u: np.ndarray, x_next: np.ndarray, k: np.ndarray
    ) -> np.ndarray:
        """``log alpha_{k+1}`` (B, N) of ``log alpha_k`` (B, N), checked arguments."""
        log_l = self._log_likelihood(x, u, x_next)
        # the limit of Sigma_i + eps I: the smallest rank among the modes that fit takes all
        fits = (log_alpha > -np.inf) & (log_l > -np.inf)
        rank = np.where(fits, self.ranks, self.model.n + 1)
        keep = fits & (rank == rank.min(axis=1, keepdims=True))
        joint = np.where(keep, log_alpha + np.where(keep, log_l, 0.0), -np.inf)
        total = _logsumexp(joint, axis=1)
        bad = ~np.isfinite(total[:, 0])
        if bad.any():
            self._impossible(int(np.flatnonzero(bad)[0]), log_alpha, log_l, x, k)
        log_beta = joint - total  # theta_k given x_{k+1}
        # the jump: Pi_k of the region of x_k at time k, eq. (eq:p_tran)
        inside = np.asarray(self.model.in_region(x, k), dtype=np.intp)
        log_next = _logsumexp(log_beta[:, :, None] + self._log_P[inside], axis=1)[:, 0]
        return log_next - _logsumexp(log_next, axis=1)

    def _log_likelihood(self, x: np.ndarray, u: np.ndarray, x_next: np.ndarray) -> np.ndarray:
        """``log l_k(i)`` (B, N): the density on the range of ``Sigma_i`` of the residual, or
        ``-inf`` where its part outside the range is beyond the tolerance or it overflowed."""
        model = self.model
        B, N, n = x.shape[0], model.N, model.n
        modes = np.broadcast_to(np.arange(N), (B, N))
        with np.errstate(over="ignore", invalid="ignore"):  # overflow: -inf, below
            mean = model.next_state(  # A_i x + B_i u of every mode, eq. (sys:djls_noise)
                np.broadcast_to(x[:, None, :], (B, N, n)),
                modes,
                np.broadcast_to(u[:, None, :], (B, N, model.m)),
                np.zeros(model.p),
            )
            r = x_next[:, None, :] - mean
            z = np.einsum("ijk,bik->bij", self._whiten, r)
            quad = np.einsum("bij,bij->bi", z, z)
            outside = np.linalg.norm(np.einsum("ijk,bik->bij", self._outside, r), axis=2)
            abs_A, abs_B = self._abs_AB
            size = np.linalg.norm(
                np.einsum("ijk,bk->bij", abs_A, np.abs(x))
                + np.einsum("ijk,bk->bij", abs_B, np.abs(u))
                + np.abs(x_next)[:, None, :],
                axis=2,
            )
            fits = (outside <= self.range_rtol * size) & np.isfinite(quad)
            return np.where(fits, self._log_norm - 0.5 * np.where(fits, quad, 0.0), -np.inf)

    def _impossible(
        self, row: int, log_alpha: np.ndarray, log_l: np.ndarray, x: np.ndarray, k: np.ndarray
    ) -> None:
        where = "" if log_alpha.shape[0] == 1 else f"row {row}: "
        possible = [int(i) for i in np.flatnonzero(log_alpha[row] > -np.inf)]
        raise ImpossibleObservationError(
            f"{where}x_next is impossible under every mode of positive belief {possible} from "
            f"x = {describe(x[row])} at k = {int(k[row])} (log-likelihoods "
            f"{describe(log_l[row])}: -inf is a residual outside the range of a singular noise "
            "covariance, or beyond float64); the belief would be all zero. Check that u is the "
            "input applied (info['u']), the states are the environment's and the model is its "
            "model; reset(prior) starts again"
        )

    def _probabilities(self, name: str, p: np.ndarray) -> np.ndarray:
        """Rows of probabilities checked (finite, >= 0, summing to 1 within 1e-9), normalized."""
        bad = ~np.all(np.isfinite(p) & (p >= 0.0), axis=1)
        sums = p.sum(axis=1)
        bad |= ~(np.abs(sums - 1.0) <= ROW_SUM_TOL)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            label = name if p.shape[0] == 1 else f"{name}[{row}]"
            raise ValueError(
                f"{label} = {describe(p[row])} is not a probability vector; expected "
                f"{p.shape[1]} entries >= 0 summing to 1 (tolerance {ROW_SUM_TOL:g})"
            )
        return p / sums[:, None]

    def _logarithms(self, name: str, log_p: np.ndarray) -> np.ndarray:
        """Rows of log-probabilities checked (no NaN or +inf, ``logsumexp`` 0 within 1e-9),
        normalized."""
        bad = np.any(np.isnan(log_p) | (log_p == np.inf), axis=1)
        with np.errstate(invalid="ignore"):
            sums = _logsumexp(np.where(bad[:, None], 0.0, log_p), axis=1)[:, 0]
        bad |= ~(np.abs(sums) <= ROW_SUM_TOL)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"{name}[{row}] = {describe(log_p[row])} is not the logarithm of a probability "
                f"vector (log=True); expected entries whose exponentials sum to 1 (tolerance "
                f"{ROW_SUM_TOL:g})"
            )
        return log_p - sums[:, None]
