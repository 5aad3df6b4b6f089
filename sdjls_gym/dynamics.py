"""The dynamics of a state-dependent jump linear system, as pure functions of its matrices.

Section 2 of the paper (eq. sys:djls_noise, eq:p_tran, eq:polyhedral)::

    x_{k+1} = A_{theta_k} x_k + B_{theta_k} u_k + E_{theta_k} w_k,      w_k ~ N(0, W)
    Pr{theta_{k+1} = j | theta_k = i, x_k} = P_in[i, j]   if G x_k <= H_k   (x_k in C1)
                                           = P_out[i, j]  otherwise         (x_k in C2)
    H_k = H0 + k * H_rate

:class:`Dynamics` holds a model's validated matrices, arranged once for the products
(``SDJLSModel.dynamics``). Its methods are the one implementation of these equations: the
model's methods, both environments (through :mod:`sdjls_gym.functional`) and the controllers
call them. Every method that takes a state accepts a leading batch axis: ``x`` may be ``(n,)``
or ``(..., n)``, ``mode`` an int or an integer array of the matching batch shape, and ``k`` an
int or an integer array broadcastable against the batch.

:meth:`Dynamics.transition` is the whole step (next state and mode, stage cost, constraint
values of the next state). For one state given with Python ints it takes a path with few numpy
calls, the single environment's hot path (a batched call costs some 20 times more for one
row): the same formulas, whose products BLAS may sum in another order, so the two paths agree
to rounding (``tests/test_batched.py`` compares them), and each keeps its own numbers.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray

from sdjls_gym import exact
from sdjls_gym.messages import describe
from sdjls_gym.validation import MAX_INDEX, check_int, check_int_array

__all__ = [
    "BatchTransition",
    "Dynamics",
    "OneTransition",
    "Sizes",
    "Transition",
    "check_time",
    "draw_categorical",
    "max_last",
    "stack_last",
]

#: Entries of the cache of ``H_k`` kept by the one-state path before it is emptied.
H_CACHE_SIZE = 4096


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


def stack_last(*arrays: Any) -> np.ndarray:
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


def check_time(k: Any) -> Any:
    """``k`` as given when it is an int or an integer array in ``[0, 2**53]``; else an error.

    Raises
    ------
    TypeError
        ``k`` is not an int or an integer array (a float, a bool, ...).
    ValueError
        ``k`` is negative or above ``2**53`` (checked on the exact integer).
    """
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


#: What :meth:`Dynamics.transition` returns, one step from ``(x_k, theta_k)`` under ``u_k``:
#: ``(x, mode, stage_cost, constraint_values)`` = ``x_{k+1}`` (..., n), ``theta_{k+1}`` (...),
#: ``x_k' Q x_k + u_k' R u_k`` (...) and ``G x_{k+1} - H_{k+1}`` (..., r); for one state an int
#: mode and a float cost. A plain tuple: on the single environment's hot path a named tuple
#: costs a measurable share of a step.
Transition = tuple[np.ndarray, Any, Any, np.ndarray]
#: :data:`Transition` of one state: ``x`` (n,), an int mode, a float cost, values (r,).
OneTransition = tuple[NDArray[np.float64], int, float, NDArray[np.float64]]
#: :data:`Transition` of a batch: ``x`` (..., n), modes (...), costs (...), values (..., r).
BatchTransition = tuple[
    NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]
]


def _size(matrix: str, axis: int, doc: str) -> cached_property[int]:
    """A cached size of a system: ``<matrix>.shape[axis]``, documented by ``doc``."""

    def size(self: Any) -> int:
        return getattr(self, matrix).shape[axis]

    size.__doc__ = doc
    return cached_property(size)


class Sizes:
    """The sizes of a system, read from its matrices ``A`` (N, n, n), ``B`` (N, n, m), ``E``
    (N, n, p) and ``G`` (r, n): a base of :class:`Dynamics` and of the model. Cached: they are
    read on every step."""

    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    G: np.ndarray

    N = _size("A", 0, "Number of modes.")
    n = _size("A", 1, "Number of states.")
    m = _size("B", 2, "Number of inputs.")
    p = _size("E", 2, "Number of noise inputs (columns of E).")
    r = _size("G", 0, "Number of rows of the region ``G x <= H_k``.")


@dataclass(frozen=True, eq=False)
class Dynamics(Sizes):
    """A model's validated matrices with the functions of its dynamics (see the module).

    Built by :class:`~sdjls_gym.SDJLSModel` from its fields (``model.dynamics``); every array has
    its mode axis. Derived tables are computed once, on first use. Thread-safe: the only state
    it changes is a cache of ``H_k`` for the one-state path, whose entries never change.
    """

    A: np.ndarray  # (N, n, n)
    B: np.ndarray  # (N, n, m)
    E: np.ndarray  # (N, n, p)
    W: np.ndarray  # (p, p)
    P_in: np.ndarray  # (N, N)
    P_out: np.ndarray  # (N, N)
    G: np.ndarray  # (r, n)
    H0: np.ndarray  # (r,)
    H_rate: np.ndarray  # (r,)
    Q: np.ndarray  # (N, n, n)
    R: np.ndarray  # (N, m, m)

    # ------------------------------------------------------------------ tables
    @cached_property
    def W_sqrt(self) -> np.ndarray:
        """(p, p) symmetric square root of ``W``: ``W_sqrt @ W_sqrt.T == W``."""
        vals, vecs = np.linalg.eigh(self.W)
        out = (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ vecs.T
        out.setflags(write=False)
        return out

    @cached_property
    def ABE(self) -> np.ndarray:
        """(N, n, n + m + p): ``[A_i B_i E_i]``, so that ``x' = ABE[mode] @ [x; u; w]``."""
        return np.concatenate([self.A, self.B, self.E], axis=2)

    @cached_property
    def QR(self) -> np.ndarray:
        """(N, n + m, n + m): ``blkdiag(Q_i, R_i)``, so that the stage cost is ``z' QR[mode] z``
        for ``z = [x; u]``."""
        N, n, m = self.N, self.n, self.m
        QR = np.zeros((N, n + m, n + m))
        QR[:, :n, :n] = self.Q
        QR[:, n:, n:] = self.R
        return QR

    @cached_property
    def _batched(self) -> dict[str, Any]:
        """Per-mode matrices stacked for batched products (see :meth:`_per_mode`), and the
        normalized CDFs of the transition rows."""
        N, n, m = self.N, self.n, self.m
        cdf = np.stack([np.cumsum(self.P_out, axis=1), np.cumsum(self.P_in, axis=1)])
        return {
            "ABE_T": self.ABE.reshape(N * n, -1).T.copy(),
            "QR_T": self.QR.reshape(N * (n + m), n + m).T.copy(),
            "cdf": cdf / cdf[..., -1:],  # [inside, mode]: as in draw_categorical
        }

    @cached_property
    def _one(self) -> dict[str, Any]:
        """The same tables as Python lists and per-mode arrays, for the one-state path."""
        return {
            # [x_next; G x_next] = [ABE; G ABE] [x; u; w]: one product gives both
            "M": list(np.concatenate([self.ABE, self.G @ self.ABE], axis=1)),
            "QR": list(self.QR),
            "n": self.n,
            "n+m": self.n + self.m,
            "cdf": {
                True: self._batched["cdf"][1].tolist(),
                False: self._batched["cdf"][0].tolist(),
            },
            "W_identity": bool(np.array_equal(self.W, np.eye(self.p))),
            "G": self.G.tolist(),
            "G_abs_sum": np.abs(self.G).sum(axis=1).tolist(),
            "H": {},  # k -> H_k, filled on demand
        }

    # ------------------------------------------------------------------ region
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
        TypeError, ValueError
            ``k`` is not a time index (see :func:`check_time`).
        """
        k = np.asarray(check_time(k), dtype=np.float64)
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

    def H_one(self, k: int) -> np.ndarray:
        """:meth:`H` for one time index ``k``, cached (the one-state path)."""
        if type(k) is not int:  # a float 2.0 would hit the cache entry of 2
            k = check_int("k", k, low=0)
        cache = self._one["H"]
        H = cache.get(k)
        if H is None:  # the range is checked once per distinct k; the cache stays bounded
            check_int("k", k, low=0)
            if len(cache) >= H_CACHE_SIZE:
                cache.clear()
            H = cache[k] = self.H0 + k * self.H_rate
        return H

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

    def constraint_values_one(self, x: np.ndarray, k: int) -> np.ndarray:
        """:meth:`constraint_values` ``G x - H_k`` (r,) for one float64 state ``x`` (n,)."""
        return self.G @ x - self.H_one(k)

    def in_region(self, x: np.ndarray, k: int | np.ndarray) -> np.ndarray:
        """Whether ``G x <= H_k`` holds in every row (``x`` in C1), eq. (eq:polyhedral), decided
        exactly for the float64 data (``H_k`` as :meth:`H` computes it): a row whose value is
        within round-off of 0 is evaluated in rational arithmetic, so the answer does not
        depend on how the product was summed (a state alone and in a batch agree).

        Returns
        -------
        (...) bool array (a numpy bool for a single state)
        """
        x = np.asarray(x, dtype=np.float64)
        H = self.H(k)
        values = x @ self.G.T - H
        # the round-off of a row's value: at most (n + 1) ulps of its terms, which are at most
        # sum|G_i| max|x| + |H_i| (and n subnormal units where the products underflow)
        xmax = np.max(np.abs(x), axis=-1, initial=0.0)[..., None]
        tie = np.abs(values) <= self._tie_scale * (self._G_abs_sum * xmax + np.abs(H)) + 1e-300
        if tie.any():
            self._exact_ties(x, H, values, tie)
        return max_last(values) <= 0.0

    def _exact_ties(self, x: np.ndarray, H: np.ndarray, values: np.ndarray,
                    tie: np.ndarray) -> None:  # fmt: skip
        """Replace the tied rows' ``values`` by their exact sign (:func:`exact.row_sign`), once
        per distinct ``(row, state, H)`` (a batch started from one state ties in every env)."""
        index = np.nonzero(tie)
        xs = np.broadcast_to(x[..., None, :], (*values.shape, self.n))[index]  # (ties, n)
        hs = np.broadcast_to(H, values.shape)[index]
        keys = np.column_stack([index[-1].astype(np.float64), xs, hs])
        ok = np.all(np.isfinite(keys), axis=1)
        distinct, inverse = np.unique(keys[ok], axis=0, return_inverse=True)
        G = self.G.tolist()
        signs = np.array([exact.row_sign(G[int(r[0])], r[1:-1].tolist(), float(r[-1]))
                          for r in distinct], dtype=np.float64)  # fmt: skip
        if signs.size:
            values[tuple(i[ok] for i in index)] = signs[inverse.reshape(-1)]

    def in_region_one(self, x: np.ndarray, k: int) -> bool:
        """:meth:`in_region` for one float64 state ``x`` (n,) and an int ``k``: the same exact
        decision, in plain floats, as a Python bool (the controllers' one-state path)."""
        H = self.H_one(k)
        values = (self.G @ x - H).tolist()
        xmax = max(map(abs, x.tolist()), default=0.0)
        scale, sums = self._tie_scale, self._one["G_abs_sum"]
        inside = True
        for j, (v, h, a) in enumerate(zip(values, H.tolist(), sums, strict=True)):
            if abs(v) <= scale * (a * xmax + abs(h)) + 1e-300 and math.isfinite(xmax):
                v = exact.row_sign(self._one["G"][j], x.tolist(), h)
            if not v <= 0.0:
                inside = False
        return inside

    @cached_property
    def _G_abs_sum(self) -> np.ndarray:
        return np.abs(self.G).sum(axis=1)

    @cached_property
    def _tie_scale(self) -> float:
        return (self.n + 2) * float(np.finfo(np.float64).eps)

    # ------------------------------------------------------------------ modes
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
        x : (..., n)
        mode : int or (...) int array
        k : int or (...) int array
        uniform : float or (...) array of draws from U[0, 1)

        Returns
        -------
        (...) int64 array (a 0-d array for a single state)
        """
        return self.draw_next_mode(self.in_region(x, k), mode, uniform)

    def sample_next_mode(
        self,
        x: np.ndarray,
        mode: int | np.ndarray,
        k: int | np.ndarray,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Draw ``theta_{k+1}`` from row ``pi_{theta_k .}(x_k)`` of eq. (eq:p_tran) with ``rng``, a
        :class:`numpy.random.Generator`: :meth:`next_mode` (the same arguments and answer) with
        one uniform per state drawn by ``rng.random``; :meth:`next_mode` itself takes the
        uniforms, for replaying a trajectory."""
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng = {rng!r:.80}; expected a numpy.random.Generator")
        inside = self.in_region(x, k)
        shape = np.broadcast_shapes(np.shape(inside), np.shape(mode))
        return self.draw_next_mode(inside, mode, rng.random(shape))

    def draw_next_mode(
        self, inside: Any, mode: int | np.ndarray, uniform: np.ndarray | float
    ) -> np.ndarray:
        """The next mode by inverse CDF of row ``mode`` of ``P_in`` (``inside``) or ``P_out``.

        :func:`draw_categorical` with the normalized CDFs tabulated once.
        """
        inside, mode = np.asarray(inside, dtype=np.intp), np.asarray(mode)
        table = self._batched["cdf"]
        if inside.ndim == 0 and mode.ndim == 0:
            cdf = table[inside, mode]
        else:  # the same rows gathered with np.take (faster than fancy indexing on a batch)
            cdf = np.take(table.reshape(-1, self.N), inside * table.shape[1] + mode, axis=0)
        u = np.asarray(uniform, dtype=np.float64)
        count = np.zeros(np.broadcast_shapes(cdf.shape[:-1], u.shape), dtype=np.int64)
        for j in range(self.N - 1):  # the last CDF entry is exactly 1 > u: never counted
            count += cdf[..., j] <= u
        return count

    # ------------------------------------------------------------------ states and costs
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
        z = stack_last(x, u, w)
        return self._per_mode(self._batched["ABE_T"], self.n, mode, z)

    def stage_cost(self, x: np.ndarray, mode: int | np.ndarray, u: np.ndarray) -> np.ndarray:
        """``x' Q_theta x + u' R_theta u``; shape ``(...)``."""
        z = stack_last(x, u)
        p = self._per_mode(self._batched["QR_T"], self.n + self.m, mode, z) * z
        if p.ndim < 2 or p.shape[-1] >= 8:  # from 8 terms numpy sums in 8 running accumulators
            return np.sum(p, axis=-1)
        out = p[..., 0].copy()  # the sum over the short last axis, in numpy's order, faster
        for j in range(1, p.shape[-1]):
            out += p[..., j]
        return out

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

    def sample_noise(
        self, rng: np.random.Generator, batch_shape: tuple[int, ...] = ()
    ) -> np.ndarray:
        """``w ~ N(0, W)`` of shape ``(*batch_shape, p)``: ``W_sqrt`` times standard normal draws
        taken from ``rng`` (for one state, ``batch_shape == ()``, with a matrix-vector product)."""
        if batch_shape == ():
            z = rng.standard_normal(self.p)
            return z if self._one["W_identity"] else self.W_sqrt @ z
        return rng.standard_normal((*batch_shape, self.p)) @ self.W_sqrt.T

    # ------------------------------------------------------------------ one step
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
        return self.next_state(x, mode, u, w), self.draw_next_mode(inside, mode, uniform)

    @overload
    def transition(
        self,
        x: np.ndarray,
        mode: int,
        u: np.ndarray,
        k: int,
        w: np.ndarray,
        uniform: float,
        inside: bool | None = None,
    ) -> OneTransition: ...
    @overload
    def transition(
        self,
        x: np.ndarray,
        mode: np.ndarray | np.integer[Any],
        u: np.ndarray,
        k: int | np.ndarray,
        w: np.ndarray,
        uniform: float | np.ndarray,
        inside: np.ndarray | None = None,
    ) -> BatchTransition: ...
    def transition(  # the arguments of either overload; dispatched on type(mode)
        self,
        x: np.ndarray,
        mode: Any,
        u: np.ndarray,
        k: Any,
        w: np.ndarray,
        uniform: Any,
        inside: Any = None,
    ) -> Transition:
        """The whole step with given randomness: :meth:`step`, the :meth:`stage_cost` of
        ``(x_k, u_k)`` and the :meth:`constraint_values` of ``x_{k+1}`` at ``k + 1``.

        Both environments take their steps here (through :func:`sdjls_gym.functional.step`).
        For one state (``mode`` and ``k`` Python ints, ``x`` (n,), ``u`` (m,), ``w`` (p,) float64
        arrays, ``uniform`` a float, ``inside`` a bool or None) it takes the one-state path:
        ``[x'; G x'] = [ABE; G ABE]_theta [x; u; w]`` in one product and the next mode by
        bisection of the CDF row, with few numpy calls.

        Returns
        -------
        Transition
            ``(x, mode, stage_cost, constraint_values)``: ``(..., n)``, ``(...)`` int,
            ``(...)`` float, ``(..., r)`` (an int and a float for one state).
        """
        if type(mode) is not int:
            x_next, modes_next = self.step(x, mode, u, k, w, uniform, inside)
            k_next = np.asarray(check_time(k)) + 1
            return (
                x_next,
                modes_next,
                self.stage_cost(x, mode, u),
                self.constraint_values(x_next, k_next),
            )
        one = self._one
        n = one["n"]
        z = np.concatenate((x, u, w))
        y = one["M"][mode] @ z  # [x_next; G x_next]
        zxu = z[: one["n+m"]]
        stage_cost = float(zxu @ one["QR"][mode] @ zxu)
        if inside is None:
            inside = max(self.constraint_values_one(x, k).tolist()) <= 0.0
        mode_next = bisect.bisect_right(one["cdf"][inside][mode], uniform)
        return y[:n], mode_next, stage_cost, y[n:] - self.H_one(k + 1)

    def exact_transition(
        self, x: np.ndarray, mode: int, u: np.ndarray, k: int, w: np.ndarray
    ) -> tuple[np.ndarray, float, np.ndarray]:
        """:meth:`transition`'s next state, stage cost and ``G x_next - H_{k+1}`` for one state,
        each the exact value of its formula rounded once to float64 (beyond float64's range:
        +-inf, never NaN): the answer of both environments to a step that overflows float64
        (see :func:`sdjls_gym.exact.exact_transition`). The next mode is not computed: it does
        not overflow."""
        return exact.exact_transition(
            self.ABE[mode], self.QR[mode], self.G, self.H_one(k + 1), x, u, w
        )
