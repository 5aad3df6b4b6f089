"""Policies behind the controllers' ``act_batch(x, mode, k)``, for :mod:`benchmarks.evaluate`.

* :class:`RawEnvPolicy`: an agent trained behind rescaling wrappers, acting on the raw
  environment (actions in units of ``u``);
* :func:`as_controller`: any policy (a controller, an object with ``predict``, a callable
  ``obs -> action``) behind ``act_batch`` / ``act``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from sdjls_gym.env import SDJLSEnv
from sdjls_gym.messages import a_type, describe
from sdjls_gym.observation import decode_observation, encode_observation
from sdjls_gym.wrappers import ResidualAction, ScaleObservationReward, scale_observation

__all__ = ["RawEnvPolicy", "as_controller"]


class _ObservationPolicy:
    """A ``predict`` or callable policy behind the controllers' ``act_batch`` / ``act``."""

    def __init__(self, policy: Any, spec: Any) -> None:
        if callable(getattr(policy, "predict", None)):
            self.call = lambda obs: policy.predict(obs, deterministic=True)[0]
        elif callable(policy):
            self.call = policy
        else:  # checked by as_controller first
            raise TypeError(f"policy is {a_type(policy)}")
        self.spec, self.m = spec, spec.model.m
        self.batched: bool | None = None  # decided at the first batch

    def _one(self, obs: np.ndarray) -> np.ndarray:
        a = np.asarray(self.call(obs), dtype=np.float64)
        if a.size != self.m:
            raise ValueError(
                f"the policy returned {describe(a)} (shape {a.shape}) for one observation; "
                f"expected {self.m} number(s)"
            )
        return a.reshape(self.m)

    def _rows(self, obs: np.ndarray) -> np.ndarray:
        return np.stack([self._one(o) for o in obs])

    def _batch(self, obs: np.ndarray) -> np.ndarray:
        B = len(obs)
        if self.batched is False:
            return self._rows(obs)
        if self.batched:
            return np.asarray(self.call(obs), dtype=np.float64).reshape(B, self.m)
        # undecided: one call on all rows, checked against single calls on up to 8 distinct rows
        # (decided only on a batch with distinct rows: a batch of equal rows cannot show a
        # policy that mixes up its rows)
        try:
            a = np.asarray(self.call(obs), dtype=np.float64)
            a = a.reshape(B, self.m) if a.shape in ((B, self.m), (B,) * (self.m == 1)) else None
        except Exception:  # noqa: BLE001 - a policy for one observation may fail on many
            a = None
        idx = np.sort(np.unique(obs, axis=0, return_index=True)[1])[:8]
        try:
            rows, error = self._rows(obs[idx]), None
        except Exception as exc:  # noqa: BLE001 - a policy for batches may fail on one row
            rows, error = None, exc
        if a is not None and rows is not None:
            scale = max(1.0, float(np.max(np.abs(rows))))
            agree = bool(np.allclose(a[idx], rows, rtol=1e-5, atol=1e-6 * scale))
            self.batched = None if agree and len(idx) < 2 else agree
            if agree:
                return a
        elif a is not None:
            self.batched = True  # a policy for batches only
            return a
        if error is not None:
            raise error
        self.batched = False
        return self._rows(obs)

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        s = self.spec
        obs = encode_observation(s.model, x, mode, k, s.horizon, s.divergence_bound)
        u = self._batch(obs)
        if not np.all(np.isfinite(u)):
            row = int(np.argwhere(~np.isfinite(u))[0, 0])
            raise ValueError(
                f"the policy returned a non-finite action {describe(u[row])} for the observation "
                f"{describe(obs[row])}; expected finite numbers"
            )
        B = len(x)
        cost = s.model.stage_cost(x, mode, np.clip(u, -s.action_bound, s.action_bound))
        return u, {"rho": np.zeros(B), "cost": cost, "ok": np.ones(B, dtype=bool)}

    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        u, info = self.act_batch(np.asarray(x)[None], np.array([mode]), np.array([k]))
        return u[0], {key: value[0] for key, value in info.items()}


def _check_policy(policy: Any) -> None:
    if not (
        callable(getattr(policy, "act_batch", None))
        or callable(getattr(policy, "predict", None))
        or callable(policy)
    ):
        raise TypeError(
            f"policy = {describe(policy)} is {a_type(policy)}; expected an object with "
            "predict(obs, deterministic=True) (stable-baselines3's), a callable obs -> action, "
            "or a controller with act_batch(x, mode, k) and act(x, mode, k)"
        )


def as_controller(policy: Any, spec: Any) -> Any:
    """``policy`` behind ``act_batch(x, mode, k)`` / ``act(x, mode, k)`` (see the module doc)."""
    _check_policy(policy)
    if callable(getattr(policy, "act_batch", None)) and callable(getattr(policy, "act", None)):
        return policy
    return _ObservationPolicy(policy, spec)


