"""Training one stable-baselines3 (or sb3-contrib) agent of the RL comparison.

A run is described by a :class:`~benchmarks.rl.spec.RunSpec` (task, algorithm, variant,
observation, seed, budget, learning-curve settings, hyperparameter overrides).
:func:`train_run` trains it on the task's training environment
(:func:`benchmarks.rl.envs.make_train_env`'s recipe, rebuilt from the run's configuration by
:func:`env_from_config`) and returns its :class:`RunRecord` (learning curve, dual ascent,
training and CPU time) and its policy's state dict (tens of KB); :mod:`benchmarks.rl.run_files`
keeps both (:func:`save_run`, :func:`load_run`). Training runs in a worker (a process or a Ray
task); the files are written by the main process. The names of :mod:`benchmarks.rl.spec` and
:mod:`benchmarks.rl.run_files` are re-exported here.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from benchmarks.core.environment import resolve_env, rollout_statistics
from benchmarks.core.montecarlo import rollout
from benchmarks.rl import hyperparams as HP
from benchmarks.rl.belief_env import BeliefObservation, agent_policy
from benchmarks.rl.envs import (
    ACTION_KINDS,
    MACRO,
    VARIANTS,
    env_from_config,
    get_task,
    make_train_env,
    task_settings,
    variant_setup,
)
from benchmarks.rl.records import CurvePoint, DualPoint, RunRecord
from benchmarks.rl.run_files import (
    kept_run_path,
    load_policy,
    load_run,
    policy_from_config,
    policy_path,
    run_path,
    save_run,
)
from benchmarks.rl.spec import (
    AGENT_ALGOS,
    ALGOS,
    CURVE_SCORING,
    RunSpec,
    config_fingerprint,
    run_specs,
)

__all__ = [
    "ACTION_KINDS",
    "AGENT_ALGOS",
    "ALGOS",
    "CURVE_SCORING",
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
    "policy_path",
    "run_path",
    "run_specs",
    "save_run",
    "train_run",
    "variant_setup",
]


# ----------------------------------------------------------------------------- environments
def _train_env(spec: RunSpec, vectorized: bool = False) -> gym.Env:
    """The training environment of ``spec``; ``vectorized``: without its
    :class:`BeliefObservation`, which :func:`build_agent` then puts around the vector."""
    env = env_from_config(spec.config(), spec.variant)
    return env.env if vectorized and isinstance(env, BeliefObservation) else env


def build_agent(spec: RunSpec, env_fns: list[Callable[[], gym.Env]]) -> Any:
    """The stable-baselines3 algorithm of ``spec`` with the hyperparameters of rl_hyperparams
    (the recurrent PPO: sb3-contrib's ``RecurrentPPO`` with its ``MlpLstmPolicy``)."""
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.noise import NormalActionNoise
    from stable_baselines3.common.vec_env import DummyVecEnv

    hp = spec.hyperparams()
    n_envs = hp.pop("n_envs")
    venv: Any = DummyVecEnv(env_fns * n_envs if len(env_fns) == 1 else env_fns)
    if spec.observation == "belief" and not venv.env_is_wrapped(BeliefObservation)[0]:
        from benchmarks.rl.belief_vec import VecBeliefObservation

        venv = VecBeliefObservation(venv)  # the filter of every environment in one step
    if spec.algo == "td3":
        shape = venv.action_space.shape
        if shape is None:
            raise TypeError(f"{spec.task}'s action space {venv.action_space} has no shape")
        std, m = hp.pop("noise_std"), shape[0]
        hp["action_noise"] = NormalActionNoise(np.zeros(m), std * np.ones(m))
    if isinstance(hp.get("train_freq"), list):
        hp["train_freq"] = tuple(hp["train_freq"])
    hp["learning_rate"] = HP.learning_rate(hp["learning_rate"])  # "lin_<r>": a linear decay
    if spec.algo == "recurrent_ppo":
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO("MlpLstmPolicy", venv, seed=1000 + spec.seed, verbose=0,
                            device="cpu", **hp)  # fmt: skip
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
            s.model, agent_policy(agent, self.env), episodes, s.horizon, seed, s.action_bound,
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
        algo = HP.DUAL_PERIOD_OF.get(spec.algo, spec.algo)
        self.period = int(period[algo] if isinstance(period, dict) else period)
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
    agent = build_agent(spec, [lambda: Monitor(_train_env(spec, vectorized=True))])
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
