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
import math
from dataclasses import MISSING, dataclass, field, fields
from fractions import Fraction
from functools import cached_property
from typing import Any

import numpy as np

from sdjls_gym._model_checks import (  # noqa: F401 - _fmt, _check_psd: used by the controllers
    InvalidModelError,
    InvalidModelTypeError,
    _check_psd,
    _fmt,
    validate_fields,
)
from sdjls_gym._validate import MAX_INDEX, check_int, check_int_array, describe

__all__ = [
    "SDJLSModel",
    "InvalidModelError",
    "InvalidModelTypeError",
    "draw_categorical",
    "max_last",
]

#: Entries of the cache of ``H_k`` kept by the one-state fast path before it is emptied.
_H_CACHE_SIZE = 4096


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


@dataclass(frozen=True, eq=False)
class SDJLSModel:
    """A discrete-time state-dependent jump linear system with a polyhedral region.

    Shapes use N modes, n states, m inputs, p noise inputs and r constraint rows. The per-mode
    matrices ``A``, ``B``, ``E``, ``Q`` and ``R`` may also be given without the leading mode
    axis, in which case the same matrix is used in every mode (with ``A`` of shape ``(n, n)``,
    N is the size of ``P_in``). Arrays are copied and made read-only.

    Parameters
    ----------
    A : (N, n, n) or (n, n)
        State matrices ``A_i``.
    B : (N, n, m) or (n, m)
        Input matrices ``B_i``.
    P_in : (N, N)
        Transition matrix lambda, used when ``G x_k <= H_k`` holds row-wise (``x_k`` in C1).
    P_out : (N, N)
        Transition matrix mu, used otherwise (``x_k`` in C2).
    G : (r, n)
        Rows of the region ``C1 = {x : G x <= H_k}``.
    H0 : (r,)
        Right-hand side at ``k = 0``.
    Q : (N, n, n) or (n, n)
        State weights of the stage cost, symmetric positive semidefinite.
    R : (N, m, m) or (m, m)
        Input weights of the stage cost, symmetric positive definite.
    x0 : (n,)
        Initial state.
    E : (N, n, p) or (n, p), optional
        Noise input matrices; identity ``(n, n)`` per mode by default (then ``p = n``).
    W : (p, p), optional
        Covariance of ``w_k``; identity by default.
    H_rate : (r,), optional
        Drift of the right-hand side, ``H_k = H0 + k * H_rate``; zeros by default.
    mode0 : int or (N,) array
        Initial mode ``0 <= mode0 < N``, or a probability vector to draw it from.
    mode_names : list or tuple of N str, optional
        Human-readable names of the modes (``"mode 0"``, ... by default).
    state_names : list or tuple of n str, optional
        Human-readable names of the states ``x(1) .. x(n)``; None (the default) when not given.

    Symmetry, positive (semi)definiteness and the row sums are checked with tolerances
    relative to each matrix's largest entry, so scaling a weight by any positive factor does
    not change the verdict.

    Raises
    ------
    InvalidModelError
        (a :class:`ValueError`) naming the field, the bad value and what is expected.
    InvalidModelTypeError
        (an :class:`InvalidModelError` and a :class:`TypeError`) when a field has the wrong type,
        e.g. a string or None where numbers belong, or names given as a generator.

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
    state_names: tuple[str, ...] | None = field(default=None)

    # ------------------------------------------------------------------ validation
    def __post_init__(self) -> None:
        raw = {f.name: getattr(self, f.name) for f in fields(self)}
        for name, value in validate_fields(raw).items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)

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
            Time indices, ``0 <= k <= 2**53``.

        Returns
        -------
        (..., r) array

        Raises
        ------
        TypeError
            ``k`` is not an int or an integer array (a float, a bool, ...).
        ValueError
            ``k`` is negative or above ``2**53`` (checked on the exact integer).
        """
        k = np.asarray(_check_k(k), dtype=np.float64)
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

    def exact_step_one(
        self, x: np.ndarray, mode: int, u: np.ndarray, k: int, w: np.ndarray
    ) -> tuple[np.ndarray, float, np.ndarray]:
        """:meth:`step_one`'s next state, stage cost and ``G x_next - H_{k+1}``, each the exact
        value of its formula rounded once to float64 (beyond float64's range: +-inf, never NaN).

        The answer of a step that overflows float64 from a finite ``x``, ``u``, ``w``: in
        floating point such a step gives ``inf - inf = NaN``, or an infinity whose sign depends
        on the order of the sums, which differs between :meth:`step_one` and the batched
        :meth:`step`. Both environments call this on such a step (rational arithmetic: slow,
        and only then). The next mode is not computed: it does not overflow.
        """
        z = [Fraction(v) for v in np.concatenate((x, u, w)).tolist()]
        x_next = [sum(map(_times, row, z)) for row in self._tables["ABE"][mode].tolist()]
        zxu = z[: self.n + self.m]
        qr = self._tables["QR"][mode].tolist()
        cost = sum(a * sum(map(_times, row, zxu)) for a, row in zip(zxu, qr, strict=True))
        H = self._H_one(k + 1).tolist()
        values = [
            sum(map(_times, row, x_next)) - Fraction(h)
            for row, h in zip(self.G.tolist(), H, strict=True)
        ]
        return (
            np.array(list(map(_rounded, x_next))),
            _rounded(cost),
            np.array(list(map(_rounded, values))),
        )

    def _H_one(self, k: int) -> np.ndarray:
        if type(k) is not int:  # a float 2.0 would hit the cache entry of 2
            k = check_int("k", k, low=0)
        cache = self._one["H"]
        H = cache.get(k)
        if H is None:  # the range is checked once per distinct k; the cache stays bounded
            check_int("k", k, low=0)
            if len(cache) >= _H_CACHE_SIZE:
                cache.clear()
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
        InvalidModelTypeError
            ``data`` is not a dict, or a field has the wrong type.
        """
        if not isinstance(data, dict):
            raise InvalidModelTypeError(
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
        names = "" if self.state_names is None else f", state_names={self.state_names}"
        return (
            f"SDJLSModel(N={self.N}, n={self.n}, m={self.m}, p={self.p}, r={self.r}, "
            f"mode_names={self.mode_names}{names})"
        )


def _times(a: float, b: Fraction) -> Fraction:
    return Fraction(a) * b


def _rounded(q: Fraction) -> float:
    """``q`` rounded to the nearest float64 (Python's int division is correctly rounded), or
    +-inf beyond float64's range."""
    try:
        return float(q)
    except OverflowError:
        return math.inf if q > 0 else -math.inf


def _check_k(k: Any) -> Any:
    """``k`` as given when it is an int or an integer array in ``[0, 2**53]``; else an error."""
    if type(k) is int and 0 <= k <= MAX_INDEX:  # the common case, first
        return k
    if isinstance(k, (list, tuple, range)):
        return check_int_array("k", k, low=0)  # a bool entry is refused, not read as 0 or 1
    if isinstance(k, np.ndarray) and k.ndim:
        if k.size and k.dtype.kind not in "iu":
            raise TypeError(
                f"k = {describe(k)} has dtype {k.dtype}; expected an int or an integer array of "
                "time indices"
            )
        if k.size:
            for bad in (int(k.min()), int(k.max())):  # exact, before any conversion
                check_int("k", bad, low=0)
        return k
    return check_int("k", k, low=0)


def __getattr__(name: str) -> Any:
    # load_model and save_model live in sdjls_gym.model_files; imported lazily (no cycle)
    if name in ("load_model", "save_model"):
        from sdjls_gym import model_files

        return getattr(model_files, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