class RawEnvPolicy:
    """An agent trained behind wrappers, acting on the raw environment (actions in units of u).

    Reads the wrappers of ``env``, the agent's training environment, and undoes them:
    :class:`~sdjls_gym.wrappers.ScaleObservationReward` (the agent sees the scaled state),
    ``gymnasium.wrappers.RescaleAction`` (the agent's action, clipped to its action space, is
    mapped back to the wrapped box) and :class:`~sdjls_gym.wrappers.ResidualAction`
    (``u = K_theta x + nu``). Wrappers that change only the reward or the episode's end
    (``ViolationPenalty``, ``TerminateOutside``, ``FiniteHorizon``, ``TimeLimit``, SB3's
    ``Monitor``) are skipped; any other wrapper that changes the observation or action space is
    an error.

    Parameters
    ----------
    agent : object
        With ``predict(obs, deterministic=True)``: an SB3 model or policy.
    env : gymnasium.Env
        The training environment (wrapped), or one built the same way.

    Examples
    --------
    >>> import gymnasium as gym
    >>> from gymnasium.wrappers import RescaleAction
    >>> from sdjls_gym.wrappers import ScaleObservationReward
    >>> env = ScaleObservationReward(RescaleAction(gym.make("SDJLS-Macro-v0"), -1.0, 1.0))
    >>> class Half:  # always a = 0.5 in [-1, 1]
    ...     def predict(self, obs, deterministic=True):
    ...         return np.full((len(obs), 1), 0.5, dtype=np.float32), None
    >>> u, _ = RawEnvPolicy(Half(), env).act(np.array([2.0, 2.0]), 0, 0)
    >>> float(u[0])  # 0.5 of the raw bound 200
    100.0
    """

    def __init__(self, agent: Any, env: gym.Env) -> None:
        if not callable(getattr(agent, "predict", None)):
            raise TypeError(
                f"agent = {describe(agent)} is {a_type(agent)}; expected an object with "
                "predict(obs, deterministic=True), such as a stable-baselines3 model"
            )
        if not isinstance(env, gym.Env):
            raise TypeError(
                f"env = {describe(env)} is {a_type(env)}; expected the agent's training "
                "environment, a gymnasium.Env (for an SB3 VecEnv pass venv.envs[0])"
            )
        base = env.unwrapped
        if not isinstance(base, SDJLSEnv):
            raise TypeError(f"env has a {type(base).__name__} underneath; expected an SDJLSEnv")
        self.agent, self.model = agent, base.model
        self.horizon, self.divergence_bound = int(base.horizon), float(base.divergence_bound)
        self.action_bound = float(np.max(base.action_space.high))
        box = env.action_space
        self.low, self.high = box.low.astype(np.float64), box.high.astype(np.float64)
        self.scaling: tuple[float, float] | None = None
        self.actions: list[tuple[str, Any]] = []  # outermost first: how an action reaches u
        e = env
        while isinstance(e, gym.Wrapper):
            inner = e.env
            if isinstance(e, ScaleObservationReward):
                self.scaling = (e.x_scale, e.obs_clip)
            elif isinstance(e, gym.wrappers.RescaleAction):
                lo, hi = e.action_space.low, e.action_space.high
                in_lo, in_hi = inner.action_space.low, inner.action_space.high
                bounds = tuple(np.asarray(v, dtype=np.float64) for v in (lo, hi, in_lo, in_hi))
                self.actions.append(("rescale", bounds))
            elif isinstance(e, ResidualAction):
                self.actions.append(("residual", e.K))
            elif isinstance(e, gym.wrappers.ClipAction):
                pass  # the action is clipped to the agent's space anyway
            elif (
                isinstance(e, (gym.ObservationWrapper, gym.ActionWrapper))
                or e.observation_space != inner.observation_space
                or e.action_space != inner.action_space
            ):
                raise ValueError(
                    f"env has a {type(e).__name__} wrapper, which changes the observation or the "
                    "action in a way RawEnvPolicy cannot undo; it knows ScaleObservationReward, "
                    "RescaleAction, ResidualAction and wrappers of the reward"
                )
            e = inner

    def observe(self, x: np.ndarray, mode: np.ndarray, k: np.ndarray) -> np.ndarray:
        """The observations (B, n + N + 1) the agent was trained on, for states (B, n)."""
        obs = encode_observation(self.model, x, mode, k, self.horizon, self.divergence_bound)
        return obs if self.scaling is None else scale_observation(obs, self.model.n, *self.scaling)

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """``u`` (B, m) for states ``x`` (B, n), modes (B,), times (B,); info as a controller's."""
        x = np.asarray(x, dtype=np.float64)
        mode = np.asarray(mode, dtype=np.int64)
        a, _ = self.agent.predict(self.observe(x, mode, k), deterministic=True)
        v = np.clip(np.asarray(a, dtype=np.float64).reshape(len(x), -1), self.low, self.high)
        nu = np.zeros_like(v)
        for kind, data in self.actions:
            if kind == "rescale":
                lo, hi, in_lo, in_hi = data
                if np.all(lo == -hi) and np.all(in_lo == -in_hi):  # symmetric: a * bound
                    v = v * (in_hi / hi)
                else:
                    v = in_lo + (in_hi - in_lo) * (v - lo) / (hi - lo)
            else:  # residual: u = K_theta x + nu
                nu = v
                v = np.einsum("bij,bj->bi", data[mode], x) + nu
        B = len(x)
        cost = self.model.stage_cost(x, mode, np.clip(v, -self.action_bound, self.action_bound))
        info = {"nu": nu, "rho": np.zeros(B), "cost": cost, "ok": np.ones(B, dtype=bool)}
        return v, info

    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """One decision: ``act_batch`` on a batch of one."""
        u, info = self.act_batch(np.asarray(x)[None], np.array([mode]), np.array([k]))
        return u[0], {key: value[0] for key, value in info.items()}

    def predict(
        self, observation: np.ndarray, state: Any = None, episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:  # fmt: skip
        """stable-baselines3's ``predict`` on raw observations (the state at float32 precision)."""
        single = np.ndim(observation) == 1
        x, mode, k = decode_observation(self.model, np.atleast_2d(observation), self.horizon)
        u = self.act_batch(x, mode, k)[0].astype(np.float32)
        return (u[0] if single else u), state
