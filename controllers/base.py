"""The base of every controller: ``act`` / ``act_batch`` / ``predict``, input checks, threads.

Every controller of this package is a :class:`Controller`:

* ``act(x, mode, k) -> (u, info)`` for one state, with ``info["nu"]``, ``info["rho"]``,
  ``info["cost"]`` and ``info["status"]``;
* ``act_batch(x, modes, k) -> (u, info)`` for a batch (arrays with a leading batch axis);
* ``predict(observation, state=None, episode_start=None, deterministic=True)`` in the
  stable-baselines3 shape, decoding the raw environment's observation
  ``[x, one-hot(mode), k / horizon]`` and returning the input ``u`` in the raw environment's units.
  These controllers need the mode: a state-only observation (an environment made with
  ``observe="state"``) is refused with :class:`~sdjls_gym.errors.ModeNotObservedError`.

Thread safety: a controller may be shared by threads. Its calls hold a per-controller lock
around the solver state (OSQP objects, warm starts, caches), so concurrent calls are serialized
and each answer equals the one a single thread would get. A controller can be pickled or
deep-copied at any time (the solver state is dropped and rebuilt on use), e.g. to send it to
worker processes.
"""

from __future__ import annotations

import threading
from typing import Any, ClassVar

import numpy as np

from sdjls_gym.errors import ModeNotObservedError
from sdjls_gym.messages import a_type, describe
from sdjls_gym.model import SDJLSModel
from sdjls_gym.observation import decode_observation
from sdjls_gym.validation import (
    MAX_INDEX,
    check_array,
    check_int,
    check_int_array,
    check_optional_int,
)

__all__ = [
    "Controller",
    "ObservationPolicy",
    "MAX_STATE",
    "ENV_DEFAULT_HORIZON",
    "check_model",
    "check_gain",
    "check_terminal_weights",
    "frozen",
    "ReadOnlyArrays",
]

#: Largest state magnitude a controller accepts. The costs it reports (``x'Q x`` and the like)
#: overflow float64 from about 1e154; a state above this bound means the closed loop diverged
#: long ago (the environments terminate at ``divergence_bound``, at most 1e30).
MAX_STATE = 1e100
_TOO_LARGE = (
    f"has an entry of magnitude above {MAX_STATE:.0e}, the largest state a controller accepts "
    "(its costs would overflow float64); a state this large means the closed loop has diverged"
)

#: The environments' default episode length (``SDJLSEnv(horizon=20)``, ``SDJLS-Macro-v0``): the
#: horizon :meth:`Controller.predict` assumes when the controller was built without one.
ENV_DEFAULT_HORIZON = 20

#: How far ``k / horizon * horizon`` may be from an integer (float32 rounding of the observation).
_TIME_TOL = 1e-3


def frozen(a: Any) -> np.ndarray:
    """A read-only, contiguous float64 copy of ``a`` (results and data that callers must not
    change in place)."""
    out = np.array(a, dtype=np.float64, order="C")
    out.setflags(write=False)
    return out


class ReadOnlyArrays:
    """A base of frozen result dataclasses: the fields named in ``ARRAYS`` are stored as
    :func:`frozen` copies (read-only, contiguous float64), whatever array-like is passed."""

    ARRAYS: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        for name in self.ARRAYS:
            object.__setattr__(self, name, frozen(getattr(self, name)))


def check_model(model: Any) -> SDJLSModel:
    """``model`` if it is an :class:`SDJLSModel`, else a TypeError naming it."""
    if not isinstance(model, SDJLSModel):
        raise TypeError(
            f"model = {describe(model, 60)} is {a_type(model)}; expected an "
            "sdjls_gym.SDJLSModel (build one with SDJLSModel(...) or a preset such as "
            "sdjls_gym.systems.macro())"
        )
    return model


def check_gain(model: SDJLSModel, K: Any, name: str = "K") -> np.ndarray:
    """A finite ``(N, m, n)`` array of mode-dependent feedback gains (read-only copy)."""
    K = check_array(
        name,
        K,
        shape=(model.N, model.m, model.n),
        what=f"one m x n gain per mode, N={model.N}, m={model.m}, n={model.n}",
    )
    K.setflags(write=False)
    return K


