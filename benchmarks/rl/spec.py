"""A run of the RL comparison described: :class:`RunSpec` (task, algorithm, variant,
observation, seed, budget, learning-curve settings, hyperparameter overrides), its whole
configuration (:meth:`RunSpec.config`) and the fingerprint that names its files
(:func:`config_fingerprint`), and the runs of a command (:func:`run_specs`).

A configuration records only what differs from the defaults a kept run was trained with: the
observation of a run with the mode observed (the default) is not in it, so the runs kept before
the hidden setting keep their fingerprints.
"""

from __future__ import annotations

import copy
import hashlib
import json
from dataclasses import asdict, dataclass
from typing import Any

from benchmarks.core.files import jsonable
from benchmarks.rl import hyperparams as HP
from benchmarks.rl.envs import (
    AGENT_ALGOS,
    MACRO,
    OBSERVATIONS,
    config_name,
    get_task,
    observation_config,
    task_digest,
    task_settings,
    variant_setup,
)

__all__ = [
    "AGENT_ALGOS",
    "ALGOS",
    "CURVE_SCORING",
    "RunSpec",
    "config_fingerprint",
    "run_specs",
]

#: The algorithms of the comparisons with the mode observed (the recurrent PPO, sb3-contrib's,
#: is the hidden comparison's: :data:`benchmarks.rl.envs.AGENT_ALGOS`).
ALGOS = ("ppo", "sac", "td3")
#: How the evaluations made during training (learning curve, dual ascent) treat a diverged
#: episode; part of a run's fingerprint, so that runs scored by another rule are trained again.
CURVE_SCORING = "a diverged episode holds its state; its later steps count as violated"


@dataclass(frozen=True)
class RunSpec:
    """One training: algorithm, variant, seed, budget, learning-curve settings, task and what
    the agent observes (``observation``: :data:`benchmarks.rl.envs.OBSERVATIONS`).

    ``overrides`` (``(name, value)`` pairs, e.g. from ``benchmarks.rl.tune``) replace entries of the
    algorithm's hyperparameters; ``net_arch`` goes into ``policy_kwargs`` and ``lr_dual`` into
    the Lagrangian's dual ascent.
    """

    algo: str
    variant: str
    seed: int
    timesteps: int
    curve_points: int
    curve_episodes: int
    curve_seed: int
    task: str = MACRO
    overrides: tuple[tuple[str, Any], ...] = ()
    observation: str = "mode"

    def __post_init__(self) -> None:
        if self.algo not in AGENT_ALGOS:
            raise ValueError(f"algo = {self.algo!r}; expected one of {AGENT_ALGOS}")
        if self.observation not in OBSERVATIONS:
            raise ValueError(f"observation = {self.observation!r}; expected one of {OBSERVATIONS}")

    @property
    def configuration(self) -> str:
        """``<algo>_<variant>``, or ``<algo>_<observation>_<variant>`` with the mode hidden."""
        return config_name(self.algo, self.variant, self.observation)

    @property
    def name(self) -> str:
        return f"{self.configuration}_s{self.seed}"

    @property
    def label(self) -> str:
        """The name with its task, for tables across tasks: ``"SDJLS-Solar-v0 ppo_reward_s0"``."""
        return f"{self.task} {self.name}"

    def hyperparams(self) -> dict[str, Any]:
        """:func:`HP.hyperparams` of the algorithm and variant with :attr:`overrides`."""
        hp = copy.deepcopy(HP.hyperparams(self.algo, self.variant))
        for key, value in self.overrides:
            if key == "lr_dual":
                continue
            if key in ("net_arch", "log_std_init"):
                hp["policy_kwargs"] = {**hp.get("policy_kwargs", {}), key: value}
            else:
                hp[key] = value
        return hp

    def lagrangian(self) -> dict[str, Any]:
        lag = task_settings(self.task).lagrangian()
        lag.update({k: v for k, v in self.overrides if k == "lr_dual"})
        return lag

    def _base_config(self) -> dict[str, Any]:
        """The configuration as the macro comparison recorded it before the suite (no task)."""
        s = task_settings(self.task)
        fields_ = {k: v for k, v in asdict(self).items()
                   if k not in ("task", "overrides", "observation")}  # fmt: skip
        config = {
            **fields_,
            "curve_scoring": CURVE_SCORING,
            "hyperparams": jsonable(self.hyperparams()),
            "env": s.env_hp(),
            "betas": s.betas(),
            "lagrangian": jsonable(self.lagrangian()),
            "residual_nu_bound": s.nu_bound,
            "residual_beta": s.residual_beta(),
        }
        if variant_setup(self.variant)[0] == "u":  # residual agents do not depend on it
            config["u_bound"] = s.u_bound
        return config

    def config(self) -> dict[str, Any]:
        """Everything the training depends on; a kept run is reused only if this matches.

        The task is in it (its id, ``env_kwargs`` and :func:`~benchmarks.rl.envs.task_digest`),
        with its scalings, bounds and penalties. The final evaluation is not: a run's policy is
        kept and scored anew by every report. The learning curve and the dual ascent are
        measured during training, so their rollout rule (:data:`CURVE_SCORING`) is.
        """
        task = get_task(self.task)
        config = {
            **self._base_config(),
            "task": self.task,
            "env_kwargs": dict(task.env_kwargs),
            "task_digest": task_digest(task),
        }
        if self.overrides:
            config["overrides"] = jsonable(dict(self.overrides))
        return {**config, **observation_config(self.observation)}

    def env_kwargs(self) -> dict[str, Any]:
        """The keyword arguments of the raw environment the run is scored on: its task's, with
        ``observe="state"`` when the mode is hidden from it."""
        kwargs = dict(get_task(self.task).env_kwargs)
        return {**kwargs, "observe": "state"} if self.observation != "mode" else kwargs

    def fingerprint(self) -> str:
        return config_fingerprint(self.config())

    def legacy_fingerprint(self) -> str | None:
        """The fingerprint the macro comparison gave this run before the suite (its
        configuration without the task), under which ``results/rl/runs`` is kept; None off the
        macro task."""
        legacy = self.task == MACRO and self.observation == "mode"
        return config_fingerprint(self._base_config()) if legacy else None


