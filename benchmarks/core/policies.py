"""Policies behind the controllers' ``act_batch(x, mode, k)``, for :mod:`benchmarks.evaluate`.

* :class:`RawEnvPolicy`: an agent trained behind rescaling wrappers, acting on the raw
  environment (actions in units of ``u``);
* :func:`as_controller`: any policy (a controller, an object with ``predict``, a callable
  ``obs -> action``) behind ``act_batch`` / ``act``.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np

from sdjls_gym.env import SDJLSEnv
from sdjls_gym.errors import NotANumberError
from sdjls_gym.messages import a_type, describe
from sdjls_gym.observation import decode_observation, encode_observation
from sdjls_gym.validation import check_numbers
from sdjls_gym.wrappers import ResidualAction, ScaleObservationReward, scale_observation

__all__ = [
    "RawEnvPolicy",
    "as_controller",
    "check_policy",
    "check_spaces",
    "raw_env_of",
    "unwrap_vec_env",
]

#: How a scored agent that acts in other units should be wrapped (the errors' advice).
_ADVICE = (
    "an agent trained behind wrappers is scored as RawEnvPolicy(agent, train_env) "
    "(python -m benchmarks.evaluate: --train-env)"
)


def check_spaces(agent: Any, observation_space: Any, action_space: Any, where: str) -> None:
    """Refuse an agent whose ``observation_space`` / ``action_space`` (SB3 models and policies
    have both) differ from those of the environment it is about to act on (``where``): its
    observations or actions would be read in other units, and every episode could diverge
    without a word. An agent without these attributes is not checked."""
    for kind, env_space in (("observation", observation_space), ("action", action_space)):
        space = getattr(agent, f"{kind}_space", None)
        if isinstance(space, gym.spaces.Space) and space != env_space:
            raise ValueError(
                f"the agent's {kind} space {space} is not the {kind} space {env_space} of "
                f"{where}; {_ADVICE}, with the environment it was trained on"
            )


def raw_env_of(env: Any) -> tuple[str, dict[str, Any]]:
    """``(env_id, env_kwargs)`` that make ``env``'s raw environment again: its spec's id and
    keyword arguments, or for an ``SDJLSEnv`` built without ``gym.make``, ``SDJLS-v0`` with its
    model, horizon and bounds."""
    base = env.unwrapped
    if not isinstance(base, SDJLSEnv):
        raise TypeError(f"env has a {type(base).__name__} underneath; expected an SDJLSEnv")
    spec = base.spec
    if spec is not None:
        return spec.id, dict(spec.kwargs)
    return "SDJLS-v0", {
        "model": base.model,
        "horizon": int(base.horizon),
        "action_bound": np.asarray(_box(base.action_space, "the SDJLSEnv").high, dtype=np.float64),
        "divergence_bound": float(base.divergence_bound),
    }


def _box(space: gym.Space[Any], where: str) -> gym.spaces.Box:
    """``space`` (the action space of ``where``), which must be a Box to be rescaled."""
    if not isinstance(space, gym.spaces.Box):
        raise TypeError(f"{where} has the action space {space}; expected a gymnasium.spaces.Box")
    return space


def _actions(value: Any, m: int, obs: np.ndarray) -> np.ndarray:
    """A policy's answer read by ``env.step``'s rule (:func:`sdjls_gym.validation.check_numbers`):
    ``"1.0"``, ``True`` or None are not actions."""
    if value is None:
        raise NotANumberError(
            f"the policy returned None for the observation {describe(obs)}; expected "
            f"{m} number(s) per observation (an action, as env.step takes)"
        )
    return check_numbers("the policy's action", value, what=f"{m} number(s) per observation")


class _Predict:
    """``agent.predict`` on a batch of observations, deterministic; an agent whose ``predict``
    takes ``state`` and ``episode_start`` (stable-baselines3's signature, sb3-contrib's
    recurrent policies) gets its state back at the next step and ``episode_start`` True at an
    episode's first step, as SB3's own ``evaluate_policy`` does."""

    def __init__(self, agent: Any) -> None:
        self.agent = agent
        params: Mapping[str, inspect.Parameter]
        try:
            params = inspect.signature(agent.predict).parameters
        except (TypeError, ValueError):
            params = {}
        self.stateful = "state" in params and "episode_start" in params
        self.state: Any = None
        self.rows: int | None = None  # the batch the state belongs to

    def __call__(self, obs: np.ndarray, k: np.ndarray | None = None) -> Any:
        if not self.stateful:
            out = self.agent.predict(obs, deterministic=True)
        else:
            B = len(obs)
            start = np.ones(B, dtype=bool) if k is None else np.asarray(k) == 0
            if self.rows != B:  # another batch (the timing states): a fresh state
                self.state, start = None, np.ones(B, dtype=bool)
            out = self.agent.predict(
                obs, state=self.state, episode_start=start, deterministic=True
            )  # fmt: skip
        if not (isinstance(out, tuple) and len(out) == 2):
            raise TypeError(
                f"the agent's predict returned {describe(out)}; expected stable-baselines3's "
                "(actions, state)"
            )
        if self.stateful:
            self.state, self.rows = out[1], len(obs)
        return out[0]


class _ObservationPolicy:
    """A ``predict`` or callable policy behind the controllers' ``act_batch`` / ``act``."""

    def __init__(self, policy: Any, spec: Any) -> None:
        if callable(getattr(policy, "predict", None)):
            self.call: Any = _Predict(policy)
        elif callable(policy):
            self.call = lambda obs, k=None: policy(obs)
        else:  # checked by as_controller first
            raise TypeError(f"policy is {a_type(policy)}")
        self.spec, self.m = spec, spec.model.m
        # decided at the first batch; a stateful agent is always called on the whole batch
        self.batched: bool | None = True if getattr(self.call, "stateful", False) else None

    def _one(self, obs: np.ndarray) -> np.ndarray:
        a = _actions(self.call(obs), self.m, obs)
        if a.size != self.m:
            raise ValueError(
                f"the policy returned {describe(a)} (shape {a.shape}) for one observation; "
                f"expected {self.m} number(s), the input of {self.spec.env_id} (evaluate's env_id)"
            )
        return a.reshape(self.m)

    def _rows(self, obs: np.ndarray) -> np.ndarray:
        return np.stack([self._one(o) for o in obs])

    def _whole(self, obs: np.ndarray, k: np.ndarray) -> np.ndarray:
        B = len(obs)
        a = _actions(self.call(obs, k), self.m, obs[0])
        if a.shape not in ((B, self.m), (B,) * (self.m == 1)):
            raise ValueError(
                f"the policy returned shape {a.shape} for {B} observations; expected "
                f"({B}, {self.m}), the inputs of {self.spec.env_id} (evaluate's env_id)"
            )
        return a.reshape(B, self.m)

    def _batch(self, obs: np.ndarray, k: np.ndarray) -> np.ndarray:
        B = len(obs)
        if self.batched is False:
            return self._rows(obs)
        if self.batched:
            return self._whole(obs, k)
        # undecided: one call on all rows, checked against single calls on up to 8 distinct rows
        # (decided only on a batch with distinct rows: a batch of equal rows cannot show a
        # policy that mixes up its rows)
        a: np.ndarray | None
        try:
            a = _actions(self.call(obs), self.m, obs[0])
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
        obs = encode_observation(s.model, x, mode, k, s.horizon, s.divergence_bound, s.observe)
        u = self._batch(obs, np.asarray(k))
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


