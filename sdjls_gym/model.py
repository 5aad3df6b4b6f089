"""The state-dependent jump linear system (SDJLS): the single source of truth for the dynamics.

The model is the one of section 2 of the paper (eq. sys:djls_noise, eq:p_tran, eq:polyhedral)::

    x_{k+1} = A_{theta_k} x_k + B_{theta_k} u_k + E_{theta_k} w_k,      w_k ~ N(0, W)
    Pr{theta_{k+1} = j | theta_k = i, x_k} = P_in[i, j]   if G x_k <= H_k   (x_k in C1)
                                           = P_out[i, j]  otherwise         (x_k in C2)
    H_k = H0 + k * H_rate

Modes are numbered ``0 .. N-1`` (the paper numbers them ``1 .. N``).

Every function here that takes a state accepts a leading batch axis: ``x`` may be ``(n,)`` or
``(..., n)``, ``mode`` an int or an integer array of the matching batch shape, and ``k`` an int
or an integer array broadcastable against the batch. The environment, the vector environment
and the controllers all call these methods; nothing else re-implements the dynamics.
"""

from __future__ import annotations

import bisect
import json
import math
from dataclasses import MISSING, dataclass, field, fields
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "SDJLSModel",
    "InvalidModelError",
    "load_model",
    "save_model",
    "draw_categorical",
    "max_last",
]

_ROW_SUM_TOL = 1e-9