def config_fingerprint(config: dict[str, Any]) -> str:
    """The fingerprint of a run's configuration: 16 hex digits of the SHA-256 of its JSON."""
    return hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()[:16]


def run_specs(
    configs: list[tuple[str, str]] | list[tuple[str, str, str]],
    seeds: int | list[int],
    timesteps: int | None,
    quick: bool,
    tasks: list[str] | tuple[str, ...] = (MACRO,),
    budgets: str = "suite",
    tuned: dict[tuple[str, str, str], tuple[tuple[str, Any], ...]] | None = None,
    tuned_timesteps: dict[tuple[str, str, str], int] | None = None,
) -> list[RunSpec]:
    """Every (task, algorithm, variant, seed) run, task by task; ``configs`` are ``(algo,
    variant)`` pairs (the mode observed) or ``(algo, variant, observation)``.

    ``budgets``: ``"suite"`` (:func:`HP.suite_timesteps`), ``"macro"`` (:func:`HP.timesteps`,
    the budgets of ``results/rl``) or ``"hidden"`` (:func:`HP.hidden_timesteps`); ``timesteps`` replaces every default budget, ``quick`` makes
    them :data:`HP.QUICK_TIMESTEPS`. ``seeds``: a count (seeds 0 .. seeds - 1) or a list.
    ``tuned``: hyperparameter overrides (:attr:`RunSpec.overrides`) by ``(task, algo, variant)``;
    ``tuned_timesteps``: budgets by ``(task, algo, variant)`` in place of the default ones (the
    budget a study tuned at), themselves replaced by ``timesteps`` and ``quick``.
    """
    tuned, tuned_timesteps = tuned or {}, tuned_timesteps or {}
    if budgets not in ("suite", "macro", "hidden"):
        raise ValueError(f"budgets = {budgets!r}; expected 'suite', 'macro' or 'hidden'")
    keys = [(c[0], c[1], c[2] if len(c) > 2 else "mode") for c in configs]
    lc = HP.LEARNING_CURVE
    seed_list = list(range(seeds)) if isinstance(seeds, int) else list(seeds)

    def budget(task: str, algo: str, variant: str, observation: str) -> int:
        if timesteps:
            return timesteps
        if quick:
            return HP.QUICK_TIMESTEPS
        if (task, algo, variant) in tuned_timesteps:
            return tuned_timesteps[(task, algo, variant)]
        if budgets == "macro":
            return HP.timesteps(algo, variant)
        if budgets == "hidden":
            return HP.hidden_timesteps(algo, observation)
        return HP.suite_timesteps(task, algo, variant)

    return [
        RunSpec(
            algo=algo,
            variant=variant,
            seed=seed,
            timesteps=budget(task, algo, variant, observation),
            curve_points=3 if quick else lc["points"],
            curve_episodes=20 if quick else lc["episodes"],
            curve_seed=lc["seed"],
            task=task,
            overrides=tuned.get((task, algo, variant), ()),
            observation=observation,
        )
        for task in tasks
        for algo, variant, observation in keys
        for seed in seed_list
    ]