def check_terminal_weights(model: SDJLSModel, Psi: Any) -> np.ndarray:
    """A finite ``(N, n, n)`` array of symmetric positive definite terminal weights ``Psi``
    (read-only); symmetry and definiteness are tested relative to each matrix's own scale."""
    Psi = check_array(
        "Psi", Psi, shape=(model.N, model.n, model.n), what="one n x n terminal weight per mode"
    )
    for i, M in enumerate(Psi):
        scale = float(np.max(np.abs(M)))
        if scale == 0.0 or float(np.max(np.abs(M - M.T))) > 1e-9 * scale:
            raise ValueError(
                f"Psi[{i}] = {describe(M)} is not symmetric positive definite; expected a "
                "symmetric positive definite matrix per mode"
            )
        eig = np.linalg.eigvalsh(0.5 * (M + M.T))
        if not eig[0] > 1e-12 * abs(eig[-1]):
            raise ValueError(
                f"Psi[{i}] is not positive definite (eigenvalues {eig[0]:.3g} .. {eig[-1]:.3g}); "
                "expected a symmetric positive definite matrix per mode"
            )
    return frozen(0.5 * (Psi + Psi.transpose(0, 2, 1)))


class ObservationPolicy:
    """stable-baselines3's ``predict`` on top of one method, ``_observed_inputs(observation)``
    (the inputs ``u`` for the decoded observations): the base of :class:`Controller` and of
    :class:`controllers.env_policy.ControllerPolicy`."""

    def _observed_inputs(self, observation: Any) -> tuple[np.ndarray, bool]:
        raise NotImplementedError

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """Actions for observations of the environment, in stable-baselines3's shape.

        For a controller, the actions are the inputs ``u`` in the raw environment's units (its
        action space). On an environment whose actions are transformed by a wrapper (e.g.
        ``gymnasium.wrappers.RescaleAction``) use :func:`controllers.policy_for` instead, whose
        policy maps them through the wrappers.

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

        Raises
        ------
        ModeNotObservedError
            (a :class:`ValueError`) A state-only observation (``observe="state"``): these
            controllers need the mode.
        """
        inputs, single = self._observed_inputs(observation)
        actions = inputs.astype(np.float32)
        return (actions[0] if single else actions), state


