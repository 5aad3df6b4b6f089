"""Training one stable-baselines3 agent of the RL comparison, and the files a run is kept in.

A run is described by a :class:`RunSpec` (algorithm, variant, seed, budget, learning-curve
settings). :func:`train_run` trains it and returns its :class:`RunRecord` (learning curve, dual
ascent, training time) and its policy's state dict (tens of KB); :func:`save_run` writes both
under ``runs/<name>-<fingerprint>.json`` and ``.pt``, named by the run's whole configuration
hashed into :meth:`RunSpec.fingerprint`, so that a run of another configuration never replaces a
kept one; :func:`load_run` reads the kept run of a spec back. Training runs in a
worker (a process or a Ray task); the files are written by the main process.
"""

from __future__ import annotations

import copy
import hashlib
import io
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import RescaleAction
from stable_baselines3.common.callbacks import BaseCallback

from benchmarks import rl_hyperparams as HP
from benchmarks.evaluate import resolve_env, statistics
from benchmarks.files import write_atomic
from benchmarks.montecarlo import rollout
from benchmarks.policies import RawEnvPolicy
from sdjls_gym.systems.macro import PAPER_K
from sdjls_gym.validation import check_choice, check_positive
from sdjls_gym.wrappers import (
    FiniteHorizon,
    ResidualAction,
    ScaleObservationReward,
    TerminateOutside,
    ViolationPenalty,
)

ALGOS = ("ppo", "sac", "td3")
VARIANTS = ("reward", *(f"beta{b:g}" for b in HP.BETAS), "residual", "lagrangian")
#: ``"u"``: the agent chooses ``u``; ``"residual"``: the offset ``nu`` of ``u = K_theta x + nu``.
ACTION_KINDS = ("u", "residual")
#: How the evaluations made during training (learning curve, dual ascent) treat a diverged
#: episode; part of a run's fingerprint, so that runs scored by another rule are trained again.
CURVE_SCORING = "a diverged episode holds its state; its later steps count as violated"


# ----------------------------------------------------------------------------- records
@dataclass(frozen=True)
class CurvePoint:
    """One learning-curve evaluation: the deterministic policy on the fixed curve episodes."""

    timesteps: int
    wall_s: float
    episode_cost_mean: float
    episode_cost_median: float
    violation: float
    diverged: int
    beta: float | None


@dataclass(frozen=True)
class DualPoint:
    """One dual-ascent update: the deterministic policy's frequency, the exploring policy's
    (``train_freq``, logged only) and the new ``beta``."""

    timesteps: int
    freq: float
    train_freq: float
    beta: float


@dataclass
class RunRecord:
    """What ``runs/<name>.json`` holds: one training, without its evaluation."""

    name: str
    algo: str
    variant: str
    seed: int
    fingerprint: str
    config: dict[str, Any]
    timesteps: int
    train_time_s: float  # the whole agent.learn, with the evaluations made during training
    wall_time_s: float
    final_beta: float | None
    learning_curve: list[CurvePoint]
    dual_ascent: list[DualPoint]
    cpu_time_s: float | None = None  # below the wall time when the training shared its core
    eval_time_s: float | None = None  # the learning curve's and the dual ascent's share
    kind: str = "rl-seed"

    @property
    def curve_episodes(self) -> int:
        return int(self.config["curve_episodes"])

    def to_json(self) -> dict[str, Any]:
        return _jsonable(asdict(self))

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RunRecord:
        known = {f.name for f in fields(cls)}
        data = {k: v for k, v in data.items() if k in known}
        data["learning_curve"] = [CurvePoint(**p) for p in data["learning_curve"]]
        data["dual_ascent"] = [DualPoint(**p) for p in data["dual_ascent"]]
        return cls(**data)


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


