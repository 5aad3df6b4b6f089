"""The model estimated from trajectories: least squares per mode, counted jumps per region.

:func:`identify` reads trajectories ``(x_0 .. x_T, u_0 .. u_{T-1}, theta_0 .. theta_T)`` of an
SDJLS (section 2 of the paper, eq. sys:djls_noise, eq:p_tran) and returns an
:class:`~sdjls_gym.SDJLSModel` whose dynamics and transition matrices are estimated from them,
every other field taken from a template that holds what the designer knows (the region, the
weights, the initial state). It reads the data with the convention of
:meth:`SDJLSModel.step <sdjls_gym.SDJLSModel.step>`: ``theta_k``'s matrices produce
``x_{k+1}``, and the region test of ``x_k`` at time ``k`` (the template's own
:meth:`~sdjls_gym.SDJLSModel.in_region`) selects the row of ``P_in`` or ``P_out`` that draws
``theta_{k+1}``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple, overload

import numpy as np
from numpy.typing import NDArray

from sdjls_gym.errors import InsufficientDataError
from sdjls_gym.messages import a_type, describe
from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import (
    check_array,
    check_bool,
    check_choice,
    check_int,
    check_int_array,
    check_mapping,
    check_positive,
)

from .base import MAX_STATE, check_model, frozen

__all__ = ["IdentificationInfo", "identify"]

#: The keys of a trajectory: required, then optional.
REQUIRED_KEYS = ("x", "u", "mode")
OPTIONAL_KEYS = ("k0",)


@dataclass(frozen=True, eq=False)
class IdentificationInfo:
    """What the estimate of :func:`identify` rests on (``identify(..., return_info=True)``).

    Attributes
    ----------
    samples : (N,) int array
        Steps ``k`` with ``theta_k = i``: the rows of mode i's regression.
    dof : (N,) int array
        Residual degrees of freedom ``samples - n - m``, the divisor of the noise covariance.
    condition : (N,) float array
        Condition number of mode i's regressors ``[x_k, u_k]`` with each column scaled to unit
        norm (scale-free; large means some direction was hardly excited).
    noise_cov : (N, n, n) array
        The estimated noise covariance ``Sigma_i`` (the returned model's ``noise_cov``).
    counts_in, counts_out : (N, N) int arrays
        Jumps ``theta_k = i -> theta_{k+1} = j`` made from ``x_k`` inside the region
        (``G x_k <= H_k``) and outside it.
    prior_count : float
        The Dirichlet pseudo-count per entry (see :func:`identify`).
    prior : str
        ``"uniform"`` or ``"template"``: the prior mean of each transition row.
    """

    samples: NDArray[np.int64]
    dof: NDArray[np.int64]
    condition: NDArray[np.float64]
    noise_cov: NDArray[np.float64]
    counts_in: NDArray[np.int64]
    counts_out: NDArray[np.int64]
    prior_count: float
    prior: str

    @property
    def prior_rows(self) -> tuple[tuple[int, str], ...]:
        """The transition rows with no observed jump, ``(mode, "in" | "out")``: their estimate
        is the prior mean alone."""
        return tuple(
            (i, region)
            for region, counts in (("in", self.counts_in), ("out", self.counts_out))
            for i in range(counts.shape[0])
            if counts[i].sum() == 0
        )


class _Steps(NamedTuple):
    """Every step ``k -> k + 1`` of the trajectories, pooled: ``(S, .)`` arrays."""

    x: np.ndarray  # (S, n) x_k
    u: np.ndarray  # (S, m) u_k
    x_next: np.ndarray  # (S, n) x_{k+1}
    mode: np.ndarray  # (S,) theta_k
    mode_next: np.ndarray  # (S,) theta_{k+1}
    k: np.ndarray  # (S,) time index of x_k


@overload
def identify(
    trajectories: Sequence[Mapping[str, Any]],
    template: SDJLSModel,
    *,
    prior: str = ...,
    prior_count: float = ...,
    return_info: Literal[False] = ...,
) -> SDJLSModel: ...
@overload
def identify(
    trajectories: Sequence[Mapping[str, Any]],
    template: SDJLSModel,
    *,
    return_info: Literal[True],
    prior: str = ...,
    prior_count: float = ...,
) -> tuple[SDJLSModel, IdentificationInfo]: ...
def identify(
    trajectories: Sequence[Mapping[str, Any]],
    template: SDJLSModel,
    *,
    prior: str = "uniform",
    prior_count: float = 1.0,
    return_info: bool = False,
) -> SDJLSModel | tuple[SDJLSModel, IdentificationInfo]:
    """Estimate an SDJLS from trajectories: ``A_i``, ``B_i``, noise covariances, ``P_in``, ``P_out``.

    **Dynamics** (eq. sys:djls_noise). For each mode ``i``, ordinary least squares over the
    steps with ``theta_k = i`` (all trajectories pooled)::

        [A_i B_i] = argmin sum_k |x_{k+1} - A x_k - B u_k|^2        (S_i steps)
        Sigma_i   = sum_k r_k r_k' / (S_i - n - m),   r_k = x_{k+1} - A_i x_k - B_i u_k

    ``Sigma_i`` is the unbiased estimate of the covariance ``E_i W E_i'`` of the noise (the
    residual sum divided by the residual degrees of freedom, not by ``S_i``: with few steps in
    a mode the maximum-likelihood divisor would underestimate it). The returned model has
    ``W = I`` (``p = n``) and ``E_i = Sigma_i^{1/2}``, the symmetric positive semidefinite
    square root, so that ``model.noise_cov[i] == Sigma_i``; a singular ``Sigma_i`` (a direction
    without noise) gives a singular ``E_i``. The regression is solved by an SVD of the
    regressors with each column scaled to unit norm, so its rank test does not depend on the
    units of ``x`` and ``u``.

    **Transitions** (eq. eq:p_tran). The jumps ``theta_k = i -> theta_{k+1} = j`` are counted
    separately for ``x_k`` inside the region (``G x_k <= H_k`` at ``x_k``'s time ``k``, by the
    template's region test): ``C_in``, and outside it: ``C_out``. Each row is the mean of its
    Dirichlet posterior::

        P_in[i, j] = (C_in[i, j] + a_ij) / (sum_l C_in[i, l] + sum_l a_il)     (P_out alike)

    with pseudo-counts ``a_ij = prior_count`` (``prior="uniform"``: a symmetric Dirichlet,
    ``prior_count = 1`` is Laplace's rule) or ``a_ij = N * prior_count * T_ij`` with ``T`` the
    template's ``P_in`` or ``P_out`` (``prior="template"``: the designer's matrices as the prior
    mean, with the same total weight ``N * prior_count``). A row never observed is the prior
    mean (uniform, or the template's row), not an error; ``IdentificationInfo.prior_rows``
    lists them.

    Everything else (``G``, ``H0``, ``H_rate``, ``Q``, ``R``, ``x0``, ``mode0``, the names)
    is the template's.

    Parameters
    ----------
    trajectories : list or tuple of dicts
        Each with ``"x"`` (T + 1, n), ``"u"`` (T, m) and ``"mode"`` (T + 1,) integers in
        ``[0, N)``, and optionally ``"k0"``, the time index of ``x[0]`` (0 by default; the region
        ``H_k`` may move with ``k``). ``T`` may differ between trajectories (an episode that
        ended early). ``u`` is the input the system received: on an environment that clips
        actions, the clipped one (``info["u"]`` of :class:`~sdjls_gym.SDJLSVectorEnv`).
    template : SDJLSModel
        What the designer knows: its ``n``, ``m`` and ``N`` must be the data's; its region and
        its weights are kept. Its ``A``, ``B``, ``E``, ``W`` are not read; its ``P_in`` and
        ``P_out`` only with ``prior="template"``.
    prior : {"uniform", "template"}
        The prior mean of each transition row.
    prior_count : float
        Pseudo-count per entry, > 0 (default 1).
    return_info : bool
        Also return an :class:`IdentificationInfo` (counts, condition numbers, degrees of
        freedom).

    Returns
    -------
    SDJLSModel
        The estimate; with ``return_info=True``, ``(model, info)``.

    Raises
    ------
    InsufficientDataError
        (a :class:`ValueError`) a mode is never the mode of a step, has fewer than
        ``n + m + 1`` steps, or its regressors ``[x_k, u_k]`` have rank below ``n + m`` (no
        input excitation independent of the state); the message names the mode and the remedy.
    TypeError
        ``trajectories`` is not a list or tuple of dicts, an entry is not a number, or
        ``template`` is not an SDJLSModel.
    ValueError
        An empty list, a missing or unknown key, a shape that does not match the others or the
        template (the message names the trajectory, the key, the shape found and expected), a
        non-finite entry or one beyond ``1e100``, a mode out of range.

    Examples
    --------
    >>> import dataclasses
    >>> import numpy as np
    >>> from sdjls_gym import SDJLSModel
    >>> template = SDJLSModel(A=[[[0.0]], [[0.0]]], B=[[0.0]], P_in=[[0.5, 0.5], [0.5, 0.5]],
    ...                       P_out=[[0.5, 0.5], [0.5, 0.5]], G=[[1.0]], H0=[0.5], Q=[[1.0]],
    ...                       R=[[1.0]], x0=[0.0])
    >>> true = dataclasses.replace(template, A=[[[0.5]], [[0.9]]], B=[[[1.0]], [[2.0]]],
    ...                            W=[[0.01]], P_in=[[0.9, 0.1], [0.2, 0.8]],
    ...                            P_out=[[0.4, 0.6], [0.3, 0.7]])
    >>> rng = np.random.default_rng(0)
    >>> episodes, T = 100, 50
    >>> x = np.zeros((episodes, T + 1, 1))
    >>> mode = np.zeros((episodes, T + 1), dtype=int)
    >>> u = rng.normal(size=(episodes, T, 1))
    >>> for k in range(T):
    ...     w = true.sample_noise(rng, (episodes,))
    ...     x[:, k + 1] = true.next_state(x[:, k], mode[:, k], u[:, k], w)
    ...     mode[:, k + 1] = true.sample_next_mode(x[:, k], mode[:, k], k, rng)
    >>> data = [{"x": x[b], "u": u[b], "mode": mode[b]} for b in range(episodes)]
    >>> model = identify(data, template)
    >>> np.round(model.A.ravel(), 2), np.round(model.B.ravel(), 2)
    (array([0.5, 0.9]), array([1., 2.]))
    >>> np.round(model.P_in, 1)
    array([[0.9, 0.1],
           [0.2, 0.8]])
    >>> np.round(model.noise_cov.ravel(), 3)
    array([0.01, 0.01])
    """
    template = check_model(template)
    prior = check_choice("prior", prior, ("uniform", "template"))
    prior_count = check_positive("prior_count", prior_count, "Dirichlet pseudo-count per entry")
    return_info = check_bool("return_info", return_info)
    steps = _pool(trajectories, template)
    A, B, cov, samples, condition = _fit_dynamics(steps, template)
    P, counts = _fit_transitions(steps, template, prior, prior_count)
    model = dataclasses.replace(
        template,
        A=A,
        B=B,
        E=_psd_sqrt(cov),
        W=np.eye(template.n),
        P_in=P["in"],
        P_out=P["out"],
    )
    if not return_info:
        return model
    n_theta = template.n + template.m
    info = IdentificationInfo(
        samples=_read_only(samples),
        dof=_read_only(samples - n_theta),
        condition=frozen(condition),
        noise_cov=frozen(cov),
        counts_in=_read_only(counts["in"]),
        counts_out=_read_only(counts["out"]),
        prior_count=prior_count,
        prior=prior,
    )
    return model, info


def _fit_transitions(
    steps: _Steps, template: SDJLSModel, prior: str, prior_count: float
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """``P`` and the jump counts, keyed ``"in"`` and ``"out"``: the jumps counted from ``x_k``
    inside the template's region and outside it, each row the mean of its Dirichlet posterior
    (see :func:`identify`)."""
    inside = np.asarray(template.in_region(steps.x, steps.k), dtype=bool)
    counts = {}
    P = {}
    for region, mask in (("in", inside), ("out", ~inside)):
        counts[region] = _count_jumps(steps.mode[mask], steps.mode_next[mask], template.N)
        prior_mean = getattr(template, f"P_{region}") if prior == "template" else None
        P[region] = _dirichlet_mean(counts[region], prior_count, prior_mean)
    return P, counts


# ---------------------------------------------------------------------- the data
def _pool(trajectories: Any, template: SDJLSModel) -> _Steps:
    """Every trajectory checked against the template, its steps pooled."""
    if (
        isinstance(trajectories, Mapping)
        or not isinstance(trajectories, Sequence)
        or isinstance(trajectories, (str, bytes))
    ):
        hint = " (one trajectory: wrap it in a list)" if isinstance(trajectories, Mapping) else ""
        raise TypeError(
            f"trajectories = {describe(trajectories)} is {a_type(trajectories)}; expected a "
            f"list or tuple of dicts with keys 'x', 'u', 'mode'{hint}"
        )
    if len(trajectories) == 0:
        raise ValueError(
            "trajectories = [] is empty; expected at least one dict with keys 'x', 'u', 'mode'"
        )
    parts = [_trajectory(i, t, template) for i, t in enumerate(trajectories)]
    x = [p[0] for p in parts]
    mode = [p[2] for p in parts]
    return _Steps(
        x=np.concatenate([xi[:-1] for xi in x]),
        u=np.concatenate([p[1] for p in parts]),
        x_next=np.concatenate([xi[1:] for xi in x]),
        mode=np.concatenate([mi[:-1] for mi in mode]),
        mode_next=np.concatenate([mi[1:] for mi in mode]),
        k=np.concatenate([p[3] + np.arange(len(p[1]), dtype=np.int64) for p in parts]),
    )


def _trajectory(
    i: int, trajectory: Any, template: SDJLSModel
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``(x (T+1, n), u (T, m), mode (T+1,), k0)`` of ``trajectories[i]``, checked."""
    name = f"trajectories[{i}]"
    data = check_mapping(name, trajectory, allowed=REQUIRED_KEYS + OPTIONAL_KEYS)
    missing = [key for key in REQUIRED_KEYS if key not in data]
    if missing:
        raise ValueError(
            f"{name} has no key {missing[0]!r}; expected keys 'x' (T + 1, n), 'u' (T, m), "
            "'mode' (T + 1,) and optionally 'k0'"
        )
    n, m, N = template.n, template.m, template.N
    x = check_array(f"{name}['x']", data["x"], max_abs=MAX_STATE, what="states")
    if x.ndim != 2 or x.shape[0] < 1 or x.shape[1] != n:
        raise ValueError(
            f"{name}['x'] has shape {x.shape}; expected (T + 1, {n}): T + 1 >= 1 states of the "
            f"template's n = {n} entries"
        )
    T = x.shape[0] - 1
    u = check_array(f"{name}['u']", data["u"], max_abs=MAX_STATE, what="inputs")
    if u.shape != (T, m):
        raise ValueError(
            f"{name}['u'] has shape {u.shape}; expected ({T}, {m}): one input of the template's "
            f"m = {m} entries per step, T = {T} steps as in 'x' of shape {x.shape}"
        )
    mode = check_int_array(f"{name}['mode']", data["mode"], low=0, high=N - 1)
    if mode.shape != (T + 1,):
        raise ValueError(
            f"{name}['mode'] has shape {mode.shape}; expected ({T + 1},): one mode per state, "
            f"as in 'x' of shape {x.shape}"
        )
    k0 = check_int(f"{name}['k0']", data.get("k0", 0), low=0, what="time index of x[0]")
    return x, u, mode, k0


# ---------------------------------------------------------------------- the estimates
def _fit_dynamics(
    steps: _Steps, template: SDJLSModel
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``A`` (N, n, n), ``B`` (N, n, m), ``Sigma`` (N, n, n), steps (N,) and condition numbers
    (N,) by least squares per mode; :class:`InsufficientDataError` when a mode's data do not
    determine them."""
    n, m, N = template.n, template.m, template.N
    d = n + m
    A, B = np.empty((N, n, n)), np.empty((N, n, m))
    cov, condition = np.empty((N, n, n)), np.empty(N)
    samples = np.bincount(steps.mode, minlength=N).astype(np.int64)
    for i in range(N):
        label = f"mode {i} ({template.mode_names[i]!r})"
        if samples[i] < d + 1:
            seen = (
                f"is the mode of no step (theta_k = {i} in no trajectory)"
                if samples[i] == 0
                else f"is the mode of {samples[i]} step(s)"
            )
            raise InsufficientDataError(
                f"{label} {seen}; its A_i, B_i and noise covariance need at least n + m + 1 = "
                f"{d + 1} steps (n + m = {d} for the regression, 1 for the residual): explore "
                "longer, with more episodes or from other initial modes"
            )
        rows = steps.mode == i
        Z = np.concatenate([steps.x[rows], steps.u[rows]], axis=1)
        Y = steps.x_next[rows]
        scale = np.linalg.norm(Z, axis=0)
        scale[scale == 0.0] = 1.0  # a column of zeros stays one: its singular value is 0
        Zs = Z / scale
        U, s, Vt = np.linalg.svd(Zs, full_matrices=False)
        rank = int(np.sum(s > s[0] * max(Zs.shape) * np.finfo(float).eps))  # numpy's matrix_rank
        if rank < d:
            raise InsufficientDataError(
                f"{label}: the regressors [x_k, u_k] of its {samples[i]} steps have rank "
                f"{rank} < n + m = {d} (singular values of the "
                f"column-scaled regressors {describe(s)}): the data do not separate A_i from "
                "B_i; excite the inputs independently of the state (input noise, e.g. "
                "controllers.ExplorationPolicy's input_std > 0) and the states in every direction"
            )
        theta = (Vt.T @ ((U.T @ Y) / s[:, None])) / scale[:, None]  # (n + m, n)
        A[i], B[i] = theta[:n].T, theta[n:].T
        residual = Y - Z @ theta
        S = residual.T @ residual / (samples[i] - d)
        cov[i] = 0.5 * (S + S.T)
        condition[i] = s[0] / s[-1]
    return A, B, cov, samples, condition


def _count_jumps(mode: np.ndarray, mode_next: np.ndarray, N: int) -> np.ndarray:
    """(N, N) counts of ``mode -> mode_next``."""
    return np.bincount(mode * N + mode_next, minlength=N * N).reshape(N, N).astype(np.int64)


def _dirichlet_mean(
    counts: np.ndarray, prior_count: float, prior_mean: np.ndarray | None
) -> np.ndarray:
    """Rows of the Dirichlet posterior mean: pseudo-counts ``prior_count`` per entry, or
    ``N * prior_count * prior_mean`` (the same total weight)."""
    N = counts.shape[0]
    alpha = np.full((N, N), prior_count) if prior_mean is None else N * prior_count * prior_mean
    total = counts + alpha
    return total / total.sum(axis=1, keepdims=True)


def _psd_sqrt(cov: np.ndarray) -> np.ndarray:
    """(N, n, n) symmetric positive semidefinite square roots (negative rounding clipped)."""
    values, vectors = np.linalg.eigh(cov)
    root = (vectors * np.sqrt(np.clip(values, 0.0, None))[:, None, :]) @ vectors.transpose(0, 2, 1)
    return 0.5 * (root + root.transpose(0, 2, 1))


def _read_only(a: np.ndarray) -> np.ndarray:
    out = np.array(a)
    out.setflags(write=False)
    return out