class Controller(ObservationPolicy):
    """Shared plumbing of the controllers: input checks, batches, ``predict``, threads.

    Subclasses implement :meth:`act` (and may replace :meth:`act_batch` with a vectorized one).

    Parameters
    ----------
    model : SDJLSModel
    horizon : int, optional
        Episode length of the environment, which scales time in the observation
        (``k / horizon``). Only :meth:`predict` uses it, and only controllers whose decision
        depends on ``k`` (the receding-horizon ones: the band ``H_k`` moves with ``k``). Without
        it, :meth:`predict` assumes the environments' default, :data:`ENV_DEFAULT_HORIZON`, and
        raises if an observation's time entry is not a multiple of ``1 / horizon``.

    Notes
    -----
    Thread-safe: calls hold the controller's lock (see the module docstring).
    """

    #: Whether the decision depends on the time ``k`` (then ``predict`` decodes it).
    _needs_time = True
    #: How many steps past ``k`` the controller reads the band ``H`` (see :attr:`max_k`).
    _lookahead = 1

    def __init__(self, model: SDJLSModel, horizon: int | None = None) -> None:
        self.model = check_model(model)
        self.horizon = check_optional_int("horizon", horizon, low=1, what="episode length")
        self._lock = threading.RLock()
        self._x_shape = (self.model.n,)

    # ------------------------------------------------------------------ pickling
    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("_lock", None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._lock = threading.RLock()

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

    @property
    def max_k(self) -> int:
        """The largest time index ``k`` accepted: ``2**53 - lookahead``, where ``lookahead`` is
        how many steps past ``k`` the controller reads the band ``H`` (1; ``steps`` for the
        scenario tree), so that every ``H_{k+t}`` it uses has an index float64 holds exactly."""
        return MAX_INDEX - self._lookahead

    @property
    def _k_what(self) -> str:
        L = self._lookahead
        return f"time index, at most 2**53 - {L}: the controller reads the band H up to k + {L}"

    def _check_inputs(self, x: Any, mode: Any, k: Any) -> tuple[np.ndarray, int, int]:
        """``x`` a finite ``(n,)`` vector within :data:`MAX_STATE`, ``mode`` in ``[0, N)``,
        ``k`` an int in ``[0, max_k]``; the messages name the argument."""
        x = check_array("x", x, shape=self._x_shape, what="one state vector")
        if np.max(np.abs(x)) > MAX_STATE:
            raise ValueError(f"x = {describe(x)} {_TOO_LARGE}")
        mode = check_int("mode", mode, low=0, high=self.model.N - 1)
        k = check_int("k", k, low=0, high=self.max_k, what=self._k_what)
        return x, mode, k

    def _check_batch_inputs(
        self, x: Any, mode: Any, k: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``x`` (B, n) finite, ``mode`` (B,) ints in [0, N), ``k`` (B,) ints in
        ``[0, max_k]`` (or a scalar)."""
        model = self.model
        x = check_array("x", x, shape=(None, model.n), what="one state per row")
        if x.size and np.max(np.abs(x)) > MAX_STATE:
            row = int(np.argmax(np.max(np.abs(x), axis=1)))
            raise ValueError(f"x[{row}] = {describe(x[row])} {_TOO_LARGE}")
        B = x.shape[0]
        out = []
        for name, value, high in (("mode", mode, model.N - 1), ("k", k, self.max_k)):
            arr = check_int_array(name, value, low=0, high=high)  # bools refused, by entry
            arr = np.broadcast_to(arr, (B,)) if arr.ndim == 0 else arr
            if arr.shape != (B,):
                raise ValueError(f"{name} has shape {arr.shape}; expected ({B},) to match x")
            out.append(arr.astype(np.int64))  # a copy, as before: callers may keep it
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
            ``"cost"``, ``"status"`` (str objects) and ``"ok"`` (bool: the answer was verified
            optimal, or is exact by construction). This generic version loops over
            :meth:`act`; subclasses replace it with a vectorized one.
        """
        x, mode, k = self._check_batch_inputs(x, mode, k)
        results = [self.act(xb, int(mb), int(kb)) for xb, mb, kb in zip(x, mode, k, strict=True)]
        info = {
            key: np.array([r[1][key] for r in results], dtype=object if key == "status" else None)
            for key in ("nu", "rho", "cost", "status")
        }
        info["ok"] = np.array([r[1].get("ok", True) for r in results], dtype=bool)
        u = np.array([r[0] for r in results], dtype=np.float64).reshape(len(results), -1)
        return u, info

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
            The position of the 1 in the one-hot part.
        k : (B,) int64
            ``round(observation[..., -1] * horizon)``; zeros for a controller whose decision
            does not depend on ``k``.

        Raises
        ------
        ValueError
            If the observation has the wrong shape or non-finite entries, if its mode part is
            not one-hot (one 1 and zeros), or (for controllers that need ``k``) if its time
            entry is negative, above 1, or not a multiple of ``1 / horizon`` (the environment's
            horizon differs from the controller's).
        ModeNotObservedError
            (a :class:`ValueError`) The observation is the state-only ``[x, k / horizon]`` of
            an environment made with ``observe="state"``: it does not show the mode.
        """
        return self._decode_own(self._observation(observation))

    def _decode_own(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_decode` with the controller's own horizon (or none, when ``k`` is unused)."""
        if not self._needs_time:
            return self._decode(obs, None)
        source = (
            f"horizon = {self.horizon}"
            if self.horizon is not None
            else f"the environments' default horizon {ENV_DEFAULT_HORIZON} (no horizon was given)"
        )
        hint = (
            "the environment's horizon differs from the controller's; pass horizon= (the "
            f"environment's episode length, env.unwrapped.horizon) to {type(self).__name__}"
        )
        horizon = self.horizon if self.horizon is not None else ENV_DEFAULT_HORIZON
        return self._decode(obs, horizon, f"{source}: {hint}")

    def _observation(self, observation: Any) -> np.ndarray:
        """``observation`` checked: finite numbers, shape ``(n + N + 1,)`` or ``(B, n + N + 1)``
        (float64 copy, its shape kept)."""
        model = self.model
        size = model.n + model.N + 1
        layout = f"[x ({model.n}), one-hot of the mode ({model.N}), k / horizon (1)]"
        obs = check_array("observation", observation, what=layout)
        if obs.ndim in (1, 2) and obs.shape[-1] == model.n + 1:  # observe="state": no mode
            raise ModeNotObservedError(
                f"observation has shape {obs.shape}: the state-only layout [x ({model.n}), "
                f"k / horizon (1)] of an environment made with observe='state', which does not "
                f"show the mode; {type(self).__name__} needs the mode theta_k. Use observe='mode', "
                "or controllers.HiddenModePolicy(ctrl), which keeps the belief of the mode "
                "(controllers.ModeFilter) across the episode and decides with its most probable "
                "mode (or the belief itself, with a BeliefRecedingHorizonController)"
            )
        if obs.ndim not in (1, 2) or obs.shape[-1] != size:
            raise ValueError(
                f"observation has shape {obs.shape}; expected ({size},) or (batch, {size}): "
                f"{layout}"
            )
        return obs

    def _decode(
        self, obs: np.ndarray, horizon: int | None, why: str = ""
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`decode_observation` of an observation checked by :meth:`_observation`, with
        time decoded at ``horizon`` (``why`` ends the message of a time that does not decode),
        or not at all (zeros) when it is None. The state part must be within
        :data:`MAX_STATE` and the mode part one-hot."""
        model = self.model
        obs = obs.reshape(-1, model.n + model.N + 1)
        which = "observation" if obs.shape[0] == 1 else "observation[{}]"
        x = obs[:, : model.n]
        if x.size and np.max(np.abs(x)) > MAX_STATE:
            row = int(np.argmax(np.max(np.abs(x), axis=1)))
            raise ValueError(f"{which.format(row)}'s state part {describe(x[row])} {_TOO_LARGE}")
        one_hot = obs[:, model.n : model.n + model.N]
        bad = ~np.all((one_hot == 0.0) | (one_hot == 1.0), axis=1) | (one_hot.sum(axis=1) != 1.0)
        if np.any(bad):
            row = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"{which.format(row)}'s mode part {describe(one_hot[row])} is not one-hot; "
                f"expected {model.N} entries, one 1.0 and the rest 0.0: [x ({model.n}), one-hot "
                f"of the mode ({model.N}), k / horizon (1)]"
            )
        if horizon is None:
            x, mode, _ = decode_observation(model, obs, 1)
            return x, mode, np.zeros(obs.shape[0], dtype=np.int64)
        tau = obs[:, -1]
        with np.errstate(over="ignore", invalid="ignore"):  # a huge tau is refused just below
            scaled = tau * horizon
            bad = ~((tau >= 0.0) & (tau <= 1.0) & (np.abs(scaled - np.rint(scaled)) <= _TIME_TOL))
        if np.any(bad):
            first = float(tau[bad][0])
            raise ValueError(
                f"observation's time entry k / horizon = {first:.6g} does not decode to a time "
                f"k in [0, horizon] with {why}"
            )
        return decode_observation(model, obs, horizon)

    def _observed_inputs(self, observation: Any) -> tuple[np.ndarray, bool]:
        """The inputs ``u`` (B, m) for the observation(s), and whether one observation was given
        (the hook of :meth:`ObservationPolicy.predict`)."""
        obs = self._observation(observation)  # checked before its ndim is read
        return self.act_batch(*self._decode_own(obs))[0], obs.ndim == 1
