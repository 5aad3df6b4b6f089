"""Training one stable-baselines3 agent of the RL comparison, and the files a run is kept in.

A run is described by a :class:`RunSpec` (task, algorithm, variant, seed, budget, learning-curve
settings, hyperparameter overrides). :func:`train_run` trains it on the task's training
environment (:func:`benchmarks.rl.envs.make_train_env`'s recipe, rebuilt from the run's
configuration by :func:`env_from_config`) and returns its :class:`RunRecord` (learning curve,
dual ascent, training and CPU time) and its policy's state dict (tens of KB); :func:`save_run`
writes both under ``runs/<task>/<name>-<fingerprint>.json`` and ``.pt``, named by the run's whole
configuration hashed into :meth:`RunSpec.fingerprint`, so that a run of another configuration
never replaces a kept one; :func:`load_run` reads the kept run of a spec back (also the macro
comparison's runs kept before the suite, :meth:`RunSpec.legacy_fingerprint`). Training runs in
a worker (a process or a Ray task); the files are written by the main process.
"""

from __future__ import annotations

import copy
import hashlib
import io
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from benchmarks.core.environment import resolve_env, rollout_statistics
from benchmarks.core.files import jsonable, write_atomic
from benchmarks.core.montecarlo import rollout
from benchmarks.core.policies import RawEnvPolicy
from benchmarks.rl import hyperparams as HP
from benchmarks.rl.envs import (
    ACTION_KINDS,
    MACRO,
    VARIANTS,
    env_from_config,
    get_task,
    make_train_env,
    task_digest,
    task_settings,
    variant_setup,
)
from benchmarks.rl.records import CurvePoint, DualPoint, RunRecord
from sdjls_gym.errors import InvalidRunError

__all__ = [
    "ACTION_KINDS",
    "ALGOS",
    "VARIANTS",
    "CurvePoint",
    "DualPoint",
    "RunRecord",
    "RunSpec",
    "config_fingerprint",
    "env_from_config",
    "kept_run_path",
    "load_policy",
    "load_run",
    "make_train_env",
    "policy_from_config",
    "run_path",
    "run_specs",
    "save_run",
    "train_run",
    "variant_setup",
]

ALGOS = ("ppo", "sac", "td3")
#: How the evaluations made during training (learning curve, dual ascent) treat a diverged
#: episode; part of a run's fingerprint, so that runs scored by another rule are trained again.
CURVE_SCORING = "a diverged episode holds its state; its later steps count as violated"


# ----------------------------------------------------------------------------- run specs
@dataclass(frozen=True)
class RunSpec:
    """One training: algorithm, variant, seed, budget, learning-curve settings and task.

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

    @property
    def name(self) -> str:
        return f"{self.algo}_{self.variant}_s{self.seed}"

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
        fields_ = {k: v for k, v in asdict(self).items() if k not in ("task", "overrides")}
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
        return config

    def fingerprint(self) -> str:
        return config_fingerprint(self.config())

    def legacy_fingerprint(self) -> str | None:
        """The fingerprint the macro comparison gave this run before the suite (its
        configuration without the task), under which ``results/rl/runs`` is kept; None off the
        macro task."""
        return config_fingerprint(self._base_config()) if self.task == MACRO else None


def config_fingerprint(config: dict[str, Any]) -> str:
    """The fingerprint of a run's configuration: 16 hex digits of the SHA-256 of its JSON."""
    return hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()[:16]


