"""Small wrappers for reinforcement learning on SDJLS environments."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sdjls_gym._validate import check_array, check_float32_bound, check_number
from sdjls_gym.env import SDJLSEnv

__all__ = ["ViolationPenalty", "ResidualAction"]


def _action_changing_layers(env: gym.Env) -> list[str]:
    """Names of the wrappers between ``env`` and its unwrapped env that change the action: an
    ``ActionWrapper`` (``RescaleAction``, ``ClipAction``, ...) or a different action space."""
    found = []
    layer, base = env, env.unwrapped
    while isinstance(layer, gym.Wrapper):
        if isinstance(layer, gym.ActionWrapper) or layer.action_space != base.action_space:
            found.append(type(layer).__name__)
        layer = layer.env
    return found


class ViolationPenalty(gym.Wrapper):
    """Reward ``reward - beta * info["cost"]``: a fixed penalty per step that violates a row.

    The unpenalized reward is kept in ``info["reward_unpenalized"]``. ``beta`` may be changed
    during training (``wrapper.beta = ...``), e.g. by a Lagrangian dual-ascent callback.

    Parameters
    ----------
    env : gymnasium.Env
        An environment that reports ``info["cost"]`` (any SDJLS environment does).
    beta : float
        Penalty per violating step, a finite number >= 0 (``TypeError`` for a bool or a string,
        ``ValueError`` for a negative, NaN or infinite value, or an int beyond float64).
    """

    def __init__(self, env: gym.Env, beta: float) -> None:
        super().__init__(env)
        self.beta = beta

    @property
    def beta(self) -> float:
        return self._beta

    @beta.setter
    def beta(self, value: float) -> None:
        self._beta = check_number("beta", value, low=0.0, what="penalty per violating step")

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["reward_unpenalized"] = reward
        return obs, float(reward - self._beta * info["cost"]), terminated, truncated, info


class ResidualAction(gym.ActionWrapper):
    """Act on the offset ``nu``: the applied input is ``u = K_theta x + nu`` (eq. 9 of the paper).

    ``u`` is in the units of the raw environment's action, so ``ResidualAction`` must sit
    directly on the raw environment (``gym.make`` output is fine: its ``TimeLimit``,
    ``OrderEnforcing`` and checker wrappers leave actions alone). Rescale on top of it, e.g.
    ``RescaleAction(ResidualAction(env, K), -1.0, 1.0)``.

    Parameters
    ----------
    env : gymnasium.Env
        An SDJLS environment (possibly wrapped; its ``unwrapped`` must be an ``SDJLSEnv``),
        without wrappers that change the action below this one.
    K : (N, m, n) array
        State-feedback gains, e.g. from ``controllers.synthesize_gains``.
    nu_bound : float
        The new action space is ``Box(-nu_bound, nu_bound, (m,))`` (a normal float32 number).

    Raises
    ------
    TypeError
        ``env`` is not an SDJLS environment, or ``K`` / ``nu_bound`` are not numbers.
    ValueError
        A wrapper between ``env`` and the raw environment changes the action (an
        ``ActionWrapper`` such as ``RescaleAction`` or ``ClipAction``, or another action space),
        or ``K`` / ``nu_bound`` are malformed.

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
        changers = _action_changing_layers(env)
        if changers:
            raise ValueError(
                f"ResidualAction must wrap the SDJLS environment directly: {', '.join(changers)} "
                "between them changes the action, so u = K x + nu would not be applied in units "
                "of u; put ResidualAction on the raw env and rescale on top of it, e.g. "
                "RescaleAction(ResidualAction(env, K), -1.0, 1.0)"
            )
        model = base.model
        self.K = check_array(
            "K", K, shape=(model.N, model.m, model.n), what="the gains K_i, one m x n per mode"
        )
        nu_bound = check_float32_bound("nu_bound", nu_bound, what="bound on |nu_i|")
        bound = np.full(model.m, nu_bound, dtype=np.float32)
        self.action_space = spaces.Box(-bound, bound, dtype=np.float32)

    def action(self, action: np.ndarray) -> np.ndarray:
        nu = np.asarray(action, dtype=np.float64).reshape(-1)
        if nu.shape != (self.K.shape[1],) or not np.all(np.isfinite(nu)):
            raise ValueError(f"action (nu) = {action!r}; expected {self.K.shape[1]} finite numbers")
        base = self.env.unwrapped
        return self.K[base.mode] @ base.state + nu