def max_last(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=-1)`` for an array whose last axis is short (a few constraint rows, modes or
    states): elementwise maxima of the last-axis slices, much faster than numpy's reduction
    over a short axis when the leading (batch) axes are large."""
    a = np.asarray(a)
    if a.shape[-1] < 2 or a.size < 256:
        return a.max(axis=-1)
    out = a[..., 0].copy()
    for j in range(1, a.shape[-1]):
        np.maximum(out, a[..., j], out=out)
    return out


def _stack_last(*arrays: Any) -> np.ndarray:
    """Concatenate float64 arrays along the last axis, broadcasting the leading (batch) axes."""
    arrs = [np.asarray(a, dtype=np.float64) for a in arrays]
    batch = np.broadcast_shapes(*(a.shape[:-1] for a in arrs))
    return np.concatenate([np.broadcast_to(a, (*batch, a.shape[-1])) for a in arrs], axis=-1)


def draw_categorical(probs: np.ndarray, uniform: np.ndarray | float) -> np.ndarray:
    """Inverse-CDF draws: index ``j`` with probability ``probs[..., j]`` for ``uniform`` in [0, 1).

    The CDF is normalized by its last entry, so it ends at exactly 1.0 and a category of
    probability 0 (trailing ones included) is never drawn, whatever the round-off of the sums.

    Parameters
    ----------
    probs : (..., N) rows of probabilities
    uniform : (...) draws from U[0, 1)

    Returns
    -------
    (...) int64 array
    """
    cdf = np.cumsum(probs, axis=-1)
    cdf = cdf / cdf[..., -1:]
    u = np.asarray(uniform, dtype=np.float64)[..., None]
    return np.sum(cdf <= u, axis=-1).astype(np.int64)


class InvalidModelError(ValueError):
    """A model (or a model file) is malformed. Subclass of :class:`ValueError`."""


def _fmt(value: Any) -> str:
    """Short printable form of a (possibly large) value for error messages."""
    text = np.array2string(np.asarray(value), precision=4, threshold=12, separator=", ")
    text = " ".join(text.split())  # one line, so that messages stay greppable
    return text if len(text) < 160 else text[:157] + "..."


def _as_float_array(name: str, value: Any) -> np.ndarray:
    if value is None:
        raise InvalidModelError(f"{name} is missing (None, or null in a file); expected numbers")
    try:  # a first look without conversion, for complex and missing entries
        raw = np.asarray(value) if isinstance(value, (list, tuple, np.ndarray)) else None
    except (TypeError, ValueError):
        raw = None  # ragged or unreadable: reported below
    if raw is not None and raw.dtype.kind == "c":
        raise InvalidModelError(
            f"{name} has complex entries (dtype {raw.dtype}); every entry must be a real number"
        )
    if raw is not None and raw.dtype == object:
        missing = [i for i, v in np.ndenumerate(raw) if v is None]
        if missing:
            raise InvalidModelError(
                f"{name} has a missing entry (None, or null in a file) at index "
                f"{tuple(int(j) for j in missing[0])}; every entry must be a finite number"
            )
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidModelError(
            f"{name} could not be read as an array of numbers ({exc}); got {value!r:.120}"
        ) from None
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise InvalidModelError(
            f"{name} has a non-finite entry {arr[tuple(bad)]} at index {tuple(int(i) for i in bad)};"
            " every entry must be a finite number"
        )
    return arr


def _per_mode(name: str, arr: np.ndarray, N: int, shape: tuple[int, ...], what: str) -> np.ndarray:
    """Accept ``shape`` (shared by all modes) or ``(N, *shape)``; return ``(N, *shape)``."""
    if arr.shape == shape:
        arr = np.broadcast_to(arr, (N, *shape)).copy()
    if arr.shape != (N, *shape):
        raise InvalidModelError(
            f"{name} has shape {arr.shape}; expected {(N, *shape)} ({what}) "
            f"or {shape} to use the same matrix in every mode"
        )
    return arr


def _check_symmetric(name: str, arr: np.ndarray) -> None:
    for i, M in enumerate(arr):
        scale = max(1.0, float(np.max(np.abs(M))))
        asym = float(np.max(np.abs(M - M.T)))
        if asym > 1e-9 * scale:
            raise InvalidModelError(
                f"{name}[{i}] is not symmetric (max |M - M'| = {asym:.3g}); it must be a "
                f"symmetric matrix, got {_fmt(M)}"
            )


def _check_psd(name: str, arr: np.ndarray, strict: bool) -> None:
    """arr: (N, d, d). Raise unless every slice is symmetric PSD (PD when ``strict``)."""
    _check_symmetric(name, arr)
    for i, M in enumerate(arr):
        scale = max(1.0, float(np.max(np.abs(M))))
        eig_min = float(np.linalg.eigvalsh(M)[0]) if M.size else 1.0
        if strict and eig_min <= 1e-12 * scale:
            raise InvalidModelError(
                f"{name}[{i}] is not positive definite (smallest eigenvalue {eig_min:.3g}); "
                f"it must be symmetric positive definite, got {_fmt(M)}"
            )
        if not strict and eig_min < -1e-9 * scale:
            raise InvalidModelError(
                f"{name}[{i}] is not positive semidefinite (smallest eigenvalue {eig_min:.3g}); "
                f"it must be symmetric positive semidefinite, got {_fmt(M)}"
            )


def _check_stochastic(name: str, P: np.ndarray, N: int) -> None:
    if P.shape != (N, N):
        raise InvalidModelError(f"{name} has shape {P.shape}; expected ({N}, {N}) for N={N} modes")
    neg = np.argwhere(P < 0)
    if neg.size:
        i, j = (int(v) for v in neg[0])
        raise InvalidModelError(
            f"{name}[{i}, {j}] = {P[i, j]:.6g} is negative; transition probabilities must be >= 0"
        )
    sums = P.sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > _ROW_SUM_TOL)
    if bad.size:
        i = int(bad[0])
        raise InvalidModelError(
            f"{name} row {i} sums to {sums[i]:.12g}; each row of a transition matrix must sum "
            f"to 1 (tolerance {_ROW_SUM_TOL:g})"
        )


@dataclass(frozen=True, eq=False)
class SDJLSModel:
    """A discrete-time state-dependent jump linear system with a polyhedral region.

    Shapes use N modes, n states, m inputs, p noise inputs and r constraint rows. Per-mode
    matrices (``B``, ``E``, ``Q``, ``R``) may also be given without the leading mode axis, in
    which case the same matrix is used in every mode. Arrays are copied and made read-only.

    Parameters
    ----------
    A : (N, n, n)
        State matrices ``A_i``.
    B : (N, n, m)
        Input matrices ``B_i``.
    P_in : (N, N)
        Transition matrix lambda, used when ``G x_k <= H_k`` holds row-wise (``x_k`` in C1).
    P_out : (N, N)
        Transition matrix mu, used otherwise (``x_k`` in C2).
    G : (r, n)
        Rows of the region ``C1 = {x : G x <= H_k}``.
    H0 : (r,)
        Right-hand side at ``k = 0``.
    Q : (N, n, n)
        State weights of the stage cost, symmetric positive semidefinite.
    R : (N, m, m)
        Input weights of the stage cost, symmetric positive definite.
    x0 : (n,)
        Initial state.
    E : (N, n, p), optional
        Noise input matrices; identity ``(n, n)`` per mode by default (then ``p = n``).
    W : (p, p), optional
        Covariance of ``w_k``; identity by default.
    H_rate : (r,), optional
        Drift of the right-hand side, ``H_k = H0 + k * H_rate``; zeros by default.
    mode0 : int or (N,) array
        Initial mode ``0 <= mode0 < N``, or a probability vector to draw it from.
    mode_names : sequence of N str, optional
        Human-readable names of the modes.

    Raises
    ------
    InvalidModelError
        (a :class:`ValueError`) naming the field, the bad value and what is expected.

    Examples
    --------
    >>> import numpy as np
    >>> m = SDJLSModel(A=[[[0.5]], [[1.2]]], B=[[1.0]], P_in=[[0.9, 0.1], [0.2, 0.8]],
    ...                P_out=[[0.5, 0.5], [0.5, 0.5]], G=[[1.0]], H0=[1.0], Q=[[1.0]],
    ...                R=[[1.0]], x0=[0.0])
    >>> m.N, m.n, m.m, m.p, m.r
    (2, 1, 1, 1, 1)
    """

    A: np.ndarray
    B: np.ndarray
    P_in: np.ndarray
    P_out: np.ndarray
    G: np.ndarray
    H0: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    x0: np.ndarray
    E: np.ndarray | None = None
    W: np.ndarray | None = None
    H_rate: np.ndarray | None = None
    mode0: int | np.ndarray = 0
    mode_names: tuple[str, ...] | None = field(default=None)

    # ------------------------------------------------------------------ validation
    def __post_init__(self) -> None:  # noqa: C901 - a flat list of checks reads best
        def put(name: str, value: Any) -> None:
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)

        A = _as_float_array("A", self.A)
        if A.ndim != 3 or A.shape[1] != A.shape[2] or A.shape[0] < 1 or A.shape[1] < 1:
            raise InvalidModelError(
                f"A has shape {A.shape}; expected (N, n, n): one square n x n matrix per mode"
            )
        N, n = A.shape[0], A.shape[1]

        B = _as_float_array("B", self.B)
        if B.ndim not in (2, 3) or B.shape[-2] != n or B.shape[-1] < 1:
            raise InvalidModelError(
                f"B has shape {B.shape}; expected ({N}, {n}, m) or ({n}, m) to match A of shape "
                f"{A.shape}"
            )
        m = B.shape[-1]
        B = _per_mode("B", B, N, (n, m), "one n x m input matrix per mode")

        if self.E is None:
            E = np.broadcast_to(np.eye(n), (N, n, n)).copy()
        else:
            E = _as_float_array("E", self.E)
            if E.ndim not in (2, 3) or E.shape[-2] != n or E.shape[-1] < 1:
                raise InvalidModelError(
                    f"E has shape {E.shape}; expected ({N}, {n}, p) or ({n}, p) to match A of "
                    f"shape {A.shape}"
                )
            E = _per_mode("E", E, N, (n, E.shape[-1]), "one n x p noise matrix per mode")
        p = E.shape[-1]

        if self.W is None:
            W = np.eye(p)
        else:
            W = _as_float_array("W", self.W)
            if W.shape != (p, p):
                raise InvalidModelError(
                    f"W has shape {W.shape}; expected ({p}, {p}), the covariance of the {p} noise "
                    "inputs (columns of E)"
                )
        _check_psd("W", W[None], strict=False)

        P_in = _as_float_array("P_in", self.P_in)
        P_out = _as_float_array("P_out", self.P_out)
        _check_stochastic("P_in", P_in, N)
        _check_stochastic("P_out", P_out, N)

        G = _as_float_array("G", self.G)
        if G.ndim != 2 or G.shape[1] != n or G.shape[0] < 1:
            raise InvalidModelError(
                f"G has shape {G.shape}; expected (r, {n}) with r >= 1 rows of the region G x <= H"
            )
        r = G.shape[0]
        if np.any(np.all(G == 0.0, axis=1)):
            i = int(np.flatnonzero(np.all(G == 0.0, axis=1))[0])
            raise InvalidModelError(
                f"G row {i} is all zeros; every row of G must have a nonzero entry (a zero row "
                "is not a constraint on the state)"
            )
        H0 = _as_float_array("H0", self.H0)
        if H0.shape != (r,):
            raise InvalidModelError(
                f"H0 has shape {H0.shape}; expected ({r},), one entry per row of G"
            )
        if self.H_rate is None:
            H_rate = np.zeros(r)
        else:
            H_rate = _as_float_array("H_rate", self.H_rate)
            if H_rate.shape != (r,):
                raise InvalidModelError(
                    f"H_rate has shape {H_rate.shape}; expected ({r},), one entry per row of G"
                )

        Q = _per_mode("Q", _as_float_array("Q", self.Q), N, (n, n), "one n x n weight per mode")
        _check_psd("Q", Q, strict=False)
        R = _per_mode("R", _as_float_array("R", self.R), N, (m, m), "one m x m weight per mode")
        _check_psd("R", R, strict=True)

        x0 = _as_float_array("x0", self.x0)
        if x0.shape != (n,):
            raise InvalidModelError(f"x0 has shape {x0.shape}; expected ({n},)")

        mode0 = self.mode0
        if isinstance(mode0, (bool, np.bool_)):
            raise InvalidModelError(
                f"mode0 = {mode0!r}; expected an int in [0, {N}) or a probability vector"
            )
        if isinstance(mode0, (int, np.integer)):
            if not 0 <= int(mode0) < N:
                raise InvalidModelError(
                    f"mode0 = {int(mode0)} is out of range; expected an int in [0, {N}) "
                    "(modes are numbered from 0) or a probability vector of length N"
                )
            mode0 = int(mode0)
        else:
            mode0 = _as_float_array("mode0", mode0)
            if mode0.shape != (N,):
                raise InvalidModelError(
                    f"mode0 has shape {mode0.shape}; expected an int in [0, {N}) or a probability "
                    f"vector of shape ({N},)"
                )
            if np.any(mode0 < 0) or abs(mode0.sum() - 1.0) > _ROW_SUM_TOL:
                raise InvalidModelError(
                    f"mode0 = {_fmt(mode0)} is not a probability vector; entries must be >= 0 and "
                    f"sum to 1 (tolerance {_ROW_SUM_TOL:g})"
                )

        names = self.mode_names
        if names is None:
            names = tuple(f"mode {i}" for i in range(N))
        else:
            if (
                isinstance(names, str)
                or len(names) != N
                or not all(isinstance(s, str) for s in names)
            ):
                raise InvalidModelError(
                    f"mode_names = {names!r}; expected a sequence of {N} strings, one per mode"
                )
            names = tuple(names)

        for name, value in [
            ("A", A), ("B", B), ("E", E), ("W", W), ("P_in", P_in), ("P_out", P_out), ("G", G),
            ("H0", H0), ("H_rate", H_rate), ("Q", Q), ("R", R), ("x0", x0), ("mode0", mode0),
            ("mode_names", names),
        ]:  # fmt: skip
            put(name, value)

    # ------------------------------------------------------------------ sizes
    @property
    def N(self) -> int:
        """Number of modes."""
        return self.A.shape[0]

    @property
    def n(self) -> int:
        """Number of states."""
        return self.A.shape[1]

    @property
    def m(self) -> int:
        """Number of inputs."""
        return self.B.shape[2]

    @property
    def p(self) -> int:
        """Number of noise inputs (columns of E)."""
        return self.E.shape[2]

    @property
    def r(self) -> int:
        """Number of rows of the region ``G x <= H_k``."""
        return self.G.shape[0]

    @cached_property
    def W_sqrt(self) -> np.ndarray:
        """(p, p) symmetric square root of ``W``: ``W_sqrt @ W_sqrt.T == W``."""
        vals, vecs = np.linalg.eigh(self.W)
        out = (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ vecs.T
        out.setflags(write=False)
        return out

    @cached_property
    def noise_cov(self) -> np.ndarray:
        """(N, n, n) covariance ``E_i W E_i'`` of the additive noise in each mode."""
        out = self.E @ self.W @ self.E.transpose(0, 2, 1)
        out.setflags(write=False)
        return out

    # ------------------------------------------------------------------ batched dynamics
    def H(self, k: int | np.ndarray) -> np.ndarray:
        """Right-hand side ``H_k = H0 + k * H_rate``.

        Parameters
        ----------
        k : int or (...) int array

        Returns
        -------
        (..., r) array
        """
        k = np.asarray(k, dtype=np.float64)
        if k.ndim == 0:
            return self.H0 + k[..., None] * self.H_rate
        # the same arithmetic column by column: contiguous loops over the batch, not loops of
        # length r
        out = np.empty((*k.shape, self.r))
        for j in range(self.r):
            column = out[..., j]
            np.multiply(k, self.H_rate[j], out=column)
            column += self.H0[j]
        return out

    def constraint_values(self, x: np.ndarray, k: int | np.ndarray) -> np.ndarray:
        """``G x - H_k``: positive entries are violated rows.

        Parameters
        ----------
        x : (..., n)
        k : int or int array broadcastable to the batch shape

        Returns
        -------
        (..., r) array
        """
        x = np.asarray(x, dtype=np.float64)
        return x @ self.G.T - self.H(k)

    def in_region(self, x: np.ndarray, k: int | np.ndarray) -> np.ndarray:
        """Whether ``G x <= H_k`` holds in every row (``x`` in C1), eq. (eq:polyhedral).

        Returns
        -------
        (...) bool array (a numpy bool for a single state)
        """
        return max_last(self.constraint_values(x, k)) <= 0.0

    def transition_rows(
        self, x: np.ndarray, mode: int | np.ndarray, k: int | np.ndarray
    ) -> np.ndarray:
        """Row ``pi_{theta_k .}(x_k)`` of eq. (eq:p_tran): ``P_in[mode]`` in C1, ``P_out[mode]`` in C2.

        Returns
        -------
        (..., N) array of probabilities of the next mode
        """
        inside = self.in_region(x, k)
        mode = np.asarray(mode)
        return np.where(inside[..., None], self.P_in[mode], self.P_out[mode])

    def next_state(
        self, x: np.ndarray, mode: int | np.ndarray, u: np.ndarray, w: np.ndarray
    ) -> np.ndarray:
        """``A_theta x + B_theta u + E_theta w``, eq. (sys:djls_noise).

        Parameters
        ----------
        x : (..., n)
        mode : int or (...) int array
        u : (..., m)
        w : (..., p) noise sample (already scaled: ``w ~ N(0, W)``)

        Returns
        -------
        (..., n) array
        """
        z = _stack_last(x, u, w)
        return self._per_mode(self._tables["ABE_T"], self.n, mode, z)

    def next_mode(
        self,
        x: np.ndarray,
        mode: int | np.ndarray,
        k: int | np.ndarray,
        uniform: np.ndarray | float,
    ) -> np.ndarray:
        """The next mode, by inverse-CDF sampling of :meth:`transition_rows` with ``uniform``.

        Parameters
        ----------
        uniform : float or (...) array of draws from U[0, 1)

        Returns
        -------
        (...) int64 array (a 0-d array for a single state)
        """
        return self._draw_next_mode(self.in_region(x, k), mode, uniform)

    def sample_next_mode(
        self,
        x: np.ndarray,
        mode: int | np.ndarray,
        k: int | np.ndarray,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Draw ``theta_{k+1}`` from row ``pi_{theta_k .}(x_k)`` of eq. (eq:p_tran) with ``rng``.

        The same law as :meth:`next_mode`, which takes the uniforms instead (for replaying a
        trajectory); this draws one uniform per state with ``rng.random``.

        Parameters
        ----------
        x : (..., n)
        mode : int or (...) int array
        k : int or (...) int array
        rng : numpy.random.Generator

        Returns
        -------
        (...) int64 array (a 0-d array for a single state)
        """
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng = {rng!r:.80}; expected a numpy.random.Generator")
        inside = self.in_region(x, k)
        shape = np.broadcast_shapes(np.shape(inside), np.shape(mode))
        return self._draw_next_mode(inside, mode, rng.random(shape))

    def _draw_next_mode(
        self, inside: np.ndarray, mode: int | np.ndarray, uniform: np.ndarray | float
    ) -> np.ndarray:
        # draw_categorical with the normalized CDFs of P_in / P_out tabulated once
        inside, mode = np.asarray(inside, dtype=np.intp), np.asarray(mode)
        if inside.ndim == 0 and mode.ndim == 0:
            cdf = self._tables["cdf"][inside, mode]
        else:  # the same rows gathered with np.take (faster than fancy indexing on a batch)
            table = self._tables["cdf"]
            cdf = np.take(table.reshape(-1, self.N), inside * table.shape[1] + mode, axis=0)
        u = np.asarray(uniform, dtype=np.float64)
        count = np.zeros(np.broadcast_shapes(cdf.shape[:-1], u.shape), dtype=np.int64)
        for j in range(self.N - 1):  # the last CDF entry is exactly 1 > u: never counted
            count += cdf[..., j] <= u
        return count

    def sample_noise(
        self, rng: np.random.Generator, batch_shape: tuple[int, ...] = ()
    ) -> np.ndarray:
        """Draw ``w ~ N(0, W)`` of shape ``(*batch_shape, p)`` from ``rng``."""
        return rng.standard_normal((*batch_shape, self.p)) @ self.W_sqrt.T

    def sample_mode0(self, rng: np.random.Generator, size: int | None = None) -> int | np.ndarray:
        """The initial mode: ``mode0`` itself, or a draw from the probability vector ``mode0``.

        With ``size``, an int64 array of ``size`` initial modes.
        """
        if isinstance(self.mode0, int):
            return self.mode0 if size is None else np.full(size, self.mode0, dtype=np.int64)
        if size is None:
            return int(draw_categorical(self.mode0, rng.random()))
        return draw_categorical(self.mode0, rng.random(size))

    def step(
        self,
        x: np.ndarray,
        mode: int | np.ndarray,
        u: np.ndarray,
        k: int | np.ndarray,
        w: np.ndarray,
        uniform: np.ndarray | float,
        inside: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One transition ``(x_k, theta_k) -> (x_{k+1}, theta_{k+1})`` with given randomness.

        The next mode uses the region test on ``x_k`` at time ``k`` (eq. eq:p_tran). Deterministic
        given ``w`` and ``uniform``, so that callers can replay the same noise. ``inside``, the
        region test of ``x`` at ``k``, may be passed when the caller already has it.

        Returns
        -------
        x_next : (..., n)
        mode_next : (...) int64
        """
        if inside is None:
            inside = self.in_region(x, k)
        return self.next_state(x, mode, u, w), self._draw_next_mode(inside, mode, uniform)

    def stage_cost(self, x: np.ndarray, mode: int | np.ndarray, u: np.ndarray) -> np.ndarray:
        """``x' Q_theta x + u' R_theta u``; shape ``(...)``."""
        z = _stack_last(x, u)
        p = self._per_mode(self._tables["QR_T"], self.n + self.m, mode, z) * z
        if p.ndim < 2 or p.shape[-1] >= 8:  # from 8 terms numpy sums in 8 running accumulators
            return np.sum(p, axis=-1)
        out = p[..., 0].copy()  # the sum over the short last axis, in numpy's order, faster
        for j in range(1, p.shape[-1]):
            out += p[..., j]
        return out

    @cached_property
    def _tables(self) -> dict[str, Any]:
        """Per-mode matrices stacked for batched products (see :meth:`_per_mode`)."""
        N, n, m = self.N, self.n, self.m
        ABE = np.concatenate([self.A, self.B, self.E], axis=2)  # (N, n, n + m + p)
        QR = np.zeros((N, n + m, n + m))
        QR[:, :n, :n] = self.Q
        QR[:, n:, n:] = self.R
        cdf = np.stack([np.cumsum(self.P_out, axis=1), np.cumsum(self.P_in, axis=1)])
        return {
            "ABE": ABE,
            "ABE_T": ABE.reshape(N * n, -1).T.copy(),
            "QR": QR,
            "QR_T": QR.reshape(N * (n + m), n + m).T.copy(),
            "cdf": cdf / cdf[..., -1:],  # [inside, mode]: as in draw_categorical
        }

    def _per_mode(self, M_T: np.ndarray, rows: int, mode: Any, z: np.ndarray) -> np.ndarray:
        """``M[mode] @ z`` over a batch, with ``M_T = M.reshape(N * rows, d).T`` (one BLAS product).

        Computing all N products and keeping one is faster than gathering (B, rows, d) matrices.
        """
        batch = z.shape[:-1]
        z2 = z.reshape(-1, z.shape[-1])
        mode2 = np.broadcast_to(np.asarray(mode), batch).reshape(-1)
        size = z2.shape[0]
        # row mode2[b] of the (N, rows) block of b: np.take is much faster than fancy indexing
        y = np.take(
            (z2 @ M_T).reshape(size * self.N, rows),
            np.arange(0, size * self.N, self.N) + mode2,
            axis=0,
        )
        return y.reshape(*batch, rows)

    # ------------------------------------------------------------------ one state, fast
    @cached_property
    def _one(self) -> dict[str, Any]:
        """Precomputed data of the unbatched hot path (:meth:`step_one` and friends)."""
        t = self._tables
        ABE = t["ABE"]
        return {
            # [x_next; G x_next] = [ABE; G ABE] [x; u; w]: one product gives both
            "M": list(np.concatenate([ABE, self.G @ ABE], axis=1)),
            "QR": list(t["QR"]),  # blkdiag(Q_i, R_i)
            "n": self.n,
            "n+m": self.n + self.m,
            "cdf": {True: t["cdf"][1].tolist(), False: t["cdf"][0].tolist()},
            "W_identity": bool(np.array_equal(self.W, np.eye(self.p))),
            "H": {},  # k -> H_k, filled on demand
        }

    def sample_noise_one(self, rng: np.random.Generator) -> np.ndarray:
        """One draw ``w ~ N(0, W)`` of shape ``(p,)``; the same law as :meth:`sample_noise`."""
        z = rng.standard_normal(self.p)
        return z if self._one["W_identity"] else self.W_sqrt @ z

    def step_one(
        self,
        x: np.ndarray,
        mode: int,
        u: np.ndarray,
        k: int,
        w: np.ndarray,
        uniform: float,
        inside: bool | None = None,
    ) -> tuple[np.ndarray, int, float, np.ndarray]:
        """:meth:`step` for one state (``x`` (n,), ``u`` (m,), ``w`` (p,) float64), with few numpy calls.

        The single environment's hot path. Same math as :meth:`step` and :meth:`stage_cost`
        (the tests check that they agree): ``x' = [A B E]_theta [x; u; w]``, the next mode by
        inverse CDF of the transition row chosen by the region test on ``x`` at time ``k``
        (pass ``inside`` when it is already known, to skip the test).

        Returns
        -------
        x_next : (n,)
        mode_next : int
        stage_cost : float, ``x' Q_theta x + u' R_theta u``
        constraint_values : (r,), ``G x_next - H_{k+1}``
        """
        one = self._one
        n = one["n"]
        z = np.concatenate((x, u, w))
        y = one["M"][mode] @ z  # [x_next; G x_next]
        zxu = z[: one["n+m"]]
        stage_cost = float(zxu @ one["QR"][mode] @ zxu)
        if inside is None:
            inside = max(self.constraint_values_one(x, k).tolist()) <= 0.0
        mode_next = bisect.bisect_right(one["cdf"][inside][mode], uniform)
        return y[:n], mode_next, stage_cost, y[n:] - self._H_one(k + 1)

    def _H_one(self, k: int) -> np.ndarray:
        cache = self._one["H"]
        H = cache.get(k)
        if H is None:
            H = cache[k] = self.H0 + k * self.H_rate
        return H

    def constraint_values_one(self, x: np.ndarray, k: int) -> np.ndarray:
        """:meth:`constraint_values` ``G x - H_k`` (r,) for one float64 state ``x`` (n,)."""
        return self.G @ x - self._H_one(k)

    # ------------------------------------------------------------------ (de)serialization
    def to_dict(self) -> dict[str, Any]:
        """A JSON/TOML-friendly dict of plain lists and numbers; inverse of :meth:`from_dict`."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                value = value.tolist()
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SDJLSModel:
        """Build a model from a dict such as one read from JSON or TOML.

        Raises
        ------
        InvalidModelError
            Unknown or missing fields, or any validation failure (the message names the field).
        """
        if not isinstance(data, dict):
            raise InvalidModelError(
                f"a model description must be a dict/table, got {type(data).__name__}"
            )
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise InvalidModelError(f"unknown model field(s) {unknown}; known fields are {names}")
        required = [f.name for f in fields(cls) if f.default is MISSING]
        missing = [name for name in required if name not in data]
        if missing:
            raise InvalidModelError(
                f"missing model field(s) {missing}; required fields are {required}"
            )
        return cls(**data)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, SDJLSModel):
            return NotImplemented
        a, b = self.to_dict(), other.to_dict()
        return a.keys() == b.keys() and all(
            np.array_equal(np.asarray(a[key], dtype=object), np.asarray(b[key], dtype=object))
            for key in a
        )

    __hash__ = None  # type: ignore[assignment]  # mutable-looking arrays: not hashable

    def __setstate__(self, state: dict[str, Any]) -> None:
        # pickle and copy.deepcopy restore arrays writable: make them read-only again
        for value in state.values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
        self.__dict__.update(state)

    def __repr__(self) -> str:
        return (
            f"SDJLSModel(N={self.N}, n={self.n}, m={self.m}, p={self.p}, r={self.r}, "
            f"mode_names={self.mode_names})"
        )


def load_model(path: str | Path) -> SDJLSModel:
    """Read a model from a ``.json`` or ``.toml`` file (see :meth:`SDJLSModel.to_dict`).

    Raises
    ------
    InvalidModelError
        If the file cannot be parsed or a field is missing or malformed.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".json", ".toml"):
        raise InvalidModelError(f"model file {str(path)!r} must end in .json or .toml")
    try:
        text = path.read_text(encoding="utf-8")
        if suffix == ".toml":
            try:
                import tomllib
            except ModuleNotFoundError:  # Python 3.10
                import tomli as tomllib  # type: ignore[no-redef]
            data = tomllib.loads(text)
        else:
            data = json.loads(text)
    except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError, TOMLDecodeError
        raise InvalidModelError(
            f"model file {str(path)!r} is not valid UTF-8 {suffix[1:].upper()}: {exc}"
        ) from None
    if not isinstance(data, dict):
        raise InvalidModelError(
            f"model file {str(path)!r} holds a {type(data).__name__}; expected a table/object "
            "of model fields (A, B, P_in, ...)"
        )
    try:
        return SDJLSModel.from_dict(data)
    except InvalidModelError as exc:
        raise InvalidModelError(f"model file {str(path)!r}: {exc}") from None