def run_specs(
    configs: list[tuple[str, str]],
    seeds: int | list[int],
    timesteps: int | None,
    quick: bool,
    tasks: list[str] | tuple[str, ...] = (MACRO,),
    budgets: str = "suite",
    tuned: dict[tuple[str, str, str], tuple[tuple[str, Any], ...]] | None = None,
    tuned_timesteps: dict[tuple[str, str, str], int] | None = None,
) -> list[RunSpec]:
    """Every (task, algorithm, variant, seed) run, task by task.

    ``budgets``: ``"suite"`` (:func:`HP.suite_timesteps`) or ``"macro"`` (:func:`HP.timesteps`,
    the budgets of ``results/rl``); ``timesteps`` replaces every default budget, ``quick`` makes
    them :data:`HP.QUICK_TIMESTEPS`. ``seeds``: a count (seeds 0 .. seeds - 1) or a list.
    ``tuned``: hyperparameter overrides (:attr:`RunSpec.overrides`) by ``(task, algo, variant)``;
    ``tuned_timesteps``: budgets by ``(task, algo, variant)`` in place of the default ones (the
    budget a study tuned at), themselves replaced by ``timesteps`` and ``quick``.
    """
    tuned, tuned_timesteps = tuned or {}, tuned_timesteps or {}
    if budgets not in ("suite", "macro"):
        raise ValueError(f"budgets = {budgets!r}; expected 'suite' or 'macro'")
    lc = HP.LEARNING_CURVE
    seed_list = list(range(seeds)) if isinstance(seeds, int) else list(seeds)

    def budget(task: str, algo: str, variant: str) -> int:
        if timesteps:
            return timesteps
        if quick:
            return HP.QUICK_TIMESTEPS
        if (task, algo, variant) in tuned_timesteps:
            return tuned_timesteps[(task, algo, variant)]
        if budgets == "macro":
            return HP.timesteps(algo, variant)
        return HP.suite_timesteps(task, algo, variant)

    return [
        RunSpec(
            algo=algo,
            variant=variant,
            seed=seed,
            timesteps=budget(task, algo, variant),
            curve_points=3 if quick else lc["points"],
            curve_episodes=20 if quick else lc["episodes"],
            curve_seed=lc["seed"],
            task=task,
            overrides=tuned.get((task, algo, variant), ()),
        )
        for task in tasks
        for algo, variant in configs
        for seed in seed_list
    ]


# ----------------------------------------------------------------------------- environments
def _train_env(spec: RunSpec) -> gym.Env:
    return env_from_config(spec.config(), spec.variant)


def build_agent(spec: RunSpec, env_fns: list[Callable[[], gym.Env]]) -> Any:
    """The stable-baselines3 algorithm of ``spec`` with the hyperparameters of rl_hyperparams."""
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.noise import NormalActionNoise
    from stable_baselines3.common.vec_env import DummyVecEnv

    hp = spec.hyperparams()
    n_envs = hp.pop("n_envs")
    venv = DummyVecEnv(env_fns * n_envs if len(env_fns) == 1 else env_fns)
    if spec.algo == "td3":
        shape = venv.action_space.shape
        if shape is None:
            raise TypeError(f"{spec.task}'s action space {venv.action_space} has no shape")
        std, m = hp.pop("noise_std"), shape[0]
        hp["action_noise"] = NormalActionNoise(np.zeros(m), std * np.ones(m))
    if isinstance(hp.get("train_freq"), list):
        hp["train_freq"] = tuple(hp["train_freq"])
    hp["learning_rate"] = HP.learning_rate(hp["learning_rate"])  # "lin_<r>": a linear decay
    cls = {"ppo": PPO, "sac": SAC, "td3": TD3}[spec.algo]
    return cls("MlpPolicy", venv, seed=1000 + spec.seed, verbose=0, device="cpu", **hp)


# ----------------------------------------------------------------------------- callbacks
@dataclass
class TrainingLog:
    """What the callbacks of one training record; ``beta`` is the current penalty."""

    beta: float | None
    curve: list[CurvePoint] = field(default_factory=list)
    dual: list[DualPoint] = field(default_factory=list)
    eval_time: float = 0.0
    t_start: float = field(default_factory=time.perf_counter)