def _refuse_class(name: str, value: Any) -> None:
    if isinstance(value, type):  # evaluate(PPO): a class is callable, and has predict
        cls = value.__name__
        example = (
            f"e.g. {cls}.load(path) or the object that {cls}(...).learn(...) returns"
            if callable(getattr(value, "load", None))
            else f"an instance, {cls}(...)"
        )
        raise TypeError(
            f"{name} = {value.__module__}.{value.__qualname__} is a class, not an agent; pass a "
            f"trained agent, {example}"
        )


def check_policy(policy: Any) -> None:
    """Refuse (``TypeError``) what cannot be scored: a class instead of an agent, or an object
    with neither ``act_batch``, ``predict`` nor ``__call__``."""
    _refuse_class("policy", policy)
    if not (
        callable(getattr(policy, "act_hidden", None))
        or callable(getattr(policy, "act_batch", None))
        or callable(getattr(policy, "predict", None))
        or callable(policy)
    ):
        raise TypeError(
            f"policy = {describe(policy)} is {a_type(policy)}; expected an object with "
            "predict(obs, deterministic=True) (stable-baselines3's), a callable obs -> action, "
            "or a controller with act_batch(x, mode, k) and act(x, mode, k)"
        )


def as_controller(policy: Any, spec: Any) -> Any:
    """``policy`` behind ``act_batch(x, mode, k)`` / ``act(x, mode, k)`` (see the module doc).

    An agent with SB3's ``observation_space`` and ``action_space`` must act on the raw
    environment's (``spec.observation_space``, ``spec.action_space``): see :func:`check_spaces`.
    """
    check_policy(policy)
    if callable(getattr(policy, "act_hidden", None)):  # keeps its own belief of the mode
        return policy
    if callable(getattr(policy, "act_batch", None)) and callable(getattr(policy, "act", None)):
        return policy
    where = f"the raw environment it is scored on ({spec.env_id})"
    check_spaces(policy, spec.observation_space, spec.action_space, where)
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
    an error. An agent trained under SB3's ``VecNormalize`` sees normalized observations: pass
    the ``VecNormalize`` (the training ``VecEnv`` itself, or ``vec_normalize=``, e.g.
    ``VecNormalize.load(path, venv)``), whose saved statistics are applied, frozen. An agent
    whose ``observation_space`` / ``action_space`` differ from ``env``'s is refused
    (:func:`check_spaces`): ``env`` is not the one it was trained on. A recurrent agent
    (sb3-contrib's ``RecurrentPPO``) keeps its state from step to step of an episode.

    Parameters
    ----------
    agent : object
        With ``predict(obs, deterministic=True)``: an SB3 model or policy.
    env : gymnasium.Env or stable_baselines3 VecEnv
        The training environment (wrapped), or one built the same way; or the training
        ``VecEnv`` (a ``DummyVecEnv``, possibly under ``VecNormalize`` and ``VecMonitor``).
    vec_normalize : stable_baselines3 VecNormalize, optional
        The normalization the agent was trained under. Default: the one in ``env``, else the
        agent's own (``agent.get_vec_normalize_env()``), else none.

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

    def __init__(self, agent: Any, env: Any, vec_normalize: Any = None) -> None:
        _refuse_class("agent", agent)
        if not callable(getattr(agent, "predict", None)):
            raise TypeError(
                f"agent = {describe(agent)} is {a_type(agent)}; expected an object with "
                "predict(obs, deterministic=True), such as a stable-baselines3 model"
            )
        env, found = unwrap_vec_env(env)
        if not isinstance(env, gym.Env):
            raise TypeError(
                f"env = {describe(env)} is {a_type(env)}; expected the agent's training "
                "environment, a gymnasium.Env or a stable-baselines3 DummyVecEnv"
            )
        base = env.unwrapped
        if not isinstance(base, SDJLSEnv):
            raise TypeError(f"env has a {type(base).__name__} underneath; expected an SDJLSEnv")
        check_spaces(agent, env.observation_space, env.action_space, "env (RawEnvPolicy's env)")
        if vec_normalize is None:
            vec_normalize = found
        if vec_normalize is None and callable(getattr(agent, "get_vec_normalize_env", None)):
            vec_normalize = agent.get_vec_normalize_env()
        self.normalization = None if vec_normalize is None else _normalization(vec_normalize)
        self.agent, self.model = agent, base.model
        #: what the training environment showed: the mode (``"mode"``) or not (``"state"``)
        self.observe_setting = str(base.observe)
        #: the raw environment's id and keyword arguments: where evaluate scores the agent
        self.env_id, self.env_kwargs = raw_env_of(base)
        self._predict = _Predict(agent)
        self.horizon, self.divergence_bound = int(base.horizon), float(base.divergence_bound)
        self.action_bound = float(np.max(_box(base.action_space, "the SDJLSEnv").high))
        box = _box(env.action_space, "env (RawEnvPolicy's env)")
        self.low, self.high = box.low.astype(np.float64), box.high.astype(np.float64)
        self.scaling: tuple[float, float] | None = None
        self.actions: list[tuple[str, Any]] = []  # outermost first: how an action reaches u
        e = env
        while isinstance(e, gym.Wrapper):
            inner = e.env
            if isinstance(e, ScaleObservationReward):
                self.scaling = (e.x_scale, e.obs_clip)
            elif isinstance(e, gym.wrappers.RescaleAction):
                outer, inner_box = (
                    _box(e.action_space, "RescaleAction"),
                    _box(inner.action_space, "the env RescaleAction wraps"),
                )
                lo, hi = outer.low, outer.high
                in_lo, in_hi = inner_box.low, inner_box.high
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
        """The observations the agent was trained on, for states (B, n): (B, n + N + 1), or
        (B, n + 1) for an agent trained with the mode hidden (``mode`` then unused)."""
        obs = encode_observation(
            self.model, x, mode, k, self.horizon, self.divergence_bound, self.observe_setting
        )
        if self.scaling is not None:
            obs = scale_observation(obs, self.model.n, *self.scaling)
        if self.normalization is not None:  # VecNormalize.normalize_obs on float32 observations
            mean, var, epsilon, clip = self.normalization
            obs = np.asarray(obs, dtype=np.float32)
            obs = np.clip((obs - mean) / np.sqrt(var + epsilon), -clip, clip).astype(np.float32)
        return obs

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """``u`` (B, m) for states ``x`` (B, n), modes (B,), times (B,); info as a controller's."""
        x = np.asarray(x, dtype=np.float64)
        mode = np.asarray(mode, dtype=np.int64)
        obs = self.observe(x, mode, k)
        a = _actions(self._predict(obs, np.asarray(k)), len(self.low), obs[0])
        v = np.clip(a.reshape(len(x), -1), self.low, self.high)
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
        x, mode, k = decode_observation(
            self.model, np.atleast_2d(observation), self.horizon, observe=self.observe_setting
        )
        if mode is None:  # trained with the mode hidden: the agent never reads it
            mode = np.zeros(len(x), dtype=np.int64)
        u = self.act_batch(x, mode, k)[0].astype(np.float32)
        return (u[0] if single else u), state


def unwrap_vec_env(env: Any) -> tuple[Any, Any]:
    """``(the gymnasium.Env of env, the VecNormalize around it or None)`` for an SB3 VecEnv;
    ``(env, None)`` for anything else."""
    try:
        from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecMonitor, VecNormalize
    except ImportError:  # without stable-baselines3 there is no VecEnv to unwrap
        return env, None
    if not isinstance(env, VecEnv):
        return env, None
    norm, e = None, env
    while isinstance(e, VecEnvWrapper):
        if isinstance(e, VecNormalize):
            norm = norm if norm is not None else e
        elif not isinstance(e, VecMonitor):
            raise ValueError(
                f"env is wrapped in {type(e).__name__}, which RawEnvPolicy cannot undo; it knows "
                "VecNormalize and VecMonitor around a DummyVecEnv"
            )
        e = e.venv
    envs = getattr(e, "envs", None)
    if not envs:
        raise TypeError(
            f"env is a {type(e).__name__}, whose environments live in other processes; pass one "
            "environment built as the training one (a gymnasium.Env), and its VecNormalize as "
            "vec_normalize="
        )
    return envs[0], norm


def _normalization(vec_normalize: Any) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """The frozen statistics ``(mean, var, epsilon, clip_obs)`` of a ``VecNormalize``; None if
    it does not normalize observations."""
    rms = getattr(vec_normalize, "obs_rms", None)
    if rms is None or not hasattr(rms, "mean") or not hasattr(vec_normalize, "clip_obs"):
        raise TypeError(
            f"vec_normalize = {describe(vec_normalize)} is {a_type(vec_normalize)}; expected a "
            "stable-baselines3 VecNormalize with observation statistics (obs_rms)"
        )
    if not getattr(vec_normalize, "norm_obs", True):
        return None
    return (
        np.array(rms.mean, dtype=np.float64),
        np.array(rms.var, dtype=np.float64),
        float(vec_normalize.epsilon),
        float(vec_normalize.clip_obs),
    )