# ----------------------------------------------------------------------------- run specs
@dataclass(frozen=True)
class RunSpec:
    algo: str
    variant: str
    seed: int
    timesteps: int
    curve_points: int
    curve_episodes: int
    curve_seed: int

    @property
    def name(self) -> str:
        return f"{self.algo}_{self.variant}_s{self.seed}"

    def config(self) -> dict[str, Any]:
        """Everything the training depends on; a kept run is reused only if this matches.

        The final evaluation is not in it: a run's policy is kept and scored anew by every
        report. The learning curve and the dual ascent are measured during training, so their
        rollout rule (:data:`CURVE_SCORING`) is.
        """
        config = {
            **asdict(self),
            "curve_scoring": CURVE_SCORING,
            "hyperparams": _jsonable(HP.hyperparams(self.algo, self.variant)),
            "env": HP.ENV,
            "betas": list(HP.BETAS),
            "lagrangian": HP.LAGRANGIAN,
            "residual_nu_bound": HP.RESIDUAL_NU_BOUND,
            "residual_beta": HP.RESIDUAL_BETA,
        }
        if variant_setup(self.variant)[0] == "u":  # residual agents do not depend on it
            config["u_bound"] = HP.U_BOUND
        return config

    def fingerprint(self) -> str:
        text = json.dumps(self.config(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def variant_setup(variant: str) -> tuple[str, float | None, bool]:
    """``(action_kind, beta or None, lagrangian)`` of a variant."""
    if variant == "reward":
        return "u", None, False
    if variant == "residual":
        return "residual", float(HP.RESIDUAL_BETA), False
    if variant == "lagrangian":
        return "u", float(HP.LAGRANGIAN["beta0"]), True
    if variant.startswith("beta") and variant in VARIANTS:
        return "u", float(variant[4:]), False
    raise ValueError(f"variant = {variant!r}; expected one of {VARIANTS}")


def run_specs(
    algos: list[str], variants: list[str], seeds: int, timesteps: int | None, quick: bool
) -> list[RunSpec]:
    """Every (algorithm, variant, seed) run; ``timesteps`` replaces every default budget."""
    lc = HP.LEARNING_CURVE
    return [
        RunSpec(
            algo=algo,
            variant=variant,
            seed=seed,
            timesteps=timesteps or (HP.QUICK_TIMESTEPS if quick else HP.timesteps(algo, variant)),
            curve_points=3 if quick else lc["points"],
            curve_episodes=20 if quick else lc["episodes"],
            curve_seed=lc["seed"],
        )
        for algo in algos
        for variant in variants
        for seed in range(seeds)
    ]


# ----------------------------------------------------------------------------- environments
def make_train_env(
    action_kind: str,
    beta: float | None,
    env_hp: dict[str, Any] | None = None,
    K: np.ndarray | None = None,
    nu_bound: float = HP.RESIDUAL_NU_BOUND,
    u_bound: float | None = None,
) -> gym.Env:
    """``SDJLS-Macro-v0`` wrapped for training one agent.

    Parameters
    ----------
    action_kind : {"u", "residual"}
        See :data:`ACTION_KINDS`.
    beta : float or None
        Violation penalty (:class:`~sdjls_gym.wrappers.ViolationPenalty`); None trains on the
        reward alone. The Lagrangian variant changes it with ``env.set_wrapper_attr``.
    env_hp : dict, optional
        Scalings (:data:`benchmarks.rl_hyperparams.ENV`, the default).
    K : (N, m, n) array
        Gains under a residual agent.
    nu_bound : float
        Bound on ``|nu|`` of a residual agent.
    u_bound : float, optional
        Bound on ``|u|`` of an agent acting on ``u``: the environment is made with
        ``action_bound=u_bound``. None keeps the registered bound (200). Ignored for residual
        agents.

    Returns
    -------
    gymnasium.Env
        Observation ``[x / x_scale (clipped), one-hot, k / T]``, action in ``[-1, 1]``.
        :class:`~benchmarks.evaluate.RawEnvPolicy` undoes both for an agent trained on it.
    """
    action_kind = check_choice("action_kind", action_kind, ACTION_KINDS)
    if u_bound is not None:
        u_bound = check_positive("u_bound", u_bound, "the agent's bound on |u|")
    env_hp = dict(HP.ENV if env_hp is None else env_hp)
    if action_kind == "residual" or u_bound is None:
        env = gym.make("SDJLS-Macro-v0")
    else:
        env = gym.make("SDJLS-Macro-v0", action_bound=u_bound)
    if action_kind == "residual":
        if K is None:
            raise ValueError("a residual agent needs the gains K (N, m, n)")
        env = ResidualAction(env, K, nu_bound)
    one = np.ones(env.action_space.shape, dtype=np.float32)
    env = RescaleAction(env, -one, one)
    if beta is not None:
        env = ViolationPenalty(env, beta)
    bound = env_hp.pop("terminate_bound", None)
    env = ScaleObservationReward(env, **env_hp)
    if bound is not None:
        env = TerminateOutside(env, bound)
    return FiniteHorizon(env)


def _train_env(spec: RunSpec) -> gym.Env:
    kind, beta, _ = variant_setup(spec.variant)
    K = PAPER_K if kind == "residual" else None
    u_bound = HP.U_BOUND if kind == "u" else None
    return make_train_env(kind, beta, HP.ENV, K, HP.RESIDUAL_NU_BOUND, u_bound)


def build_agent(spec: RunSpec, env_fns: list[Callable[[], gym.Env]]) -> Any:
    """The stable-baselines3 algorithm of ``spec`` with the hyperparameters of rl_hyperparams."""
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.noise import NormalActionNoise
    from stable_baselines3.common.vec_env import DummyVecEnv

    hp = copy.deepcopy(HP.hyperparams(spec.algo, spec.variant))
    n_envs = hp.pop("n_envs")
    venv = DummyVecEnv(env_fns * n_envs if len(env_fns) == 1 else env_fns)
    if spec.algo == "td3":
        std = hp.pop("noise_std")
        hp["action_noise"] = NormalActionNoise(np.zeros(1), std * np.ones(1))
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

    def __init__(self, train_env: gym.Env, log: TrainingLog) -> None:
        self.env, self.log = train_env, log
        self.spec = resolve_env("SDJLS-Macro-v0", {})

    def __call__(self, agent: Any, episodes: int, seed: int) -> dict[str, Any]:
        t0 = time.perf_counter()
        s = self.spec
        ro = rollout(
            s.model, RawEnvPolicy(agent, self.env), episodes, s.horizon, seed, s.action_bound,
            None, s.divergence_bound,
        )  # fmt: skip
        self.log.eval_time += time.perf_counter() - t0
        return statistics(ro, s.divergence_bound)


class LearningCurve(BaseCallback):
    """Evaluate the deterministic policy before training and at ``spec.curve_points`` marks."""

    def __init__(
        self, spec: RunSpec, log: TrainingLog, evaluator: _Evaluator, report: Callable | None
    ) -> None:
        super().__init__()
        self.spec, self.log, self.evaluator, self.report = spec, log, evaluator, report
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
            self.report(self.spec.name, int(self.num_timesteps))

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
    evaluation episodes of the deterministic policy (:data:`~benchmarks.rl_hyperparams.LAGRANGIAN`).
    """

    def __init__(self, spec: RunSpec, log: TrainingLog, evaluator: _Evaluator) -> None:
        super().__init__()
        self.log, self.evaluator = log, evaluator
        self.violations, self.steps = 0.0, 0
        period = HP.LAGRANGIAN["period"]
        self.period = int(period[spec.algo] if isinstance(period, dict) else period)
        self.seeds = np.random.default_rng([HP.LAGRANGIAN["seed"], spec.seed])

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            self.violations += float(info["cost"])
            self.steps += 1
        return True

    def _on_rollout_end(self) -> None:
        if self.steps < self.period:
            return
        seed = int(self.seeds.integers(2**31))
        freq = self.evaluator(self.model, HP.LAGRANGIAN["episodes"], seed)["violation"]
        train_freq = self.violations / self.steps
        target = 1.0 - HP.LAGRANGIAN["xi"]
        beta = max(0.0, self.log.beta + HP.LAGRANGIAN["lr_dual"] * (freq - target))
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
) -> tuple[RunRecord, bytes]:
    """Train one agent: its record and its policy's state dict (``torch.save`` bytes).

    One torch thread; everything is rebuilt from ``spec``, so the result does not depend on
    the process or machine it runs in. ``report(name, timesteps)`` is called at each
    learning-curve point; ``should_stop()``, if given, can end the training
    (:class:`TrainingStopped`).
    """
    import torch
    from stable_baselines3.common.monitor import Monitor

    torch.set_num_threads(1)
    agent = build_agent(spec, [lambda: Monitor(_train_env(spec))])
    _, beta0, lagrangian = variant_setup(spec.variant)
    log = TrainingLog(beta=beta0)
    evaluator = _Evaluator(_train_env(spec), log)
    callbacks: list[BaseCallback] = [LearningCurve(spec, log, evaluator, report)]
    if lagrangian:
        callbacks.insert(0, DualAscent(spec, log, evaluator))
    if should_stop is not None:
        callbacks.append(StopWhen(should_stop))
    t0, c0 = time.perf_counter(), time.process_time()
    agent.learn(total_timesteps=spec.timesteps, callback=callbacks)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    if should_stop is not None and callbacks[-1].stopped:
        raise TrainingStopped(f"{spec.name} was stopped at {agent.num_timesteps} steps")
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
    """Write ``<name>-<fingerprint>.pt`` then ``.json`` (a JSON file implies its policy), each
    atomically (:func:`benchmarks.files.write_atomic`); only a run of the same configuration
    (``--retrain``) is replaced."""
    path = run_path(run_dir, record.name, record.fingerprint)
    write_atomic(policy_path(path), policy)
    write_atomic(path, json.dumps(record.to_json()) + "\n")
    return path


def kept_run_path(run_dir: Path, spec: RunSpec) -> Path | None:
    """The record file of the kept run of ``spec`` (with its policy beside it), or None.

    Reads ``<name>-<fingerprint>.json``, and the older layout ``<name>.json`` when the
    fingerprint recorded in it matches (such a file is read, never written)."""
    fingerprint = spec.fingerprint()
    for path in (run_path(run_dir, spec.name, fingerprint), Path(run_dir) / f"{spec.name}.json"):
        if not (path.exists() and policy_path(path).exists()):
            continue
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError):
            continue
        if isinstance(data, dict) and data.get("fingerprint") == fingerprint:
            return path
    return None


def load_run(run_dir: Path, spec: RunSpec) -> RunRecord | None:
    """The kept run of ``spec``, or None if it is missing, unreadable or of another configuration."""
    path = kept_run_path(run_dir, spec)
    return None if path is None else RunRecord.from_json(json.loads(path.read_text()))


def load_policy(spec: RunSpec, path: str | Path) -> RawEnvPolicy:
    """The trained policy of ``spec`` from its state dict at ``path``, acting on the raw env."""
    import torch
    from stable_baselines3 import PPO, SAC, TD3

    env = _train_env(spec)
    cls = {"ppo": PPO, "sac": SAC, "td3": TD3}[spec.algo]
    kwargs = copy.deepcopy(HP.hyperparams(spec.algo, spec.variant).get("policy_kwargs", {}))
    policy = cls.policy_aliases["MlpPolicy"](
        env.observation_space, env.action_space, lambda _: 0.0, **kwargs
    )
    policy.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))
    policy.set_training_mode(False)
    return RawEnvPolicy(policy, env)