class _Evaluator:
    """The deterministic policy's statistics on the raw environment during training."""

    def __init__(self, train_env: gym.Env, log: TrainingLog, task: str = MACRO) -> None:
        self.env, self.log = train_env, log
        self.spec = resolve_env(task, dict(get_task(task).env_kwargs))

    def __call__(self, agent: Any, episodes: int, seed: int) -> dict[str, Any]:
        t0 = time.perf_counter()
        s = self.spec
        ro = rollout(
            s.model, RawEnvPolicy(agent, self.env), episodes, s.horizon, seed, s.action_bound,
            None, s.divergence_bound,
        )  # fmt: skip
        self.log.eval_time += time.perf_counter() - t0
        return rollout_statistics(ro, s.divergence_bound)


class LearningCurve(BaseCallback):
    """Evaluate the deterministic policy before training and at ``spec.curve_points`` marks."""

    def __init__(
        self,
        spec: RunSpec,
        log: TrainingLog,
        evaluator: _Evaluator,
        report: Callable | None,
        on_point: Callable[[CurvePoint], None] | None = None,
    ) -> None:
        super().__init__()
        self.spec, self.log, self.evaluator, self.report = spec, log, evaluator, report
        self.on_point = on_point
        points = max(1, spec.curve_points)
        self.marks = [int(round(spec.timesteps * (i + 1) / points)) for i in range(points)]
        self.next = 0

    def _record(self) -> None:
        s = self.evaluator(self.model, self.spec.curve_episodes, self.spec.curve_seed)
        self.log.curve.append(
            CurvePoint(
                timesteps=int(self.num_timesteps),
                wall_s=time.perf_counter() - self.log.t_start,
                episode_cost_mean=s["cost_mean"],
                episode_cost_median=s["cost_median"],
                violation=s["violation"],
                diverged=s["diverged"],
                beta=self.log.beta,
            )
        )
        if self.report is not None:
            self.report(self.spec.label, int(self.num_timesteps))
        if self.on_point is not None:
            self.on_point(self.log.curve[-1])

    def _on_training_start(self) -> None:
        self._record()  # the untrained policy

    def _on_step(self) -> bool:
        while self.next < len(self.marks) and self.num_timesteps >= self.marks[self.next]:
            self.next += 1
            self._record()
        return True


class DualAscent(BaseCallback):
    """``beta <- max(0, beta + lr_dual * (violation frequency - (1 - xi)))`` after each rollout
    that ends ``period`` steps after the last update, the frequency measured on fresh
    evaluation episodes of the deterministic policy (:data:`~benchmarks.rl.hyperparams.LAGRANGIAN`,
    with the task's ``xi`` and penalty unit: :meth:`RunSpec.lagrangian`).
    """

    def __init__(self, spec: RunSpec, log: TrainingLog, evaluator: _Evaluator) -> None:
        super().__init__()
        self.log, self.evaluator = log, evaluator
        self.violations, self.steps = 0.0, 0
        self.lag = spec.lagrangian()
        period = self.lag["period"]
        self.period = int(period[spec.algo] if isinstance(period, dict) else period)
        self.seeds = np.random.default_rng([self.lag["seed"], spec.seed])

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            self.violations += float(info["cost"])
            self.steps += 1
        return True

    def _on_rollout_end(self) -> None:
        if self.steps < self.period:
            return
        seed = int(self.seeds.integers(2**31))
        freq = self.evaluator(self.model, self.lag["episodes"], seed)["violation"]
        train_freq = self.violations / self.steps
        target = 1.0 - self.lag["xi"]
        beta = max(0.0, self.log.beta + self.lag["lr_dual"] * (freq - target))
        self.training_env.env_method("set_wrapper_attr", "beta", beta)
        seen = self.training_env.get_attr("beta")
        if not np.allclose(seen, beta):
            raise RuntimeError(f"beta was not set on the ViolationPenalty wrappers: {seen}")
        self.log.beta = beta
        self.log.dual.append(DualPoint(int(self.num_timesteps), freq, train_freq, beta))
        self.logger.record("lagrangian/beta", beta)
        self.logger.record("lagrangian/violation_freq", freq)
        self.logger.record("lagrangian/train_violation_freq", train_freq)
        self.violations, self.steps = 0.0, 0


