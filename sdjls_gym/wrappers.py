"""Small wrappers for reinforcement learning on SDJLS environments."""

from __future__ import annotations

from typing import Any, SupportsFloat, cast

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sdjls_gym.env import SDJLSEnv
from sdjls_gym.errors import ModeNotObservedError
from sdjls_gym.messages import a_type, describe
from sdjls_gym.validation import (
    check_array,
    check_choice,
    check_float32_bound,
    check_number,
    check_positive,
)

__all__ = [
    "ViolationPenalty",
    "ResidualAction",
    # training wrappers of the RL comparison (at the end of this file)
    "FiniteHorizon",
    "OBS_CLIP",
    "REWARD_CLIP",
    "REWARD_SCALE",
    "REWARD_TRANSFORM",
    "ScaleObservationReward",
    "TERMINATE_BOUND",
    "TerminateOutside",
    "X_SCALE",
    "scale_observation",
]


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


def _check_env(env: Any) -> None:
    """Refuse (``TypeError``) a wrapper's ``env`` that is not a ``gymnasium.Env``, naming it."""
    if not isinstance(env, gym.Env):
        raise TypeError(
            f"env = {describe(env)} is {a_type(env)}; expected a gymnasium.Env (an SDJLS "
            "environment, possibly wrapped)"
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
        Penalty per violating step, a finite number >= 0 (``TypeError`` for a bool or a string,
        ``ValueError`` for a negative, NaN or infinite value, or an int beyond float64).
    """

    def __init__(self, env: gym.Env, beta: float) -> None:
        _check_env(env)
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

    With the mode hidden (the environment's ``observe="state"``) the wrapper must not read
    ``theta``: every ``K_i`` must then be the same gain, applied as ``u = K_0 x + nu``, and gains
    that differ by mode are refused. A gain chosen from the mode's belief is a policy's business
    (``controllers.ModeFilter``), not this wrapper's.

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
        State-feedback gains, e.g. from ``controllers.synthesize_gains`` (with the mode hidden:
        one gain repeated, ``np.stack([K0] * N)``).
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
    ModeNotObservedError
        (a :class:`ValueError`) The environment hides the mode (``observe="state"``) and the
        gains ``K_i`` differ by mode.

    Notes
    -----
    The environment still clips ``u`` to its own action box; ``info["u"]`` is what was applied.
    """

    def __init__(self, env: gym.Env, K: np.ndarray, nu_bound: float = 100.0) -> None:
        _check_env(env)
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
        self._base = base  # typed: the SDJLSEnv whose state and mode feed u = K x + nu
        model = base.model
        self.K = check_array(
            "K", K, shape=(model.N, model.m, model.n), what="the gains K_i, one m x n per mode"
        )
        # with the mode hidden it is never read: u = K_0 x + nu, the same gain in every mode
        self._hidden = base.observe == "state"
        if self._hidden and not np.array_equal(self.K, np.broadcast_to(self.K[0], self.K.shape)):
            raise ModeNotObservedError(
                f"K = {describe(self.K)} differs by mode, but the environment hides the mode "
                "(observe = 'state'): u = K_theta x + nu would read it. Repeat one gain in every "
                f"mode (np.stack([K0] * {model.N})), or compute u from the mode's belief "
                "(controllers.ModeFilter) in the policy"
            )
        nu_bound = check_float32_bound("nu_bound", nu_bound, what="bound on |nu_i|")
        bound = np.full(model.m, nu_bound, dtype=np.float32)
        self.action_space = spaces.Box(-bound, bound, dtype=np.float32)

    def action(self, action: np.ndarray) -> np.ndarray:
        nu = np.asarray(action, dtype=np.float64).reshape(-1)
        if nu.shape != (self.K.shape[1],) or not np.all(np.isfinite(nu)):
            raise ValueError(f"action (nu) = {action!r}; expected {self.K.shape[1]} finite numbers")
        base = self._base
        return self.K[0 if self._hidden else base.mode] @ base.state + nu


# ----------------------------------------------------------------------------- learning scalings
# The fixed scalings of the RL comparison (``python -m benchmarks.rl.compare``): the
# observation's state ``x / X_SCALE`` clipped to ``+-OBS_CLIP``, the reward
# ``-log(1 + c / REWARD_SCALE)`` of the per-step cost ``c = -reward``, and training episodes
# ended once ``max |x| > TERMINATE_BOUND``.
X_SCALE = 10.0
OBS_CLIP = 10.0
REWARD_SCALE = 100.0
REWARD_CLIP = 1e30
REWARD_TRANSFORM = "log"
TERMINATE_BOUND = 100.0


def scale_observation(obs: np.ndarray, n: int, x_scale: float, obs_clip: float) -> np.ndarray:
    """``[clip(x / x_scale, +-obs_clip), one-hot, k / T]`` of observations ``(..., n + N + 1)``,
    or ``[clip(x / x_scale, +-obs_clip), k / T]`` of state-only ones ``(..., n + 1)``.

    Returns a new float32 array; only the first ``n`` entries (the state) change, so either
    layout of :mod:`sdjls_gym.observation` keeps its meaning.
    """
    out = np.array(obs, dtype=np.float32, copy=True)
    out[..., :n] = np.clip(out[..., :n] / x_scale, -obs_clip, obs_clip)
    return out


def _sdjls_base(env: gym.Env, wrapper: str) -> SDJLSEnv:
    base = env.unwrapped
    if not isinstance(base, SDJLSEnv):
        raise TypeError(f"{wrapper} needs an SDJLSEnv underneath, got {type(base).__name__}")
    return base


class ScaleObservationReward(gym.Wrapper):
    """Fixed scalings for learning: the state in the observation and the reward.

    The observation becomes ``[clip(x / x_scale, +-obs_clip), one-hot of the mode, k / T]``
    (``[clip(x / x_scale, +-obs_clip), k / T]`` when the environment hides the mode) and
    the reward ``r`` becomes ``max(r, -reward_clip) / reward_scale`` (``"linear"``) or
    ``-log(1 + max(-r, 0) / reward_scale)`` with the clip applied first (``"log"``: monotone in
    the cost, and still informative while the state diverges). The unscaled reward stays in
    ``info["reward_raw"]``. The defaults are the RL comparison's (:data:`X_SCALE`,
    :data:`OBS_CLIP`, :data:`REWARD_SCALE`, :data:`REWARD_CLIP`, :data:`REWARD_TRANSFORM`).

    Fixed constants rather than running statistics (``VecNormalize``): the rewards of the first,
    diverging episodes are ~1e9 times those of a good policy, and running statistics would keep
    them forever.

    Parameters
    ----------
    env : gymnasium.Env
        An SDJLS environment, possibly wrapped (its ``unwrapped`` is an ``SDJLSEnv``).
    x_scale, obs_clip, reward_scale, reward_clip : float
        Positive constants.
    reward_transform : {"log", "linear"}

    Notes
    -----
    A policy trained behind this wrapper sees scaled observations; to run it on the raw
    environment (``benchmarks.evaluate``), wrap it with ``benchmarks.evaluate.RawEnvPolicy``.
    """

    def __init__(
        self,
        env: gym.Env,
        x_scale: float = X_SCALE,
        obs_clip: float = OBS_CLIP,
        reward_scale: float = REWARD_SCALE,
        reward_clip: float = REWARD_CLIP,
        reward_transform: str = REWARD_TRANSFORM,
    ) -> None:
        _check_env(env)
        super().__init__(env)
        self.n = _sdjls_base(env, "ScaleObservationReward").model.n
        self.x_scale = check_positive("x_scale", x_scale)
        self.obs_clip = check_positive("obs_clip", obs_clip)
        self.reward_scale = check_positive("reward_scale", reward_scale)
        self.reward_clip = check_positive("reward_clip", reward_clip)
        self.reward_transform = check_choice(
            "reward_transform", reward_transform, ("log", "linear")
        )
        raw_space = cast(spaces.Box, env.observation_space)  # the SDJLS env's Box
        low = self.observation(raw_space.low)
        high = self.observation(raw_space.high)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

    def observation(self, obs: np.ndarray) -> np.ndarray:
        """The scaled observation(s) of raw observation(s) ``(..., n + N + 1)`` or, with the
        mode hidden, ``(..., n + 1)``."""
        return scale_observation(obs, self.n, self.x_scale, self.obs_clip)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        return self.observation(obs), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["reward_raw"] = reward
        reward = max(float(reward), -self.reward_clip) / self.reward_scale
        if self.reward_transform == "log":  # -log(1 + cost / scale): monotone in the cost
            reward = -float(np.log1p(-min(reward, 0.0)))
        return self.observation(obs), reward, terminated, truncated, info


class TerminateOutside(gym.Wrapper):
    """End a training episode once ``max |x| > bound``, charging the rest of the horizon.

    The remaining steps of the horizon are charged at this step's reward, so that ending early
    is never better than going on. For training only: past the bound the scaled observation is
    saturated and a bounded input can no longer bring the state back, so without it most of a
    beginner's experience is spent in diverged states that teach nothing.

    Parameters
    ----------
    env : gymnasium.Env
        An SDJLS environment, possibly wrapped.
    bound : float
        Positive; the comparison's is :data:`TERMINATE_BOUND`.
    """

    def __init__(self, env: gym.Env, bound: float = TERMINATE_BOUND) -> None:
        _check_env(env)
        super().__init__(env)
        self.horizon = int(_sdjls_base(env, "TerminateOutside").horizon)
        self.bound = check_positive("bound", bound)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if not (terminated or truncated) and np.max(np.abs(info["state"])) > self.bound:
            reward = float(reward) * (1 + self.horizon - int(info["k"]))
            terminated = True
        return obs, reward, terminated, truncated, info


class FiniteHorizon(gym.Wrapper):
    """Report the end of the horizon as a termination (``terminated=True``, ``truncated=False``).

    The time ``k / T`` is part of the observation, so the problem is a finite-horizon one and
    nothing should be bootstrapped past ``x_T`` (stable-baselines3 bootstraps on truncation).
    """

    def __init__(self, env: gym.Env) -> None:
        _check_env(env)
        super().__init__(env)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, bool(terminated or truncated), False, info