def save_model(model: SDJLSModel, path: str | Path) -> None:
    """Write ``model`` as JSON (``.json``) or TOML (``.toml``) readable by :func:`load_model`."""
    path = Path(path)
    data = model.to_dict()
    if path.suffix.lower() == ".json":
        path.write_text(json.dumps(data, indent=2) + "\n")
    elif path.suffix.lower() == ".toml":
        path.write_text(_to_toml(data))
    else:
        raise ValueError(f"path {str(path)!r} must end in .json or .toml")


def _to_toml(data: dict[str, Any]) -> str:
    """Minimal TOML writer for the flat dict of nested number lists that ``to_dict`` returns."""

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int):
            return str(v)
        if isinstance(v, float):
            if not math.isfinite(v):
                raise ValueError(f"cannot write non-finite number {v} to TOML")
            return repr(v)
        if isinstance(v, str):  # a TOML basic string: JSON's escapes, raw non-ASCII
            return json.dumps(v, ensure_ascii=False)
        if isinstance(v, list):
            return "[" + ", ".join(value(item) for item in v) + "]"
        raise TypeError(f"cannot write {type(v).__name__} to TOML")

    lines = [f"{key} = {value(v)}" for key, v in data.items() if v is not None]
    return "\n".join(lines) + "\n"
