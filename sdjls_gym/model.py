"""The state-dependent jump linear system (SDJLS): the model record.

The model is the one of section 2 of the paper (eq. sys:djls_noise, eq:p_tran, eq:polyhedral)::

    x_{k+1} = A_{theta_k} x_k + B_{theta_k} u_k + E_{theta_k} w_k,      w_k ~ N(0, W)
    Pr{theta_{k+1} = j | theta_k = i, x_k} = P_in[i, j]   if G x_k <= H_k   (x_k in C1)
                                           = P_out[i, j]  otherwise         (x_k in C2)
    H_k = H0 + k * H_rate

Modes are numbered ``0 .. N-1`` (the paper numbers them ``1 .. N``).

:class:`SDJLSModel` holds the validated fields (checked by :mod:`sdjls_gym.model_checks`) and
turns them into and from plain dicts. Its dynamics methods (``H``, ``constraint_values``,
``in_region``, ``transition_rows``, ``next_state``, ``next_mode``, ``step``, ``stage_cost``,
``sample_noise``, ``transition``, ...) hand over to :class:`~sdjls_gym.dynamics.Dynamics`
(``model.dynamics``), the one implementation of the equations above. Every method that takes a
state accepts a leading batch axis: ``x`` may be ``(n,)`` or ``(..., n)``, ``mode`` an int or
an integer array of the matching batch shape, and ``k`` an int or an integer array
broadcastable against the batch.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from functools import cached_property
from typing import Any, Concatenate, ParamSpec, TypeVar, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sdjls_gym.dynamics import Dynamics, Sizes, draw_categorical
from sdjls_gym.errors import InvalidModelError, InvalidModelTypeError
from sdjls_gym.messages import a_type, describe
from sdjls_gym.model_checks import validate_fields

__all__ = ["SDJLSModel"]

_P = ParamSpec("_P")
_R = TypeVar("_R")


def _handed_over(
    method: Callable[Concatenate[Dynamics, _P], _R],
) -> Callable[Concatenate[SDJLSModel, _P], _R]:
    """The model's method of ``method``'s name: ``model.dynamics``'s, with its signature and
    docstring (for ``help()``, ``inspect.signature`` and type checkers, overloads included)."""
    name = method.__name__

    @functools.wraps(method)
    def hand_over(self: SDJLSModel, /, *args: _P.args, **kwargs: _P.kwargs) -> _R:
        return getattr(self.dynamics, name)(*args, **kwargs)

    hand_over.__qualname__ = f"SDJLSModel.{name}"
    return hand_over


@dataclass(frozen=True, eq=False)
class SDJLSModel(Sizes):
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
        Human-readable names of the modes (``"mode 0"``, ... by default). Names are labels:
        printable text, without control characters (tab, newline, DEL, U+0080-U+009F, ...) or
        lone surrogates, so that every name round-trips through ``save_model`` / ``load_model``.
    state_names : list or tuple of n str, optional
        Human-readable names of the states ``x(1) .. x(n)`` (the same rule); None (the
        default) when not given.

    Raises
    ------
    InvalidModelError
        (a :class:`ValueError`) naming the field, the bad value and what is expected.
    InvalidModelTypeError
        (an :class:`InvalidModelError` and a :class:`TypeError`) when a field has the wrong type,
        e.g. a string or None where numbers belong, or names given as a generator.

    Notes
    -----
    Symmetry, positive (semi)definiteness and the row sums are checked with tolerances
    relative to each matrix's largest entry, so scaling a weight by any positive factor does
    not change the verdict.

    The methods of the dynamics (``H``, ``constraint_values``, ``in_region``, ``next_state``,
    ``next_mode``, ``step``, ``transition``, ...) are those of
    :class:`~sdjls_gym.dynamics.Dynamics`, with its signatures and docstrings, called on
    ``model.dynamics``; the sizes ``N``, ``n``, ``m``, ``p``, ``r`` are
    :class:`~sdjls_gym.dynamics.Sizes`'s.

    Examples
    --------
    >>> import numpy as np
    >>> m = SDJLSModel(A=[[[0.5]], [[1.2]]], B=[[1.0]], P_in=[[0.9, 0.1], [0.2, 0.8]],
    ...                P_out=[[0.5, 0.5], [0.5, 0.5]], G=[[1.0]], H0=[1.0], Q=[[1.0]],
    ...                R=[[1.0]], x0=[0.0])
    >>> m.N, m.n, m.m, m.p, m.r
    (2, 1, 1, 1, 1)
    """

    # The validated fields (what validate_fields returns); the constructor's arguments are the
    # raw, array-like ones of __init__.
    A: NDArray[np.float64]
    B: NDArray[np.float64]
    P_in: NDArray[np.float64]
    P_out: NDArray[np.float64]
    G: NDArray[np.float64]
    H0: NDArray[np.float64]
    Q: NDArray[np.float64]
    R: NDArray[np.float64]
    x0: NDArray[np.float64]
    E: NDArray[np.float64]
    W: NDArray[np.float64]
    H_rate: NDArray[np.float64]
    mode0: int | NDArray[np.float64]
    mode_names: tuple[str, ...]
    state_names: tuple[str, ...] | None

    # ------------------------------------------------------------------ validation
    def __init__(
        self,
        A: ArrayLike,
        B: ArrayLike,
        P_in: ArrayLike,
        P_out: ArrayLike,
        G: ArrayLike,
        H0: ArrayLike,
        Q: ArrayLike,
        R: ArrayLike,
        x0: ArrayLike,
        E: ArrayLike | None = None,
        W: ArrayLike | None = None,
        H_rate: ArrayLike | None = None,
        mode0: int | ArrayLike = 0,
        mode_names: Sequence[str] | None = None,
        state_names: Sequence[str] | None = None,
    ) -> None:
        # written by hand (the dataclass keeps it) so that the arguments are array-likes while
        # the fields are the validated float64 arrays; dataclasses.replace still works
        raw = {
            "A": A, "B": B, "P_in": P_in, "P_out": P_out, "G": G, "H0": H0, "Q": Q, "R": R,
            "x0": x0, "E": E, "W": W, "H_rate": H_rate, "mode0": mode0,
            "mode_names": mode_names, "state_names": state_names,
        }  # fmt: skip
        for name, value in validate_fields(raw).items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)

    # ------------------------------------------------------------------ sizes (Sizes), dynamics
    @cached_property
    def dynamics(self) -> Dynamics:
        """The functions of the dynamics on this model's matrices (built on first use)."""
        return Dynamics(
            A=self.A, B=self.B, E=self.E, W=self.W, P_in=self.P_in, P_out=self.P_out, G=self.G,
            H0=self.H0, H_rate=self.H_rate, Q=self.Q, R=self.R,
        )  # fmt: skip

    @property
    def W_sqrt(self) -> np.ndarray:
        """(p, p) symmetric square root of ``W``: ``W_sqrt @ W_sqrt.T == W``."""
        return self.dynamics.W_sqrt

    @cached_property
    def noise_cov(self) -> np.ndarray:
        """(N, n, n) covariance ``E_i W E_i'`` of the additive noise in each mode."""
        out = self.E @ self.W @ self.E.transpose(0, 2, 1)
        out.setflags(write=False)
        return out

    # ------------------------------------------------------------------ the dynamics
    # model.H(k) is model.dynamics.H(k), and so on: the signatures and docstrings are
    # Dynamics's, written once there
    H = _handed_over(Dynamics.H)
    constraint_values = _handed_over(Dynamics.constraint_values)
    constraint_values_one = _handed_over(Dynamics.constraint_values_one)
    in_region = _handed_over(Dynamics.in_region)
    in_region_one = _handed_over(Dynamics.in_region_one)
    transition_rows = _handed_over(Dynamics.transition_rows)
    next_state = _handed_over(Dynamics.next_state)
    next_mode = _handed_over(Dynamics.next_mode)
    sample_next_mode = _handed_over(Dynamics.sample_next_mode)
    sample_noise = _handed_over(Dynamics.sample_noise)
    step = _handed_over(Dynamics.step)
    stage_cost = _handed_over(Dynamics.stage_cost)
    transition = _handed_over(Dynamics.transition)
    exact_transition = _handed_over(Dynamics.exact_transition)

    @overload
    def sample_mode0(self, rng: np.random.Generator, size: None = None) -> int: ...
    @overload
    def sample_mode0(self, rng: np.random.Generator, size: int) -> NDArray[np.int64]: ...
    def sample_mode0(
        self, rng: np.random.Generator, size: int | None = None
    ) -> int | NDArray[np.int64]:
        """The initial mode: ``mode0`` itself, or a draw from the probability vector ``mode0``.

        With ``size``, an int64 array of ``size`` initial modes.
        """
        if isinstance(self.mode0, int):
            return self.mode0 if size is None else np.full(size, self.mode0, dtype=np.int64)
        if size is None:
            return int(draw_categorical(self.mode0, rng.random()))
        return draw_categorical(self.mode0, rng.random(size))

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
                f"data = {describe(data)} is {a_type(data)}; expected a dict/table of the model's "
                "fields (a model description)"
            )
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise InvalidModelError(f"unknown model field(s) {unknown}; known fields are {names}")
        parameters = inspect.signature(cls).parameters.values()
        required = [p.name for p in parameters if p.default is inspect.Parameter.empty]
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
