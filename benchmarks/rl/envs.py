"""The training environments of the RL comparison, on every task of the suite.

:func:`make_train_env` is the one recipe: ``make_train_env(task, variant)`` builds the
environment an agent of ``python -m benchmarks.compare_rl`` trains on (the same recipe the
rl-zoo3 files, ``benchmarks.evaluate --train-env`` and :func:`benchmarks.rl.runs.load_agent` use).
Its scalings and bounds come from :class:`TaskSettings`, one per task: the table
:data:`benchmarks.rl.hyperparams.TASK_SCALES` for the suite's tasks, :func:`derive_scales` (the
rule that table was written from) for any other.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import RescaleAction

from benchmarks.rl import hyperparams as HP
from benchmarks.rl.belief_env import BeliefObservation
from sdjls_gym.systems import TASKS, Task, random_task
from sdjls_gym.validation import check_choice, check_positive
from sdjls_gym.wrappers import (
    FiniteHorizon,
    ResidualAction,
    ScaleObservationReward,
    TerminateOutside,
    ViolationPenalty,
)

__all__ = [
    "ACTION_KINDS",
    "AGENT_ALGOS",
    "MACRO",
    "OBSERVATIONS",
    "TaskSettings",
    "VARIANTS",
    "comparison_env_kwargs",
    "config_name",
    "derive_scales",
    "env_from_config",
    "observation_config",
    "observation_of",
    "parse_config",
    "raw_scales",
    "get_task",
    "make_train_env",
    "task_digest",
    "task_settings",
    "variant_setup",
    "wrap_train_env",
]

MACRO = "SDJLS-Macro-v0"
#: The training variants: on the reward alone, with a fixed violation penalty, residual over the
#: task's gains, and with the penalty adapted by dual ascent (see ``benchmarks.rl.compare``).
VARIANTS = ("reward", *(f"beta{b:g}" for b in HP.BETAS), "residual", "lagrangian")
#: ``"u"``: the agent chooses ``u``; ``"residual"``: the offset ``nu`` of ``u = K_theta x + nu``.
ACTION_KINDS = ("u", "residual")
#: Every algorithm a run may train (the recurrent PPO is sb3-contrib's, for the hidden mode).
AGENT_ALGOS = ("ppo", "sac", "td3", "recurrent_ppo")
#: What an agent observes: the mode (``"mode"``, the default), the state alone (``"state"``: the
#: environment made with ``observe="state"``), or the state with the mode filter's belief
#: appended (``"belief"``, :class:`benchmarks.rl.belief_env.BeliefObservation`).
OBSERVATIONS = ("mode", "state", "belief")
#: The reward scale the penalties of :mod:`benchmarks.rl.hyperparams` are written for (the macro
#: task's); on another task every penalty is multiplied by its reward scale over this one.
PENALTY_REFERENCE_SCALE = 100.0


# ----------------------------------------------------------------------------- tasks
def get_task(env_id: str | Task, env_kwargs: Mapping[str, Any] | None = None) -> Task:
    """The :class:`~sdjls_gym.systems.Task` of ``env_id`` (a suite id, or ``"SDJLS-Random-v0"``
    with the generator's ``env_kwargs``); a Task is returned as it is."""
    if isinstance(env_id, Task):
        return env_id
    if not isinstance(env_id, str):
        raise TypeError(f"task = {env_id!r}; expected a suite env id (str) or a Task")
    kwargs = dict(env_kwargs or {})
    if env_id == "SDJLS-Random-v0" and kwargs:
        unknown = sorted(set(kwargs) - {"n", "m", "N", "r", "system_seed", "spectral_radius"})
        if unknown:
            raise ValueError(f"env_kwargs = {kwargs!r}: {unknown} are not parameters of the task")
        sizes = {k: kwargs[k] for k in ("n", "m", "N", "r") if k in kwargs}
        extra = {k: kwargs[k] for k in ("spectral_radius",) if k in kwargs}
        return random_task(**sizes, seed=kwargs.get("system_seed", 0), **extra)
    if env_id not in TASKS:
        raise ValueError(f"task = {env_id!r}; expected one of {tuple(TASKS)}")
    if kwargs:
        raise ValueError(f"env_kwargs = {kwargs!r}; task {env_id!r} takes none")
    return TASKS[env_id]


#: The model's fields a run's task digest reads (numbers only, to 12 significant digits: a
#: change of the model's file format or of the last bits of a computed entry is not a new task).
DIGEST_FIELDS = ("A", "B", "E", "W", "P_in", "P_out", "G", "H0", "H_rate", "Q", "R", "x0", "mode0")


def task_digest(task: Task) -> str:
    """A short hash of what training depends on in ``task`` (the model's :data:`DIGEST_FIELDS`,
    horizon, action bound, gains ``K``, ``xi`` and ``nu_bound``): a kept run is reused only on
    the task it was trained on."""
    from benchmarks.core.files import stable_floats

    values = {name: np.asarray(getattr(task.model, name), dtype=np.float64).tolist()
              for name in DIGEST_FIELDS}  # fmt: skip
    values.update(
        horizon=float(task.horizon),
        action_bound=np.asarray(task.action_bound, dtype=np.float64).tolist(),
        K=np.asarray(task.K, dtype=np.float64).tolist(),
        xi=float(task.rhc["xi"]),
        nu_bound=float(task.rhc["nu_bound"]),
    )
    text = json.dumps(stable_floats(values, 12), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _one_digit(value: float) -> float:
    """``value`` rounded to one significant digit (13 -> 10, 0.244 -> 0.2)."""
    return float(f"{value:.0e}")


def _one_digit_up(value: float, floor: float) -> float:
    """``value`` to one significant digit, moved one digit up while below ``floor``."""
    out = _one_digit(value)
    while out < floor:
        step = 10.0 ** math.floor(math.log10(out))
        out = float(f"{out + step:.0e}")
    return out


def raw_scales(task: Task, episodes: int = 300, seed: int = 0) -> dict[str, float]:
    """What :func:`derive_scales` rounds: from ``episodes`` episodes (noise seed ``seed``) of the
    task's receding-horizon controller (its ``K``, ``rhc`` and ``xi``), the 95th percentile of
    ``|x_i|`` over every state entry (``x``), its mean stage cost (``stage_cost``) and its
    largest ``|u_i|`` (``u``)."""
    from benchmarks.core.montecarlo import rollout
    from controllers import RecedingHorizonController

    ctrl = RecedingHorizonController(task.model, task.K, horizon=task.horizon, **task.rhc)
    ro = rollout(task.model, ctrl, episodes, task.horizon, seed, task.action_bound)
    return {
        "x": float(np.quantile(np.abs(ro.x), 0.95)),
        "stage_cost": float(ro.stage_cost.mean()),
        "u": float(np.max(np.abs(ro.u))),
    }


def derive_scales(task: Task, episodes: int = 300, seed: int = 0) -> dict[str, float]:
    """The scalings of ``task`` by the rule :data:`benchmarks.rl.hyperparams.TASK_SCALES` states.

    From :func:`raw_scales`: ``x_scale`` is the 95th percentile of ``|x_i|`` to one significant
    digit; ``reward_scale`` the mean stage cost / 2.5 to one significant digit; ``u_bound`` 1.25
    times the largest ``|u_i|`` to one significant digit, not below that largest ``|u_i|`` and at
    most the task's action bound. On the macro task these are the values the comparison of
    ``results/rl`` was trained with (10, 100, 60).
    """
    raw = raw_scales(task, episodes, seed)
    return {
        "x_scale": _one_digit(raw["x"]),
        "reward_scale": _one_digit(raw["stage_cost"] / 2.5),
        "u_bound": min(float(task.action_bound), _one_digit_up(1.25 * raw["u"], raw["u"])),
    }


# ----------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class TaskSettings:
    """Everything the training environment of one task depends on besides the variant.

    ``x_scale``, ``reward_scale``, ``u_bound``: :data:`~benchmarks.rl.hyperparams.TASK_SCALES`;
    ``xi``: the task's receding-horizon controller's (the Lagrangian agent aims at its
    ``1 - xi``); ``nu_bound``, the residual agent's bound on ``|nu|``: the receding-horizon
    controller's, at most :data:`HP.RESIDUAL_NU_U_BOUNDS` times ``u_bound``. The fixed
    parts (``obs_clip``, ``reward_clip``, ``reward_transform``) are :data:`HP.ENV`'s, and
    ``terminate_bound`` is ``HP.TERMINATE_SCALES`` times ``x_scale``. Every penalty is in units
    of ``reward_scale / 100`` (:attr:`penalty_unit`; 1 on the macro task).
    """

    env_id: str
    x_scale: float
    reward_scale: float
    u_bound: float
    nu_bound: float
    xi: float
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)

    @property
    def penalty_unit(self) -> float:
        return self.reward_scale / PENALTY_REFERENCE_SCALE

    def env_hp(self) -> dict[str, float | str]:
        """The keyword arguments of ScaleObservationReward plus ``terminate_bound``."""
        return {
            "x_scale": self.x_scale,
            "obs_clip": HP.ENV["obs_clip"],
            "reward_scale": self.reward_scale,
            "reward_clip": HP.ENV["reward_clip"],
            "reward_transform": HP.ENV["reward_transform"],
            "terminate_bound": HP.TERMINATE_SCALES * self.x_scale,
        }

    def betas(self) -> list[float]:
        """The fixed penalties of the ``beta<b>`` variants: ``b`` penalty units each."""
        return [b * self.penalty_unit for b in HP.BETAS]

    def residual_beta(self) -> float:
        return HP.RESIDUAL_BETA * self.penalty_unit

    def lagrangian(self) -> dict[str, Any]:
        """:data:`HP.LAGRANGIAN` with this task's ``xi`` and the penalties in its units."""
        lag = dict(HP.LAGRANGIAN)
        lag["xi"] = self.xi
        lag["beta0"] = HP.LAGRANGIAN["beta0"] * self.penalty_unit
        lag["lr_dual"] = HP.LAGRANGIAN["lr_dual"] * self.penalty_unit
        return lag


def task_settings(task: str | Task, env_kwargs: Mapping[str, Any] | None = None) -> TaskSettings:
    """The :class:`TaskSettings` of ``task``: from :data:`HP.TASK_SCALES` for a suite id,
    else by :func:`derive_scales`."""
    task = get_task(task, env_kwargs)
    kwargs = dict(task.env_kwargs)
    table = HP.TASK_SCALES.get(task.env_id)
    if table is not None and (task.env_id != "SDJLS-Random-v0" or task is TASKS[task.env_id]
                              or kwargs == dict(TASKS[task.env_id].env_kwargs)):  # fmt: skip
        scales = dict(table)
    else:
        scales = derive_scales(task)
    return TaskSettings(
        env_id=task.env_id,
        x_scale=float(scales["x_scale"]),
        reward_scale=float(scales["reward_scale"]),
        u_bound=float(scales["u_bound"]),
        nu_bound=min(
            float(task.rhc["nu_bound"]), HP.RESIDUAL_NU_U_BOUNDS * float(scales["u_bound"])
        ),
        xi=float(task.rhc["xi"]),
        env_kwargs=kwargs,
    )


# ----------------------------------------------------------------------------- configurations
def config_name(algo: str, variant: str, observation: str = "mode") -> str:
    """A configuration's name: ``<algo>_<variant>`` with the mode observed,
    ``<algo>_<observation>_<variant>`` otherwise (``"ppo_belief_reward"``,
    ``"recurrent_ppo_state_lagrangian"``): a run of the hidden setting is never named as one of
    the mode observed."""
    observation = check_choice("observation", observation, OBSERVATIONS)
    return f"{algo}_{variant}" if observation == "mode" else f"{algo}_{observation}_{variant}"


def parse_config(name: str) -> tuple[str, str, str]:
    """``(algo, variant, observation)`` of a configuration's name (:func:`config_name`)."""
    for algo in sorted(AGENT_ALGOS, key=len, reverse=True):
        if not name.startswith(algo + "_"):
            continue
        rest, observation = name[len(algo) + 1 :], "mode"
        for other in OBSERVATIONS[1:]:
            if rest.startswith(other + "_"):
                rest, observation = rest[len(other) + 1 :], other
        if rest in VARIANTS:
            return algo, rest, observation
    raise ValueError(
        f"configuration = {name!r}; expected <algo>[_<observation>]_<variant> with algo in "
        f"{AGENT_ALGOS}, observation in {OBSERVATIONS[1:]} and variant in {VARIANTS}"
    )


def observation_config(observation: str) -> dict[str, Any]:
    """What a run's configuration records of its observation: nothing with the mode observed
    (the runs kept before the hidden setting keep their fingerprints), ``observe = "state"``
    with the mode hidden, and ``features = ["belief"]`` with the belief appended."""
    observation = check_choice("observation", observation, OBSERVATIONS)
    if observation == "mode":
        return {}
    return {"observe": "state", **({"features": ["belief"]} if observation == "belief" else {})}


def observation_of(config: Mapping[str, Any]) -> str:
    """The observation (:data:`OBSERVATIONS`) a run's recorded configuration describes."""
    if "belief" in config.get("features", ()):
        return "belief"
    return "state" if config.get("observe", "mode") == "state" else "mode"


# ----------------------------------------------------------------------------- variants
def comparison_env_kwargs(task: str | Task) -> dict[str, Any]:
    """The environment every controller and agent of the comparison is scored on: the task's own
    keyword arguments with the action bound the agents acting on ``u`` are trained with
    (``TaskSettings.u_bound``, 1.25 times the largest input of the task's RHC): equal action
    limits for everyone, the controllers' inputs clipped there as the agents' are."""
    t = get_task(task)
    return {**dict(t.env_kwargs), "action_bound": task_settings(t).u_bound}


def variant_setup(
    variant: str, settings: TaskSettings | None = None
) -> tuple[str, float | None, bool]:
    """``(action_kind, beta or None, lagrangian)`` of a variant on a task (default: the macro
    task, whose penalty unit is 1): ``beta<b>`` is ``b`` penalty units, the residual agents'
    penalty :data:`HP.RESIDUAL_BETA` units, the Lagrangian's initial one ``beta0`` units."""
    unit = 1.0 if settings is None else settings.penalty_unit
    if variant == "reward":
        return "u", None, False
    if variant == "residual":
        return "residual", float(HP.RESIDUAL_BETA) * unit, False
    if variant == "lagrangian":
        return "u", float(HP.LAGRANGIAN["beta0"]) * unit, True
    if variant in VARIANTS and variant.startswith("beta"):
        return "u", float(variant[4:]) * unit, False
    raise ValueError(f"variant = {variant!r}; expected one of {VARIANTS}")


# ----------------------------------------------------------------------------- environments
def wrap_train_env(
    env_id: str,
    action_kind: str,
    beta: float | None,
    env_hp: Mapping[str, Any],
    K: np.ndarray | None = None,
    nu_bound: float = HP.RESIDUAL_NU_BOUND,
    u_bound: float | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    observation: str = "mode",
) -> gym.Env:
    """``gym.make(env_id, **env_kwargs)`` wrapped for training one agent, from explicit values
    (what a run's configuration records; :func:`make_train_env` takes them from the task).

    The chain, innermost first: ``ResidualAction(K, nu_bound)`` (residual agents) or the
    environment made with ``action_bound=u_bound`` (agents acting on ``u``; None keeps the
    registered bound), ``RescaleAction`` to ``[-1, 1]``, ``ViolationPenalty(beta)`` (unless
    ``beta`` is None), ``ScaleObservationReward(**env_hp)``, ``TerminateOutside`` (when
    ``env_hp`` has ``terminate_bound``), ``FiniteHorizon``, and with ``observation="belief"``
    :class:`~benchmarks.rl.belief_env.BeliefObservation`; ``observation`` other than ``"mode"``
    makes the environment with ``observe="state"`` (the mode hidden).
    """
    action_kind = check_choice("action_kind", action_kind, ACTION_KINDS)
    observation = check_choice("observation", observation, OBSERVATIONS)
    if u_bound is not None:
        u_bound = check_positive("u_bound", u_bound, "the agent's bound on |u|")
    env_hp = dict(env_hp)
    kwargs = dict(env_kwargs or {})
    if action_kind == "u" and u_bound is not None:
        kwargs["action_bound"] = u_bound
    if observation != "mode":
        kwargs["observe"] = "state"
    env = gym.make(env_id, **kwargs)
    if action_kind == "residual":
        if K is None:
            raise ValueError("a residual agent needs the gains K (N, m, n)")
        env = ResidualAction(env, K, nu_bound)
    shape = env.action_space.shape
    if shape is None:
        raise TypeError(f"{env_id}'s action space {env.action_space} has no shape; expected a Box")
    one = np.ones(shape, dtype=np.float32)
    env = RescaleAction(env, -one, one)
    if beta is not None:
        env = ViolationPenalty(env, beta)
    bound = env_hp.pop("terminate_bound", None)
    env = ScaleObservationReward(env, **env_hp)
    if bound is not None:
        env = TerminateOutside(env, bound)
    env = FiniteHorizon(env)
    return BeliefObservation(env) if observation == "belief" else env


def make_train_env(
    task: Any = MACRO, variant: Any = "residual", *args: Any, observation: str = "mode",
    **kwargs: Any,
) -> gym.Env:  # fmt: skip
    """The environment an agent of the comparison trains on: ``task`` (a suite env id or a
    :class:`~sdjls_gym.systems.Task`) in ``variant`` (:data:`VARIANTS`), observing
    ``observation`` (:data:`OBSERVATIONS`: ``"state"`` hides the mode, ``"belief"`` appends the
    mode filter's belief to the state-only observation).

    Observation ``[clip(x / x_scale, +-10), one-hot mode, k / T]``; action in ``[-1, 1]``, read as
    ``u`` in ``[-u_bound, u_bound]`` or, for ``"residual"``, as ``nu`` in ``[-nu_bound,
    nu_bound]`` over the task's gains ``K`` (``u = K_theta x + nu``); reward
    ``-log(1 + c / reward_scale)`` of the penalized stage cost ``c``; training episodes end once
    ``max |x| > 10 x_scale``. The values: :func:`task_settings`.
    :class:`~benchmarks.evaluate.RawEnvPolicy` undoes the observation and action wrappers for
    an agent trained on it.

    Examples
    --------
    >>> env = make_train_env("SDJLS-VTOL-v0", "residual")
    >>> env.action_space.shape, env.observation_space.shape
    ((2,), (8,))

    Notes
    -----
    The form of the macro comparison before the suite, ``make_train_env(action_kind, beta,
    env_hp=None, K=None, nu_bound=100.0, u_bound=None)`` with ``action_kind`` in
    :data:`ACTION_KINDS`, is still accepted: it is :func:`wrap_train_env` on the macro task.
    """
    if isinstance(task, str) and task in ACTION_KINDS:  # the older form, on the macro task
        names = ("env_hp", "K", "nu_bound", "u_bound")
        given = dict(zip(names, args, strict=False)) | kwargs
        env_hp = given.get("env_hp")
        return wrap_train_env(
            MACRO, task, variant, HP.ENV if env_hp is None else env_hp, given.get("K"),
            given.get("nu_bound", HP.RESIDUAL_NU_BOUND), given.get("u_bound"),
        )  # fmt: skip
    if args or kwargs:
        raise TypeError(
            f"make_train_env(task, variant) takes no other argument, got {args or kwargs}"
        )
    t = get_task(task)
    settings = task_settings(t)
    kind, beta, _ = variant_setup(variant, settings)
    return wrap_train_env(
        t.env_id, kind, beta, settings.env_hp(), t.K if kind == "residual" else None,
        settings.nu_bound, settings.u_bound if kind == "u" else None, t.env_kwargs, observation,
    )  # fmt: skip


def env_from_config(config: dict[str, Any], variant: str) -> gym.Env:
    """The training environment a run's recorded ``config`` describes (:meth:`RunSpec.config`;
    a run kept before the suite has no task in it: the macro task).

    Raises
    ------
    ValueError
        The task's data (model, gains, ``xi``) changed since the run was trained.
    """
    task = get_task(config.get("task", MACRO), config.get("env_kwargs"))
    digest = config.get("task_digest")
    if digest is not None and digest != task_digest(task):
        raise ValueError(
            f"task {task.env_id!r} is not the one this run was trained on (task_digest "
            f"{digest} recorded, {task_digest(task)} now): its model, gains or xi changed"
        )
    kind, _, _ = variant_setup(variant)
    if variant == "reward":
        beta = None
    elif variant == "residual":
        beta = config["residual_beta"]
    elif variant == "lagrangian":
        beta = config["lagrangian"]["beta0"]
    else:
        beta = config["betas"][list(HP.BETAS).index(float(variant[4:]))]
    return wrap_train_env(
        task.env_id, kind, beta, config["env"], task.K if kind == "residual" else None,
        config["residual_nu_bound"], config.get("u_bound"), task.env_kwargs,
        observation_of(config),
    )  # fmt: skip
