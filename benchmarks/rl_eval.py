"""Training environments for stable-baselines3 agents, and their evaluation next to the controllers.

Every controller, model-based or learned, is scored by :func:`benchmarks.montecarlo.rollout` on
the same :class:`~sdjls_gym.SDJLSVectorEnv` with the same seed, so all of them see the same
noise (common random numbers). A trained agent enters through :class:`SB3Policy`, an adapter
with the controllers' ``act_batch(x, mode, k)``: it encodes the observation exactly as the
training environment did and maps the agent's action in ``[-1, 1]`` back to ``u``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from numbers import Real
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import RescaleAction

from benchmarks.montecarlo import Rollouts, mean_ci, rollout, wilson
from sdjls_gym import SDJLSModel
from sdjls_gym.env import encode_observation
from sdjls_gym.wrappers import ResidualAction, ViolationPenalty

__all__ = [
    "ACTION_KINDS",
    "FiniteHorizon",
    "ScaleObservationReward",
    "make_train_env",
    "SB3Policy",
    "evaluate",
    "score",
    "decision_time",
]

#: ``"u"``: the agent chooses ``u`` (rescaled to [-1, 1]); ``"residual"``: it chooses the offset
#: ``nu`` of ``u = K_theta x + nu`` (rescaled to [-1, 1]).
ACTION_KINDS = ("u", "residual")


def scale_observation(obs: np.ndarray, n: int, x_scale: float, obs_clip: float) -> np.ndarray:
    """``[clip(x / x_scale, +-obs_clip), one-hot, k / T]``; ``obs`` (..., n + N + 1) float32."""
    out = np.array(obs, dtype=np.float32, copy=True)
    out[..., :n] = np.clip(out[..., :n] / x_scale, -obs_clip, obs_clip)
    return out


class ScaleObservationReward(gym.Wrapper):
    """Fixed scaling for learning: ``x / x_scale`` (clipped) and ``max(r, -reward_clip) / reward_scale``.

    Fixed constants rather than running statistics (``VecNormalize``): the rewards of the first,
    diverging episodes are ~1e9 times those of a good policy, and running statistics would keep
    them forever. The unscaled reward stays in ``info["reward_raw"]``.
    """

    def __init__(
        self,
        env: gym.Env,
        x_scale: float,
        obs_clip: float,
        reward_scale: float,
        reward_clip: float,
        reward_transform: str = "linear",
    ) -> None:
        super().__init__(env)
        if reward_transform not in ("linear", "log"):
            raise ValueError(f"reward_transform = {reward_transform!r}; expected 'linear' or 'log'")
        self.n = env.unwrapped.model.n
        self.x_scale, self.obs_clip = float(x_scale), float(obs_clip)
        self.reward_scale, self.reward_clip = float(reward_scale), float(reward_clip)
        self.reward_transform = reward_transform
        low = scale_observation(env.observation_space.low, self.n, x_scale, obs_clip)
        high = scale_observation(env.observation_space.high, self.n, x_scale, obs_clip)
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        return scale_observation(obs, self.n, self.x_scale, self.obs_clip), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["reward_raw"] = reward
        reward = max(float(reward), -self.reward_clip) / self.reward_scale
        if self.reward_transform == "log":  # -log(1 + cost / scale): monotone in the cost
            reward = -float(np.log1p(-min(reward, 0.0)))
        obs = scale_observation(obs, self.n, self.x_scale, self.obs_clip)
        return obs, reward, terminated, truncated, info


class TerminateOutside(gym.Wrapper):
    """End a training episode once ``max |x| > bound`` (the observation is saturated there and a
    bounded input can no longer bring the state back), charging the remaining steps of the horizon
    at the reward of this step, so that ending early is never better than going on.

    Only for training: without it most of a beginner's experience is spent in diverged states
    that teach nothing. Evaluation runs the plain environment.
    """

    def __init__(self, env: gym.Env, bound: float) -> None:
        super().__init__(env)
        self.bound = float(bound)
        self.horizon = int(env.unwrapped.horizon)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if not (terminated or truncated) and np.max(np.abs(info["state"])) > self.bound:
            reward = reward * (1 + self.horizon - int(info["k"]))
            terminated = True
        return obs, reward, terminated, truncated, info


class FiniteHorizon(gym.Wrapper):
    """The end of the 20-step horizon is a true end of the task: report it as a termination.

    The time ``k / T`` is part of the observation, so the problem is a finite-horizon one and
    nothing should be bootstrapped past ``x_T`` (SB3 bootstraps on truncation).
    """

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, bool(terminated or truncated), False, info


def make_train_env(
    action_kind: str,
    beta: float | None,
    env_hp: dict[str, float],
    K: np.ndarray | None = None,
    nu_bound: float = 100.0,
    u_bound: float | None = None,
) -> gym.Env:
    """``SDJLS-Macro-v0`` wrapped for training one agent.

    Parameters
    ----------
    action_kind : {"u", "residual"}
        See :data:`ACTION_KINDS`.
    beta : float or None
        Violation penalty of :class:`~sdjls_gym.wrappers.ViolationPenalty`; ``None`` trains on
        the reward alone (no wrapper). The Lagrangian variant passes its initial ``beta`` and
        changes it with ``env.set_wrapper_attr("beta", ...)``.
    env_hp : dict
        :data:`benchmarks.rl_hyperparams.ENV`.
    K : (N, m, n) array
        Gains under a residual agent.
    nu_bound : float
        Bound on ``|nu|`` of a residual agent.
    u_bound : float, optional
        Bound on ``|u|`` of an agent acting on ``u``: the environment is made with
        ``action_bound=u_bound``, so the agent's action ``a`` in [-1, 1] is ``u = u_bound * a``.
        ``None`` keeps the registered bound (200). Ignored for residual agents. Evaluate such an
        agent with ``SB3Policy(..., action_bound=u_bound)``.

    Returns
    -------
    gymnasium.Env
        Observation ``[x / x_scale, one-hot, k / T]``, action in ``[-1, 1]``.
    """
    if action_kind not in ACTION_KINDS:
        raise ValueError(f"action_kind = {action_kind!r}; expected one of {ACTION_KINDS}")
    if u_bound is not None and not (
        isinstance(u_bound, Real)
        and not isinstance(u_bound, bool)
        and np.isfinite(u_bound)
        and u_bound > 0
    ):
        raise ValueError(f"u_bound = {u_bound!r}; expected a finite positive float or None")
    if action_kind == "residual" or u_bound is None:
        env = gym.make("SDJLS-Macro-v0")
    else:
        env = gym.make("SDJLS-Macro-v0", action_bound=float(u_bound))
    if action_kind == "residual":
        if K is None:
            raise ValueError("a residual agent needs the gains K (N, m, n)")
        env = ResidualAction(env, K, nu_bound)
    one = np.ones(env.action_space.shape, dtype=np.float32)
    env = RescaleAction(env, -one, one)
    if beta is not None:
        env = ViolationPenalty(env, beta)
    scale = {k: v for k, v in env_hp.items() if k != "terminate_bound"}
    env = ScaleObservationReward(env, **scale)
    if env_hp.get("terminate_bound") is not None:
        env = TerminateOutside(env, env_hp["terminate_bound"])
    return FiniteHorizon(env)


class SB3Policy:
    """A trained stable-baselines3 agent behind the controllers' ``act_batch`` interface.

    Parameters
    ----------
    agent : stable_baselines3 BaseAlgorithm
        Trained on :func:`make_train_env` (action in [-1, 1]).
    model : SDJLSModel
    action_kind : {"u", "residual"}
    action_bound : float
        ``|u|`` bound of the environment (``"u"`` agents: ``u = action_bound * a``).
    env_hp : dict
        The scaling used in training (:data:`benchmarks.rl_hyperparams.ENV`).
    K : (N, m, n) array, optional
        Gains of a residual agent: ``u = K_theta x + nu_bound * a``.
    nu_bound : float
    horizon, divergence_bound
        As for the environment (the observation's ``k / horizon`` and clipping).
    """

    def __init__(
        self,
        agent: Any,
        model: SDJLSModel,
        action_kind: str,
        action_bound: float,
        env_hp: dict[str, float],
        K: np.ndarray | None = None,
        nu_bound: float = 100.0,
        horizon: int = 20,
        divergence_bound: float = 1e6,
    ) -> None:
        if action_kind not in ACTION_KINDS:
            raise ValueError(f"action_kind = {action_kind!r}; expected one of {ACTION_KINDS}")
        if action_kind == "residual" and K is None:
            raise ValueError("a residual agent needs the gains K (N, m, n)")
        self.agent, self.model, self.action_kind = agent, model, action_kind
        self.action_bound, self.nu_bound = float(action_bound), float(nu_bound)
        self.env_hp = dict(env_hp)
        self.K = None if K is None else np.asarray(K, dtype=np.float64)
        self.horizon, self.divergence_bound = int(horizon), float(divergence_bound)

    def observe(self, x: np.ndarray, mode: np.ndarray, k: np.ndarray) -> np.ndarray:
        """The scaled observations (B, n + N + 1) the agent was trained on."""
        obs = encode_observation(self.model, x, mode, k, self.horizon, self.divergence_bound)
        return scale_observation(obs, self.model.n, self.env_hp["x_scale"], self.env_hp["obs_clip"])

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """``u`` (B, m) for states ``x`` (B, n), modes (B,), times (B,); info as the controllers'."""
        x = np.asarray(x, dtype=np.float64)
        mode = np.asarray(mode, dtype=np.int64)
        a, _ = self.agent.predict(self.observe(x, mode, k), deterministic=True)
        a = np.clip(np.asarray(a, dtype=np.float64).reshape(len(x), -1), -1.0, 1.0)
        if self.action_kind == "residual":
            nu = self.nu_bound * a
            u = np.einsum("bij,bj->bi", self.K[mode], x) + nu
        else:
            nu = np.zeros_like(a)
            u = self.action_bound * a
        B = len(x)
        info = {
            "nu": nu,
            "rho": np.zeros(B),
            "cost": self.model.stage_cost(
                x, mode, np.clip(u, -self.action_bound, self.action_bound)
            ),
            "status": np.full(B, "policy", dtype=object),
            "ok": np.ones(B, dtype=bool),
        }
        return u, info

    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """One decision: ``act_batch`` on a batch of one."""
        u, info = self.act_batch(np.asarray(x)[None], np.array([mode]), np.array([k]))
        return u[0], {key: value[0] for key, value in info.items()}


def evaluate(
    model: SDJLSModel,
    controller: Any,
    episodes: int,
    seed: int,
    horizon: int = 20,
    action_bound: float = 200.0,
    divergence_bound: float = 1e6,
) -> tuple[Rollouts, dict[str, Any]]:
    """Score ``controller`` on ``episodes`` episodes with noise seed ``seed``: ``(rollouts, stats)``.

    See :func:`score` for the statistics.
    """
    ro = rollout(model, controller, episodes, horizon, seed, action_bound)
    return ro, score(ro, divergence_bound)


def score(ro: Rollouts, divergence_bound: float = 1e6) -> dict[str, Any]:
    """The statistics of the report for one set of rollouts.

    Returns
    -------
    dict
        ``episodes``, ``steps``; ``episode_cost`` mean with a Student-t 95% interval (over
        episodes), and its median; ``violation`` per-step frequency of any violated row with a
        95% Wilson interval (over episodes x steps, as if the steps were independent) and, as a
        check of that, ``episode_t95``: a Student-t interval over the episodes' shares of
        violated steps, which allows for any dependence between the steps of an episode (cut to
        [0, 1]); ``diverged`` episodes (``max |x| > divergence_bound`` at some step; such an
        episode's cost is the cost up to divergence, and every step after it counts as violated:
        see :class:`benchmarks.montecarlo.Rollouts`). The intervals need at least two episodes:
        one raises ``ValueError``.
    """
    costs = ro.episode_cost
    violations = ro.any_violation
    total = violations.size
    count = int(violations.sum())
    lo, hi = wilson(count, total)
    # the episodes are independent; the steps of one episode need not be
    _, elo, ehi = mean_ci(violations.mean(axis=1))
    mean, clo, chi = mean_ci(costs, floor=0.0)  # a cost is >= 0
    diverged = np.any(np.abs(ro.x) > divergence_bound, axis=(1, 2))
    return {
        "episodes": int(ro.runs),
        "steps": int(violations.shape[1]),
        "episode_cost": {
            "mean": float(mean),
            "ci95": [float(clo), float(chi)],
            "median": float(np.median(costs)),
        },
        "violation": {
            "freq": count / total,
            "wilson95": [float(lo), float(hi)],
            "episode_t95": [max(float(elo), 0.0), min(float(ehi), 1.0)],
        },
        "diverged": int(diverged.sum()),
    }


def decision_time(
    controller: Any,
    x: np.ndarray,
    mode: np.ndarray,
    k: np.ndarray,
    single: int = 50,
    repeats: int = 3,
) -> dict[str, float]:
    """Mean decision time per state, in seconds.

    ``batched``: the best of ``repeats`` calls of ``act_batch`` on all of ``x`` (B, n), divided
    by B. ``single``: the mean over ``single`` states of one call of ``act`` (one state, as a
    controller in the loop would be called).
    """
    B = len(x)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        controller.act_batch(x, mode, k)
        best = min(best, time.perf_counter() - t0)
    idx = np.linspace(0, B - 1, min(single, B)).astype(int)
    t0 = time.perf_counter()
    for i in idx:
        controller.act(x[i], int(mode[i]), int(k[i]))
    one = (time.perf_counter() - t0) / len(idx)
    return {"batched": float(best / B), "single": float(one), "batch_size": int(B)}


@dataclass
class DecisionStates:
    """A sample of visited states for timing: ``x`` (B, n), ``mode`` (B,), ``k`` (B,)."""

    x: np.ndarray
    mode: np.ndarray
    k: np.ndarray

    @classmethod
    def from_rollouts(cls, ro: Rollouts, size: int, seed: int = 0) -> DecisionStates:
        """``size`` states ``(x_k, theta_k, k)``, k < T, drawn from ``ro``.

        Only states the controller decided on: none from after a diverged episode ended (so
        none beyond the environment's divergence bound).
        """
        runs, T = ro.ended.shape
        rng = np.random.default_rng(seed)
        lived = np.flatnonzero(~ro.ended.ravel())
        i, k = np.divmod(lived[rng.integers(0, lived.size, size)], T)
        x = ro.x[i, k]
        return cls(x=x, mode=ro.mode[i, k].astype(np.int64), k=k.astype(np.int64))
