"""The belief of the hidden mode as part of an agent's observation.

:class:`BeliefObservation` wraps a training environment made with ``observe="state"``: its
observation ``[x, k / T]`` (scaled or not) gets the belief of ``theta_k`` appended,
``[x, k / T, belief (N)]``. The belief is :class:`controllers.ModeFilter`'s, stepped with the
exact states (``info["state"]``) and the inputs applied (``info["u"]``, clipped to the action
box), and starts each episode at the prior (the model's ``mode0``).

:class:`BeliefAgentPolicy` is an agent trained behind it, acting on the raw environment with the
mode hidden: like :class:`controllers.HiddenModePolicy` it keeps the filter per episode
(``reset(batch)``, ``act_hidden(x, k, u_applied)``), and it hands the agent the observation the
wrapper made, through :class:`benchmarks.core.policies.RawEnvPolicy` for the scalings and the
action's units. :func:`agent_policy` picks it or ``RawEnvPolicy`` from the training environment.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from benchmarks.core.policies import RawEnvPolicy, check_spaces
from controllers import ModeFilter
from sdjls_gym.env import SDJLSEnv
from sdjls_gym.errors import ImpossibleObservationError

__all__ = ["BeliefAgentPolicy", "BeliefObservation", "agent_policy", "filter_rows", "probabilities"]


def filter_rows(
    mode_filter: ModeFilter,
    log_prior: np.ndarray,
    log_belief: np.ndarray,
    x: np.ndarray,
    u: np.ndarray,
    x_next: np.ndarray,
    k: np.ndarray,
) -> np.ndarray:
    """One filter step of each row (logarithms, (B, N)): ``theta_{k+1}`` given ``x_{k+1}``.

    A row whose ``x_next`` is not finite (a diverged episode) or that no mode of positive belief
    can produce (a diverged episode's state replaced by the rollout) starts again from the
    prior, as :class:`controllers.HiddenModePolicy` does."""
    out = np.tile(log_prior, (len(x), 1))
    fine = np.all(np.isfinite(x_next), axis=1) & np.all(np.isfinite(x), axis=1)
    rows = np.flatnonzero(fine)
    if not rows.size:
        return out
    step = mode_filter.step_batch
    try:
        out[rows] = step(log_belief[rows], x[rows], u[rows], x_next[rows], k[rows], log=True)
        return out
    except ImpossibleObservationError:
        pass
    for i in rows:  # rare: find the rows, one at a time
        try:
            out[i] = step(log_belief[i : i + 1], x[i : i + 1], u[i : i + 1], x_next[i : i + 1],
                          k[i : i + 1], log=True)[0]  # fmt: skip
        except ImpossibleObservationError:
            pass  # the prior
    return out


def probabilities(log_belief: np.ndarray) -> np.ndarray:
    """The beliefs of log-beliefs (..., N), normalized."""
    belief = np.exp(log_belief - log_belief.max(axis=-1, keepdims=True))
    return belief / belief.sum(axis=-1, keepdims=True)


def _hidden_base(env: gym.Env, who: str) -> SDJLSEnv:
    base = env.unwrapped
    if not isinstance(base, SDJLSEnv):
        raise TypeError(f"{who} needs an SDJLSEnv underneath, got {type(base).__name__}")
    if base.observe != "state":
        raise ValueError(
            f"{who} needs an environment made with observe='state' (the mode hidden); this one "
            f"has observe = {base.observe!r}"
        )
    return base


class BeliefObservation(gym.Wrapper):
    """``[observation, belief of theta_k]``: the mode filter's belief appended (see the module).

    Parameters
    ----------
    env : gymnasium.Env
        An SDJLS environment made with ``observe="state"``, possibly wrapped.

    Attributes
    ----------
    mode_filter : controllers.ModeFilter
    belief : (N,) array
        The belief of the current ``theta_k`` (also ``info["belief"]``).
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        base = _hidden_base(env, "BeliefObservation")
        self.mode_filter = ModeFilter(base.model)
        with np.errstate(divide="ignore"):
            self.log_prior = np.log(self.mode_filter.initial_belief())
        N = base.model.N
        box = env.observation_space
        if not isinstance(box, gym.spaces.Box):
            raise TypeError(f"BeliefObservation needs a Box observation space, got {box}")
        low = np.concatenate([box.low, np.zeros(N)]).astype(np.float32)
        high = np.concatenate([box.high, np.ones(N)]).astype(np.float32)
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self._log = self.log_prior.copy()
        self._x = np.zeros(base.model.n)
        self._k = 0

    @property
    def belief(self) -> np.ndarray:
        return probabilities(self._log)

    def _observe(self, obs: np.ndarray) -> np.ndarray:
        return np.concatenate([np.asarray(obs, dtype=np.float32),
                               self.belief.astype(np.float32)])  # fmt: skip

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._log = self.log_prior.copy()
        self._x, self._k = np.array(info["state"], dtype=np.float64), int(info["k"])
        info["belief"] = self.belief
        return self._observe(obs), info

    def step(self, action: Any) -> tuple[np.ndarray, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        x_next = np.array(info["state"], dtype=np.float64)
        u = np.asarray(info["u"], dtype=np.float64)
        self._log = filter_rows(self.mode_filter, self.log_prior, self._log[None], self._x[None],
                                u[None], x_next[None], np.array([self._k]))[0]  # fmt: skip
        self._x, self._k = x_next, int(info["k"])
        info["belief"] = self.belief
        return self._observe(obs), reward, terminated, truncated, info


class _BeliefFed:
    """The agent seen from the environment inside :class:`BeliefObservation`: its observations
    get the current beliefs appended before the agent's ``predict``."""

    def __init__(self, agent: Any, observation_space: Any) -> None:
        self.agent, self.observation_space = agent, observation_space
        self.action_space = getattr(agent, "action_space", None)
        self.belief = np.zeros((0, 0))

    def predict(self, observation: np.ndarray, deterministic: bool = True) -> tuple[Any, Any]:
        obs = np.concatenate([np.asarray(observation, dtype=np.float32),
                              self.belief.astype(np.float32)], axis=-1)  # fmt: skip
        return self.agent.predict(obs, deterministic=deterministic)


class BeliefAgentPolicy:
    """An agent trained behind :class:`BeliefObservation`, on the raw environment with the mode
    hidden: ``reset(batch)`` and ``act_hidden(x, k, u_applied)`` (the protocol's hidden-mode
    policy, :func:`benchmarks.core.montecarlo.rollout`).

    Parameters
    ----------
    agent : object
        With ``predict(obs, deterministic=True)`` on the observations of ``env``.
    env : BeliefObservation
        The agent's training environment (outermost wrapper :class:`BeliefObservation`).

    Notes
    -----
    Not thread-safe: the beliefs of the episodes change at every call.
    """

    def __init__(self, agent: Any, env: gym.Env) -> None:
        if not isinstance(env, BeliefObservation):
            raise TypeError(
                f"env is a {type(env).__name__}; expected the agent's training environment "
                "wrapped in BeliefObservation"
            )
        check_spaces(agent, env.observation_space, env.action_space, "env (BeliefObservation)")
        self.mode_filter, self.log_prior = env.mode_filter, env.log_prior
        self._fed = _BeliefFed(agent, env.env.observation_space)
        self.raw = RawEnvPolicy(self._fed, env.env)
        self.model, self.horizon = self.raw.model, self.raw.horizon
        #: where evaluate scores the agent: its training environment's raw one (mode hidden)
        self.env_id, self.env_kwargs = self.raw.env_id, self.raw.env_kwargs
        self._log: np.ndarray | None = None
        self._x = self._u = np.zeros((0, 0))
        self._k = np.zeros(0, dtype=np.int64)

    def reset(self, batch: int) -> np.ndarray:
        """Start ``batch`` episodes at the prior; returns their beliefs (batch, N)."""
        self._log = np.tile(self.log_prior, (int(batch), 1))
        self._x = np.zeros((int(batch), self.model.n))
        self._u = np.zeros((int(batch), self.model.m))
        self._k = np.full(int(batch), -1, dtype=np.int64)
        return probabilities(self._log)

    def act_hidden(
        self, x: Any, k: Any, u_applied: Any = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Decisions for states ``x`` (B, n) at times ``k`` (B,): a row at ``k == 0`` starts its
        episode at the prior; a row at ``k > 0`` steps its belief from its last call with the
        inputs applied then (``u_applied`` (B, m); None: this policy's answers)."""
        x = np.asarray(x, dtype=np.float64)
        B = len(x)
        k = np.broadcast_to(np.asarray(k, dtype=np.int64), (B,))
        if self._log is None or len(self._log) != B:
            if np.any(k != 0):
                raise ValueError(f"x has {B} rows at k > 0 but the policy holds no such "
                                 f"episodes; call reset({B}) at the episodes' start")  # fmt: skip
            self.reset(B)
        assert self._log is not None
        log = self._log.copy()
        moving = np.flatnonzero(k > 0)
        if moving.size:
            if np.any(self._k[moving] != k[moving] - 1):
                row = int(moving[np.flatnonzero(self._k[moving] != k[moving] - 1)[0]])
                raise ValueError(f"k[{row}] = {int(k[row])} does not follow the row's last "
                                 f"call at k = {int(self._k[row])}")  # fmt: skip
            u_prev = self._u if u_applied is None else np.asarray(u_applied, dtype=np.float64)
            log[moving] = filter_rows(self.mode_filter, self.log_prior, log[moving],
                                      self._x[moving], u_prev[moving], x[moving],
                                      self._k[moving])  # fmt: skip
        log[k == 0] = self.log_prior
        belief = probabilities(log)
        self._fed.belief = belief
        u, info = self.raw.act_batch(x, np.zeros(B, dtype=np.int64), k)
        self._log, self._x, self._u, self._k = (
            log,
            x.copy(),
            np.array(u, dtype=np.float64),
            k.copy(),
        )
        return u, {**info, "belief": belief}


def agent_policy(agent: Any, env: gym.Env) -> BeliefAgentPolicy | RawEnvPolicy:
    """``agent`` acting on the raw environment: a :class:`BeliefAgentPolicy` when its training
    environment ``env`` appends the belief (:class:`BeliefObservation`), else
    :class:`~benchmarks.core.policies.RawEnvPolicy` (a recurrent agent keeps its state there)."""
    if isinstance(env, BeliefObservation):
        return BeliefAgentPolicy(agent, env)
    return RawEnvPolicy(agent, env)
