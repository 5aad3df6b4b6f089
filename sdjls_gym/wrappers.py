"""Small wrappers for reinforcement learning on SDJLS environments."""

from __future__ import annotations

import numbers
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sdjls_gym.env import SDJLSEnv

__all__ = ["ViolationPenalty", "ResidualAction"]


def _is_real(value: Any) -> bool:
    """A real number (not a bool, a string or None)."""
    return isinstance(value, (numbers.Real, np.floating, np.integer)) and not isinstance(
        value, (bool, np.bool_)
    )


class ViolationPenalty(gym.Wrapper):
    """Reward ``reward - beta * info["cost"]``: a fixed penalty per step that violates a row.

    The unpenalized reward is kept in ``info["reward_unpenalized"]``. ``beta`` may be changed
    during training (``wrapper.beta = ...``), e.g. by a Lagrangian dual-ascent callback.

    Parameters
    ----------
    env : gymnasium.Env
        An environment that reports ``info["cost"]`` (any SDJLS environment does).
    beta : float
        Penalty per violating step, finite and >= 0.
    """

    def __init__(self, env: gym.Env, beta: float) -> None:
        super().__init__(env)
        self.beta = beta

    @property
    def beta(self) -> float:
        return self._beta

    @beta.setter
    def beta(self, value: float) -> None:
        if not (_is_real(value) and np.isfinite(value) and value >= 0):
            raise ValueError(f"beta = {value!r}; expected a finite penalty >= 0")
        self._beta = float(value)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["reward_unpenalized"] = reward
        return obs, float(reward - self._beta * info["cost"]), terminated, truncated, info


class ResidualAction(gym.ActionWrapper):
    """Act on the offset ``nu``: the applied input is ``u = K_theta x + nu`` (eq. 9 of the paper).

    Parameters
    ----------
    env : gymnasium.Env
        An SDJLS environment (possibly wrapped; its ``unwrapped`` must be an ``SDJLSEnv``).
    K : (N, m, n) array
        State-feedback gains, e.g. from ``controllers.synthesize_gains``.
    nu_bound : float
        The new action space is ``Box(-nu_bound, nu_bound, (m,))``.

    Notes
    -----
    The environment still clips ``u`` to its own action box; ``info["u"]`` is what was applied.
    """

    def __init__(self, env: gym.Env, K: np.ndarray, nu_bound: float = 100.0) -> None:
        super().__init__(env)
        base = env.unwrapped
        if not isinstance(base, SDJLSEnv):
            raise TypeError(
                f"ResidualAction needs an SDJLSEnv underneath, got {type(base).__name__}"
            )
        model = base.model
        try:
            K = np.asarray(K, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(
                f"K = {K!r:.60}; expected an ({model.N}, {model.m}, {model.n}) array of gains"
            ) from None
        if K.shape != (model.N, model.m, model.n):
            raise ValueError(f"K has shape {K.shape}; expected ({model.N}, {model.m}, {model.n})")
        if not np.all(np.isfinite(K)):
            raise ValueError("K contains NaN or inf; expected finite gains")
        if not (_is_real(nu_bound) and np.isfinite(nu_bound) and nu_bound > 0):
            raise ValueError(f"nu_bound = {nu_bound!r}; expected a finite positive float")
        self.K = K
        bound = np.full(model.m, nu_bound, dtype=np.float32)
        self.action_space = spaces.Box(-bound, bound, dtype=np.float32)

    def action(self, action: np.ndarray) -> np.ndarray:
        nu = np.asarray(action, dtype=np.float64).reshape(-1)
        if nu.shape != (self.K.shape[1],) or not np.all(np.isfinite(nu)):
            raise ValueError(f"action (nu) = {action!r}; expected {self.K.shape[1]} finite numbers")
        base = self.env.unwrapped
        return self.K[base.mode] @ base.state + nu
