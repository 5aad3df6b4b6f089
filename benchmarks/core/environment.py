"""The raw environment a policy is scored on, and the statistics of its rollouts.

:func:`resolve_env` makes ``gym.make(env_id, **env_kwargs)`` once and reads what the rollouts
need (:class:`TaskEnv`); :func:`rollout_statistics` turns rollouts into the fields of
:class:`benchmarks.evaluate.Score`. Both are re-exported by :mod:`benchmarks.evaluate`; they live
here so that training (:mod:`benchmarks.rl.train`) uses them without importing the scoring
protocol, which loads kept runs (``--run``) through :mod:`benchmarks.rl.runs`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from benchmarks.core.montecarlo import Rollouts
from benchmarks.core.policies import raw_env_of
from benchmarks.core.reference import task_of
from benchmarks.core.stats import mean_ci, wilson
from sdjls_gym import SDJLSModel
from sdjls_gym.env import SDJLSEnv
from sdjls_gym.systems import Task
from sdjls_gym.validation import check_int

__all__ = [
    "DEFAULT_ENV_ID",
    "TaskEnv",
    "check_fits",
    "check_hidden",
    "infer_env",
    "is_hidden_policy",
    "resolve_env",
    "rollout_statistics",
]

#: The task of a policy that says nothing of its own (a callable, an SB3 agent without its
#: training environment): the paper's example.
DEFAULT_ENV_ID = "SDJLS-Macro-v0"


# ----------------------------------------------------------------------------- environments
@dataclass(frozen=True)
class TaskEnv:
    """What the rollouts need to know of ``gym.make(env_id, **env_kwargs)``."""

    model: SDJLSModel
    horizon: int
    action_bound: float | np.ndarray  # one bound, or one per input (m,)
    divergence_bound: float
    paper_system: bool  # the macro example
    env_id: str = "SDJLS-Macro-v0"
    observation_space: Any = None  # the raw environment's: what a scored agent must act on
    action_space: Any = None
    task: Task | None = None  # the suite's task of this system: its reference curve applies
    observe: str = "mode"  # "state": the mode is hidden from the policies (env's observe)


def _key(model: SDJLSModel) -> str:
    return json.dumps(model.to_dict(), sort_keys=True)


def resolve_env(env_id: str, env_kwargs: dict[str, Any]) -> TaskEnv:
    """Make the environment once and read its model, horizon and bounds."""
    from sdjls_gym.systems.macro import macro

    try:
        env = gym.make(env_id, **env_kwargs)
    except gym.error.Error as exc:  # an unknown or misspelled id, a wrong version
        raise ValueError(
            f"env_id = {env_id!r} cannot be made ({exc}); expected a registered SDJLS "
            "environment, e.g. 'SDJLS-Macro-v0' or 'SDJLS-v0'"
        ) from None
    try:
        base = env.unwrapped
        if not isinstance(base, SDJLSEnv):
            raise ValueError(
                f"env_id = {env_id!r} makes a {type(base).__name__}; expected an SDJLS "
                "environment (an SDJLSEnv underneath)"
            )
        limit = env.spec.max_episode_steps if env.spec is not None else None
        if limit is not None and limit != base.horizon:
            if "horizon" in env_kwargs:  # both given, and they disagree
                advice = f"pass max_episode_steps={base.horizon} too, or leave it out"
            else:
                advice = f"pass horizon={limit} (the environment's episode length) instead"
            raise ValueError(
                f"env_kwargs give max_episode_steps = {limit} but the environment's horizon is "
                f"{base.horizon} (its episodes, and the time in its observation, run to it); "
                f"{advice}"
            )
        box = base.action_space
        if not isinstance(box, gym.spaces.Box):
            raise ValueError(f"env_id = {env_id!r} has the action space {box}; expected a Box")
        bound = np.asarray(box.high, dtype=np.float64)
        return TaskEnv(
            model=base.model,
            horizon=int(base.horizon),
            action_bound=float(bound[0]) if np.all(bound == bound[0]) else bound,
            divergence_bound=float(base.divergence_bound),
            paper_system=_key(base.model) == _key(macro()),
            env_id=env_id,
            observation_space=base.observation_space,
            action_space=base.action_space,
            task=task_of(env_id, env_kwargs, base.model),
            observe=str(base.observe),
        )
    finally:
        env.close()


def _registered_task(model: SDJLSModel) -> tuple[str, dict[str, Any]] | None:
    """The registered task whose system is ``model``: ``(env_id, env_kwargs)``, or None."""
    from sdjls_gym.systems import TASKS

    key = _key(model)
    for task in TASKS.values():
        if _key(task.model) == key:
            return task.env_id, dict(task.env_kwargs)
    return None


def infer_env(
    policy: Any, env_id: str | None, env_kwargs: dict[str, Any] | None, env: Any = None
) -> tuple[str, dict[str, Any], str]:
    """Where :func:`benchmarks.evaluate.evaluate` scores ``policy``: ``(env_id, env_kwargs,
    how)``, ``how`` saying in words how the task was found.

    In this order: ``env`` (an environment, possibly wrapped: its raw environment's id and
    keyword arguments); ``env_id`` as given; the policy's own (a ``RawEnvPolicy`` knows its
    training environment's id; a controller's ``model`` is a registered task's system, or else
    is scored on ``SDJLS-v0`` with that model and the controller's horizon); the default
    :data:`DEFAULT_ENV_ID` for a policy that says nothing of its task. ``env_kwargs`` without
    ``env_id`` update the keyword arguments of the task found.
    """
    if env is not None:
        if env_id is not None or env_kwargs:
            raise ValueError(
                f"env = {type(env).__name__} and env_id = {env_id!r} / env_kwargs = "
                f"{env_kwargs!r} both name the environment; expected one of them"
            )
        found_id, found_kwargs = raw_env_of(env)
        return found_id, found_kwargs, "the environment passed as env"
    if env_id is not None:
        return env_id, dict(env_kwargs or {}), "env_id"
    found_id, found_kwargs, how = _policy_env(policy)
    return found_id, {**found_kwargs, **(env_kwargs or {})}, how


def _policy_env(policy: Any) -> tuple[str, dict[str, Any], str]:
    """The task ``policy`` names by itself (see :func:`infer_env`)."""
    own = getattr(policy, "env_id", None)
    if isinstance(own, str):  # RawEnvPolicy: its training environment's id
        return own, dict(getattr(policy, "env_kwargs", None) or {}), "the policy's env_id"
    model = getattr(policy, "model", None)
    hidden = {"observe": "state"} if is_hidden_policy(policy) else {}
    if isinstance(model, SDJLSModel):
        task = _registered_task(model)
        if task is not None:
            return task[0], {**task[1], **hidden}, "the task of the policy's model"
        kwargs: dict[str, Any] = {"model": model, **hidden}
        horizon = getattr(policy, "horizon", None)
        if isinstance(horizon, int):
            kwargs["horizon"] = horizon
        return "SDJLS-v0", kwargs, "SDJLS-v0 with the policy's model"
    return DEFAULT_ENV_ID, {}, f"the default {DEFAULT_ENV_ID} (the policy names no task)"


def is_hidden_policy(policy: Any) -> bool:
    """Whether ``policy`` decides with the mode hidden by its own means: it has
    ``act_hidden(x, k, u_applied)`` (:class:`controllers.HiddenModePolicy`)."""
    return callable(getattr(policy, "act_hidden", None))


def check_hidden(policy: Any, spec: TaskEnv) -> None:
    """Refuse a controller that decides from the true mode on an environment that hides it
    (``observe="state"``): the mode in ``info`` is for scoring only. Observation policies (an
    agent with ``predict``, a callable, a ``RawEnvPolicy`` trained with the mode hidden) and
    hidden-mode policies (``act_hidden``) are accepted."""
    if spec.observe != "state" or is_hidden_policy(policy):
        return
    observed = getattr(policy, "observe_setting", None)
    if observed is not None:  # RawEnvPolicy: what its training environment showed
        if observed != "state":
            raise ValueError(
                f"the agent was trained with observe = {observed!r} and env_kwargs give "
                "observe = 'state': it would read the mode it never sees; score it on the "
                "environment it was trained on"
            )
        return
    if callable(getattr(policy, "act_batch", None)):
        raise ValueError(
            f"env_kwargs give observe = 'state' (the mode hidden) but the policy is a "
            f"{type(policy).__name__}, which decides from (x, mode, k): it would read the true "
            "mode; wrap it as controllers.HiddenModePolicy(controller) (the mode filter's most "
            "probable mode), or use controllers.BeliefRecedingHorizonController inside one"
        )


def check_fits(policy: Any, spec: TaskEnv, how: str) -> None:
    """Refuse a policy whose ``model`` has other sizes than the environment's (a controller of
    another system), naming ``env_id`` and how it was chosen."""
    model = getattr(policy, "model", None)
    if not isinstance(model, SDJLSModel):
        return
    mine = (model.n, model.m, model.N)
    theirs = (spec.model.n, spec.model.m, spec.model.N)
    if mine != theirs:
        raise ValueError(
            f"env_id = {spec.env_id!r} ({how}) has n, m, N = {theirs} but the policy's model has "
            f"{mine}; expected the environment of the policy's system: pass env_id (or env=) "
            "of its task"
        )


def rollout_statistics(ro: Rollouts, divergence_bound: float) -> dict[str, Any]:
    """Cost, violation and divergence statistics of rollouts (the fields of :class:`Score`);
    the intervals are over the episodes, which must be at least 2."""
    check_int(
        "episodes", ro.runs, low=2, what="the rollouts' episodes; the intervals are over them"
    )
    costs = ro.episode_cost
    violations = ro.any_violation
    total, count = violations.size, int(violations.sum())
    lo, hi = wilson(count, total)
    shares = violations.mean(axis=1)
    _, elo, ehi = mean_ci(shares)  # the episodes are independent; their steps need not be
    mean, clo, chi = mean_ci(costs, floor=0.0)  # a cost is >= 0
    return {
        "episodes": int(ro.runs),
        "steps": int(violations.shape[1]),
        "cost_mean": float(mean),
        "cost_ci95": (float(clo), float(chi)),
        "cost_median": float(np.median(costs)),
        "violation": count / total,
        "violation_wilson95": (float(lo), float(hi)),
        "violation_episode_t95": (max(float(elo), 0.0), min(float(ehi), 1.0)),
        "diverged": ro.diverged(divergence_bound),
        "max_abs_u": float(np.max(np.abs(ro.u))),
        "episode_costs": costs,
        "episode_violations": shares,
    }