class TrainingStopped(RuntimeError):
    """A training stopped from outside (the main process ended or asked it to stop)."""


class StopWhen(BaseCallback):
    """Stop training when ``should_stop()`` says so (asked every ``every_s`` seconds)."""

    def __init__(self, should_stop: Callable[[], bool], every_s: float = 2.0) -> None:
        super().__init__()
        self.should_stop, self.every_s = should_stop, every_s
        self.next = time.monotonic() + every_s
        self.stopped = False

    def _on_step(self) -> bool:
        if time.monotonic() < self.next:
            return True
        self.next = time.monotonic() + self.every_s
        self.stopped = bool(self.should_stop())
        return not self.stopped


# ----------------------------------------------------------------------------- one run
def train_run(
    spec: RunSpec,
    report: Callable[[str, int], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    on_curve_point: Callable[[CurvePoint], None] | None = None,
) -> tuple[RunRecord, bytes]:
    """Train one agent: its record and its policy's state dict (``torch.save`` bytes).

    One torch thread; everything is rebuilt from ``spec``, so the result does not depend on
    the process or machine it runs in. ``report(label, timesteps)`` is called at each
    learning-curve point, and ``on_curve_point(point)`` with the point (an exception it raises,
    e.g. a tuner's pruning, ends the training and propagates); ``should_stop()``, if given, can
    end the training (:class:`TrainingStopped`).
    """
    import torch
    from stable_baselines3.common.monitor import Monitor

    torch.set_num_threads(1)
    agent = build_agent(spec, [lambda: Monitor(_train_env(spec))])
    _, beta0, lagrangian = variant_setup(spec.variant, task_settings(spec.task))
    log = TrainingLog(beta=beta0)
    evaluator = _Evaluator(_train_env(spec), log, spec.task)
    callbacks: list[BaseCallback] = [LearningCurve(spec, log, evaluator, report, on_curve_point)]
    if lagrangian:
        callbacks.insert(0, DualAscent(spec, log, evaluator))
    stopper = None if should_stop is None else StopWhen(should_stop)
    if stopper is not None:
        callbacks.append(stopper)
    t0, c0 = time.perf_counter(), time.process_time()
    agent.learn(total_timesteps=spec.timesteps, callback=callbacks)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    if stopper is not None and stopper.stopped:
        raise TrainingStopped(f"{spec.label} was stopped at {agent.num_timesteps} steps")
    record = RunRecord(
        name=spec.name,
        algo=spec.algo,
        variant=spec.variant,
        seed=spec.seed,
        fingerprint=spec.fingerprint(),
        config=spec.config(),
        timesteps=int(agent.num_timesteps),
        train_time_s=wall,
        wall_time_s=wall,
        cpu_time_s=cpu,
        eval_time_s=log.eval_time,
        final_beta=log.beta,
        learning_curve=log.curve,
        dual_ascent=log.dual,
        task=spec.task,
    )
    buffer = io.BytesIO()
    torch.save(agent.policy.state_dict(), buffer)
    return record, buffer.getvalue()


# ----------------------------------------------------------------------------- run files
def run_path(run_dir: str | Path, name: str, fingerprint: str) -> Path:
    """``run_dir/<name>-<fingerprint>.json``: a run's record is named by its whole configuration,
    so that a run of another configuration (``--quick``, ``--timesteps``, changed
    hyperparameters) lands beside a kept run and never replaces it."""
    return Path(run_dir) / f"{name}-{fingerprint}.json"


def policy_path(json_path: str | Path) -> Path:
    """Where the trained policy of the run recorded in ``json_path`` is kept."""
    return Path(json_path).with_suffix(".pt")


def save_run(run_dir: Path, record: RunRecord, policy: bytes) -> Path:
    """Write ``<task>/<name>-<fingerprint>.pt`` then ``.json`` under ``run_dir`` (a JSON file
    implies its policy), each atomically (:func:`benchmarks.core.files.write_atomic`); only a run of
    the same configuration (``--retrain``) is replaced."""
    path = run_path(Path(run_dir) / record.task, record.name, record.fingerprint)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(policy_path(path), policy)
    write_atomic(path, json.dumps(record.to_json()) + "\n")
    return path


def kept_run_path(run_dir: Path, spec: RunSpec) -> Path | None:
    """The record file of the kept run of ``spec`` (with its policy beside it), or None.

    Reads ``run_dir/<task>/<name>-<fingerprint>.json``; on the macro task also the layouts of
    the macro comparison before the suite (read, never written): ``run_dir/<name>-<fp>.json``
    and ``run_dir/<name>.json``, where ``fp`` is the run's fingerprint or
    :meth:`RunSpec.legacy_fingerprint` and the file records it."""
    fingerprint = spec.fingerprint()
    candidates = [(run_path(Path(run_dir) / spec.task, spec.name, fingerprint), {fingerprint})]
    legacy = spec.legacy_fingerprint()
    if legacy is not None:
        accepted = {fingerprint, legacy}
        candidates += [(run_path(run_dir, spec.name, fp), accepted) for fp in (fingerprint, legacy)]
        candidates.append((Path(run_dir) / f"{spec.name}.json", accepted))
    for path, accepted in candidates:
        if not (path.exists() and policy_path(path).exists()):
            continue
        try:
            data = json.loads(path.read_text())
        except (ValueError, RecursionError):  # not JSON, or nested too deep to read
            continue
        if isinstance(data, dict) and data.get("fingerprint") in accepted:
            return path
    return None


def load_run(run_dir: Path, spec: RunSpec) -> RunRecord | None:
    """The kept run of ``spec``, or None if it is missing, unreadable or of another configuration."""
    path = kept_run_path(run_dir, spec)
    return None if path is None else RunRecord.from_json(json.loads(path.read_text()))


def policy_from_config(
    algo: str, variant: str, config: dict[str, Any], path: str | Path
) -> RawEnvPolicy:
    """The policy whose state dict is at ``path``, rebuilt from a run's recorded ``config``
    (its hyperparameters' ``policy_kwargs`` and its training environment,
    :func:`env_from_config`), acting on the raw environment.

    Raises
    ------
    InvalidRunError
        The file at ``path`` is not a state dict (truncated, not torch's) or does not fit the
        network ``config`` describes.
    """
    import torch
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.base_class import BaseAlgorithm

    env = env_from_config(config, variant)
    classes: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "sac": SAC, "td3": TD3}
    cls = classes[algo]
    kwargs = copy.deepcopy(config["hyperparams"].get("policy_kwargs", {}))
    policy = cls.policy_aliases["MlpPolicy"](
        env.observation_space, env.action_space, lambda _: 0.0, **kwargs
    )
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - truncated, not torch's, or not weights alone
        raise InvalidRunError(
            f"the policy file {path} cannot be read ({type(exc).__name__}: "
            f"{' '.join(str(exc).split())[:200]}); expected the state dict a training saved"
        ) from None
    try:
        policy.load_state_dict(state)
    except (RuntimeError, TypeError, AttributeError) as exc:  # another network's weights
        raise InvalidRunError(
            f"the policy file {path} does not fit the {algo.upper()} network its run record "
            f"describes ({' '.join(str(exc).split())[:200]}): another run's policy, or an edited "
            "record"
        ) from None
    policy.set_training_mode(False)
    return RawEnvPolicy(policy, env)


def load_policy(spec: RunSpec, path: str | Path) -> RawEnvPolicy:
    """The trained policy of ``spec`` from its state dict at ``path``, acting on the raw env."""
    return policy_from_config(spec.algo, spec.variant, spec.config(), path)
