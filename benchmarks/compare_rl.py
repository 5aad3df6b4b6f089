"""The receding-horizon controller against stable-baselines3 agents on cost and violation frequency.

Run ``python -m benchmarks.compare_rl --help`` for the options. On ``SDJLS-Macro-v0`` it trains
PPO, SAC and TD3 (``--algos``) with ``--seeds`` seeds each in six variants: on the reward alone
(``reward``), with a violation penalty ``reward - beta * info["cost"]`` for three values of
``beta`` (``beta100``, ``beta1000``, ``beta10000``), as residual agents choosing ``nu`` on top of
the paper's gains (``residual``, with the middle penalty beta = 1000), and with ``beta`` adapted
by dual ascent to hold the violation frequency at ``1 - xi = 0.15`` (``lagrangian``). Every agent
and every model-based controller (the paper's receding-horizon controller at xi = 0.85 with
individual and joint constraints and over a sweep of xi, the unconstrained receding-horizon
controller, the linear feedback ``u = K x`` and the MJLS LQ regulator) is then scored on the same
``--eval-episodes`` episodes (the same noise: common random numbers).

Outputs under ``--out`` (default ``results/rl/``): ``summary.csv``, ``summary.json``, the
figures, ``REPORT.md``, and per training run ``runs/<name>.json`` (its learning curve, dual
ascent and training time) and ``runs/<name>.pt`` (the trained SB3 policy's state dict, 40-130
KB). A run whose files exist with the same training configuration is not trained again, so an
interrupted run resumes where it stopped (``--retrain`` trains anew). The evaluation is not
cached: after the training, every controller and every kept policy is scored in the main process
on the same ``--eval-episodes`` episodes, so a change of the evaluation needs no training.

Compute: measured on the 2-core development machine, with one torch thread per process and two
trainings in parallel: PPO trains at about 6300 to 9300 env steps/s, SAC at about 165 to 310
and TD3 at about 290 to 630 (the machine is shared: the speed of one configuration varied by up
to 2x between days). The default budgets (:func:`benchmarks.rl_hyperparams.timesteps`: PPO
2.5M steps, SAC 60k, TD3 100k, raised per variant where the learning curves still moved, up to
14M, 800k and 1.2M; 4 to 62 minutes per run) make the default run from scratch (3 x 3 x 6 = 54
trainings on ``--workers 2``, with their learning curves) take about 9 h: the committed run's
trainings took 19.1 h in all (the sum of their ``train_time_s``), measured over three days; 1.0 h
of it is the three SAC beta10000 runs' waiting, trained three at a time on the two cores (3.1 h
of wall time for 2.1 h of CPU, ``cpu_time_s`` in their run files). If
the main process is killed, its worker processes end with it (Linux), and a new start reuses the
finished runs.
"""

from __future__ import annotations

import argparse
import copy
import csv
import hashlib
import json
import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from benchmarks import rl_hyperparams as HP
from benchmarks.montecarlo import Rollouts, mean_ci, paper_rhc, wilson
from benchmarks.rl_eval import DecisionStates, SB3Policy, decision_time, evaluate, make_train_env
from controllers import (
    LinearFeedbackController,
    MJLSLQRController,
    RecedingHorizonController,
    UnconstrainedRecedingHorizonController,
    tightened_set_empty,
)
from sdjls_gym.systems.macro import ACTION_BOUND, HORIZON, PAPER_K, PAPER_RHC, macro

ALGOS = ("ppo", "sac", "td3")
VARIANTS = ("reward", *(f"beta{b:g}" for b in HP.BETAS), "residual", "lagrangian")
XI_SWEEP = (0.3, 0.5, 0.7, 0.8, 0.85, 0.9, 0.95, 0.99)
XI = PAPER_RHC["xi"]
INCOME_TRAJECTORIES = 30  # incomes kept per controller for the trajectory figure
TIMING_STATES = 1000
#: How the evaluations made during training (learning curve, dual ascent) treat a diverged
#: episode; part of a run's fingerprint, so that runs scored by an older rule are trained again.
CURVE_SCORING = "a diverged episode holds its state; its later steps count as violated"


@dataclass
class Options:
    algos: list[str] = field(
        default_factory=lambda: list(ALGOS),
        metadata={"help": "stable-baselines3 algorithms to train", "nargs": "+", "choices": ALGOS},
    )
    variants: list[str] = field(
        default_factory=lambda: list(VARIANTS),
        metadata={"help": "training variants", "nargs": "+", "choices": VARIANTS},
    )
    timesteps: int | None = field(
        default=None,
        metadata={
            "help": "env steps per training run (default: per algorithm, "
            + ", ".join(f"{a} {n}" for a, n in HP.TIMESTEPS.items())
            + ", raised for some variants: "
            + ", ".join(f"{a} {v} {n}" for (a, v), n in HP.TIMESTEPS_VARIANT.items())
            + f"; {HP.QUICK_TIMESTEPS} with --quick; N replaces them all)"
        },
    )
    seeds: int = field(default=3, metadata={"help": "training seeds per algorithm and variant"})
    eval_episodes: int = field(
        default=1000,
        metadata={
            "help": "evaluation episodes per controller and per trained agent (one noise seed for all)"
        },
    )
    seed: int = field(default=0, metadata={"help": "noise seed of the evaluation episodes"})
    out: Path = field(
        default=Path("results/rl"),
        metadata={"help": "folder for figures, summary files, REPORT.md and runs/ (*.json, *.pt)"},
    )
    workers: int = field(
        default=2, metadata={"help": "trainings run in parallel (one torch thread each)"}
    )
    quick: bool = field(
        default=False,
        metadata={
            "help": f"smoke test: {HP.QUICK_TIMESTEPS} steps per run, 200 evaluation episodes, "
            "3 learning-curve points of 20 episodes"
        },
    )
    retrain: bool = field(
        default=False, metadata={"help": "train again even when runs/ has the trained run"}
    )
    no_progress: bool = field(default=False, metadata={"help": "do not show the progress bar"})


def parse_args(argv: list[str] | None = None) -> Options:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.compare_rl",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    explicit: set[str] = set()

    class Record(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):  # noqa: ANN001
            explicit.add(self.dest)
            setattr(namespace, self.dest, values)

    for f in fields(Options):
        flag = "--" + f.name.replace("_", "-")
        meta = f.metadata
        if f.type in ("bool", bool):
            parser.add_argument(flag, action="store_true", help=meta["help"])
        elif "nargs" in meta:
            parser.add_argument(
                flag,
                nargs=meta["nargs"],
                choices=meta["choices"],
                default=f.default_factory(),
                action=Record,
                help=meta["help"],
            )
        else:
            conv = Path if f.name == "out" else int
            default = None if f.default is None else f.default
            parser.add_argument(flag, type=conv, default=default, action=Record, help=meta["help"])
    ns = parser.parse_args(argv)
    opts = Options(**vars(ns))
    if opts.quick and "eval_episodes" not in explicit:
        opts.eval_episodes = 200
    for name in ("seeds", "workers"):
        if getattr(opts, name) < 1:
            parser.error(
                f"--{name.replace('_', '-')} = {getattr(opts, name)}; expected a positive integer"
            )
    if opts.eval_episodes < 2:
        parser.error(
            f"--eval-episodes = {opts.eval_episodes}; expected an integer >= 2 (the cost "
            "intervals are over episodes)"
        )
    if opts.timesteps is not None and opts.timesteps < 1:
        parser.error(f"--timesteps = {opts.timesteps}; expected a positive integer")
    opts.algos = list(dict.fromkeys(opts.algos))
    opts.variants = list(dict.fromkeys(opts.variants))
    return opts


# ---------------------------------------------------------------------------- model-based
def rhc(model, xi: float, constraint: str = "individual") -> RecedingHorizonController:
    return paper_rhc(model, xi, constraint)


def model_based_controllers(model) -> list[tuple[str, dict[str, Any], Any]]:
    """``(name, description, controller)`` of every model-based controller, sweep included."""
    out = []
    for constraint in ("individual", "joint"):
        for xi in XI_SWEEP:
            out.append(
                (
                    f"RHC {constraint} xi={xi:g}",
                    {"family": f"RHC {constraint}", "xi": xi, "constraint": constraint},
                    rhc(model, xi, constraint),
                )
            )
    out.append(
        (
            "RHC unconstrained",
            {"family": "RHC unconstrained"},
            UnconstrainedRecedingHorizonController(
                model,
                PAPER_K,
                PAPER_RHC["Psi"],
                alpha=PAPER_RHC["alpha"],
                nu_bound=PAPER_RHC["nu_bound"],
                horizon=HORIZON,
            ),
        )
    )
    out.append(
        (
            "Linear feedback (nu = 0)",
            {"family": "Linear feedback"},
            LinearFeedbackController(model, PAPER_K, horizon=HORIZON),
        )
    )
    out.append(
        ("MJLS LQR", {"family": "MJLS LQR"}, MJLSLQRController(model, "average", horizon=HORIZON))
    )
    return out


def incomes(ro: Rollouts, count: int = INCOME_TRAJECTORIES) -> list[list[float]]:
    """The first ``count`` income trajectories ``x_k(2)``, k = 0..T, rounded (for the figure)."""
    return np.round(ro.x[:count, :, 1], 4).tolist()


def scored(controller: Any, opts: Options) -> dict[str, Any]:
    """What the report keeps of one controller, model-based or trained: its statistics on the
    common evaluation episodes, its decision time, its largest |u|, the first incomes and (for
    the paired comparisons, not written out) every episode's cost and share of violated steps."""
    ro, stats = evaluate(macro(), controller, opts.eval_episodes, opts.seed, HORIZON, ACTION_BOUND)
    states = DecisionStates.from_rollouts(ro, min(TIMING_STATES, ro.x.shape[0] * HORIZON))
    return {
        **stats,
        "max_abs_u": float(np.max(np.abs(ro.u))),
        "decision_time_s": decision_time(controller, states.x, states.mode, states.k),
        "incomes": incomes(ro),
        "_episode_costs": ro.episode_cost,
        "_episode_violations": ro.any_violation.mean(axis=1),
    }


def evaluate_model_based(model, opts: Options) -> list[dict[str, Any]]:
    rows = [
        {"name": name, "kind": "model-based", **desc, "train_time_s": 0.0, **scored(ctrl, opts)}
        for name, desc, ctrl in model_based_controllers(model)
    ]
    for r in rows:
        if "constraint" in r:
            r["tightened_band_empty"] = empty_band_share(model, r["xi"], r["constraint"])
    return rows


def empty_band_share(model, xi: float, constraint: str) -> float:
    """Share of the (mode, next time) pairs of an episode at which the RHC's tightened band
    ``{y : G y <= H_{k+1} - t}`` is empty (:func:`controllers.tightened_set_empty`): there the QP
    is feasible only through its slack, ``rho > 0``, whatever the state."""
    return float(
        np.mean([tightened_set_empty(model, xi, k, constraint) for k in range(1, HORIZON + 1)])
    )


#: Bootstrap resamples of the episodes behind each paired curve gap (:func:`paired_curve_gap`),
#: and the seed that draws them (the same resamples for every agent).
GAP_RESAMPLES = 2000
GAP_SEED = 0


def paired_curve_gap(
    costs: np.ndarray,
    violations: np.ndarray,
    mb: list[dict[str, Any]],
    resamples: int = GAP_RESAMPLES,
    seed: int = GAP_SEED,
) -> dict | None:
    """Cost minus the RHC curve's at the agent's violation frequency, paired over the episodes.

    The curve is the individual-constraint RHC over the xi sweep (the ``mb`` rows of family
    ``"RHC individual"``, each with ``_episode_costs`` and ``_episode_violations``), linear between
    the two sweep points whose violation frequencies bracket the agent's. ``costs`` (E,) and
    ``violations`` (E,) are the agent's cost and share of violated steps on each of the common
    episodes (the same noise as the sweep's). The agent's frequency ``v`` is the mean of
    ``violations``; the gap is its mean cost minus the curve's interpolated at ``v``.

    The 95% interval is a percentile bootstrap over episodes (``resamples`` resamples, seed
    ``seed``): each resample recomputes the agent's cost and frequency and every sweep point's
    cost and frequency on the same resampled episodes, and interpolates anew (linearly
    extrapolated from the end segment where a resample's ``v`` leaves the curve's range). So the
    interval covers the sampling error of ``v`` and of the curve's frequencies, times the curve's
    slope, as well as the cost's; pairing removes the episode-to-episode spread the agent and the
    curve share. Returns ``{"mean", "ci95", "curve_cost", "violation"}`` (negative: cheaper than the
    curve), or None where ``v`` lies outside the curve's range.
    """
    costs = np.asarray(costs, dtype=np.float64)
    violations = np.asarray(violations, dtype=np.float64)
    if costs.shape != violations.shape or costs.ndim != 1 or costs.size < 2:
        raise ValueError(
            f"costs {costs.shape} and violations {violations.shape}: expected two arrays of the "
            "same length E >= 2 (one entry per evaluation episode)"
        )
    curve = [r for r in mb if r["family"] == "RHC individual"]
    c_cost = np.stack([np.asarray(r["_episode_costs"], dtype=np.float64) for r in curve])  # (P, E)
    c_viol = np.stack([np.asarray(r["_episode_violations"], dtype=np.float64) for r in curve])
    if c_cost.shape[1] != costs.size or len(curve) < 2:
        raise ValueError(
            f"the RHC curve has {len(curve)} point(s) on {c_cost.shape[1]} episodes; expected at "
            f"least 2 points on the agent's {costs.size} episodes"
        )

    def gaps(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Gap, curve cost and agent frequency for each row of episode weights (B, E)."""
        v = weights @ violations  # (B,)
        xs, ys = weights @ c_viol.T, weights @ c_cost.T  # (B, P)
        order = np.argsort(xs, axis=1, kind="stable")
        xs, ys = np.take_along_axis(xs, order, 1), np.take_along_axis(ys, order, 1)
        j = np.clip((xs < v[:, None]).sum(axis=1) - 1, 0, xs.shape[1] - 2)[:, None]
        x0, x1 = np.take_along_axis(xs, j, 1)[:, 0], np.take_along_axis(xs, j + 1, 1)[:, 0]
        y0, y1 = np.take_along_axis(ys, j, 1)[:, 0], np.take_along_axis(ys, j + 1, 1)[:, 0]
        span = x1 - x0
        w = np.where(span == 0, 1.0, (x1 - v) / np.where(span == 0, 1.0, span))
        ref = w * y0 + (1 - w) * y1  # weight w on the lower sweep point
        return weights @ costs - ref, ref, v

    E = costs.size
    (gap,), (ref,), (v,) = gaps(np.full((1, E), 1.0 / E))
    point_vs = c_viol.mean(axis=1)
    if not point_vs.min() <= v <= point_vs.max():
        return None
    rng = np.random.default_rng(seed)
    boot, _, _ = gaps(rng.multinomial(E, np.full(E, 1.0 / E), size=resamples) / E)
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return {
        "mean": float(gap),
        "ci95": [float(lo), float(hi)],
        "curve_cost": float(ref),
        "violation": float(v),
    }


# ---------------------------------------------------------------------------- RL runs
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
        """Everything the training depends on; a cached run is reused only if this matches.

        The evaluation (``--eval-episodes``, ``--seed``) is not in it: a run's policy is kept
        (``runs/<name>.pt``) and scored anew by every report. The learning curve and the dual
        ascent are measured during training, so their rollout rule (:data:`CURVE_SCORING`) is.
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


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def variant_setup(variant: str) -> tuple[str, float | None, bool]:
    """``(action_kind, beta or None, lagrangian)`` of a variant."""
    if variant == "reward":
        return "u", None, False
    if variant == "residual":
        return "residual", float(HP.RESIDUAL_BETA), False
    if variant == "lagrangian":
        return "u", float(HP.LAGRANGIAN["beta0"]), True
    if variant.startswith("beta"):
        return "u", float(variant[4:]), False
    raise ValueError(f"variant = {variant!r}; expected one of {VARIANTS}")


def build_agent(spec: RunSpec, env_fns: list) -> Any:
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


def _callbacks(spec: RunSpec, policy_factory, report) -> tuple[list, dict]:
    """Learning-curve evaluation and (for ``lagrangian``) dual ascent on beta."""
    from stable_baselines3.common.callbacks import BaseCallback

    model = macro()
    log: dict[str, Any] = {"curve": [], "dual": [], "eval_time": 0.0}
    _, beta0, lagrangian = variant_setup(spec.variant)
    state = {"beta": beta0}
    t_start = time.perf_counter()
    points = max(1, spec.curve_points)
    marks = [int(round(spec.timesteps * (i + 1) / points)) for i in range(points)]

    def timed_evaluation(agent, episodes: int, seed: int) -> dict[str, Any]:
        """The deterministic policy's statistics; the time goes to ``log["eval_time"]``."""
        t0 = time.perf_counter()
        _, stats = evaluate(model, policy_factory(agent), episodes, seed)
        log["eval_time"] += time.perf_counter() - t0
        return stats

    class Curve(BaseCallback):
        """Evaluate the deterministic policy at 0 steps and at every mark."""

        def __init__(self) -> None:
            super().__init__()
            self.next = 0

        def _record(self) -> None:
            stats = timed_evaluation(self.model, spec.curve_episodes, spec.curve_seed)
            log["curve"].append(
                {
                    "timesteps": int(self.num_timesteps),
                    "wall_s": time.perf_counter() - t_start,
                    "episode_cost_mean": stats["episode_cost"]["mean"],
                    "episode_cost_median": stats["episode_cost"]["median"],
                    "violation": stats["violation"]["freq"],
                    "diverged": stats["diverged"],
                    "beta": state["beta"],
                }
            )
            if report is not None:
                report(spec.name, int(self.num_timesteps))

        def _on_training_start(self) -> None:
            self._record()  # the untrained policy

        def _on_step(self) -> bool:
            while self.next < len(marks) and self.num_timesteps >= marks[self.next]:
                self.next += 1
                self._record()
            return True

    class DualAscent(BaseCallback):
        """beta <- max(0, beta + lr_dual * (violation frequency - (1 - xi))), the frequency
        measured on fresh evaluation episodes of the deterministic policy."""

        def __init__(self) -> None:
            super().__init__()
            self.violations = 0.0
            self.steps = 0
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
            freq = timed_evaluation(self.model, HP.LAGRANGIAN["episodes"], seed)["violation"][
                "freq"
            ]
            train_freq = self.violations / self.steps
            target = 1.0 - HP.LAGRANGIAN["xi"]
            beta = max(0.0, state["beta"] + HP.LAGRANGIAN["lr_dual"] * (freq - target))
            self.training_env.env_method("set_wrapper_attr", "beta", beta)
            seen = self.training_env.get_attr("beta")
            if not np.allclose(seen, beta):
                raise RuntimeError(f"beta was not set on the ViolationPenalty wrappers: {seen}")
            state["beta"] = beta
            log["dual"].append(
                {
                    "timesteps": int(self.num_timesteps),
                    "freq": freq,
                    "train_freq": train_freq,
                    "beta": beta,
                }
            )
            self.logger.record("lagrangian/beta", beta)
            self.logger.record("lagrangian/violation_freq", freq)
            self.logger.record("lagrangian/train_violation_freq", train_freq)
            self.violations, self.steps = 0.0, 0

    cbs = [Curve()]
    if lagrangian:
        cbs.insert(0, DualAscent())
    log["state"] = state  # the same dict the callbacks write to (its "eval_time" is a float)
    return cbs, log


def _train_setup(spec: RunSpec):
    """``(make_env, policy_factory)`` of a run: its training environment and evaluation adapter."""
    from stable_baselines3.common.monitor import Monitor

    model = macro()
    kind, beta, _ = variant_setup(spec.variant)
    K = PAPER_K if kind == "residual" else None
    u_bound = HP.U_BOUND if kind == "u" else ACTION_BOUND

    def make_env():
        return Monitor(make_train_env(kind, beta, HP.ENV, K, HP.RESIDUAL_NU_BOUND, u_bound))

    def policy_factory(agent):
        return SB3Policy(agent, model, kind, u_bound, HP.ENV, K, HP.RESIDUAL_NU_BOUND, HORIZON)

    return make_env, policy_factory


def policy_path(json_path: str | Path) -> Path:
    """Where the trained policy of the run recorded in ``json_path`` is kept."""
    return Path(json_path).with_suffix(".pt")


def train_run(spec: RunSpec, path: str | None, report=None) -> dict[str, Any]:
    """Train one agent; write its policy (``.pt``, the SB3 policy's state dict, tens of KB) and
    ``path`` (JSON: learning curve, dual ascent, training time) and return the record.

    Runs in a worker process: one torch thread, everything it needs rebuilt from ``spec``. The
    record has no evaluation yet: :func:`score_run` adds it, in the main process.
    """
    import torch

    torch.set_num_threads(1)
    make_env, policy_factory = _train_setup(spec)
    agent = build_agent(spec, [make_env])
    callbacks, log = _callbacks(spec, policy_factory, report)
    t0, c0 = time.perf_counter(), time.process_time()
    agent.learn(total_timesteps=spec.timesteps, callback=callbacks)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    result = {
        "name": spec.name,
        "kind": "rl-seed",
        "algo": spec.algo,
        "variant": spec.variant,
        "seed": spec.seed,
        "fingerprint": spec.fingerprint(),
        "config": spec.config(),
        "timesteps": int(agent.num_timesteps),
        # the whole agent.learn, with the evaluations made during training: the learning curve
        # (part of what the report shows) and the dual ascent's (part of the Lagrangian method)
        "train_time_s": wall,
        "wall_time_s": wall,
        # this process's CPU time over the same span: below the wall time when the training
        # shared its core (more trainings than cores, or other load on the machine)
        "cpu_time_s": cpu,
        "eval_time_s": log["eval_time"],
        "final_beta": log["state"]["beta"],
        "learning_curve": log["curve"],
        "dual_ascent": log["dual"],
    }
    if path is not None:
        pt = policy_path(path)
        torch.save(agent.policy.state_dict(), pt.with_suffix(".pt.tmp"))
        os.replace(pt.with_suffix(".pt.tmp"), pt)  # the policy first: a JSON implies its policy
        tmp = Path(path).with_suffix(".tmp")
        tmp.write_text(json.dumps(_jsonable(result)) + "\n")
        os.replace(tmp, path)
    return result


def load_policy(spec: RunSpec, path: str | Path) -> Any:
    """The trained SB3 policy of ``spec``, rebuilt from its state dict at ``path``."""
    import torch
    from stable_baselines3 import PPO, SAC, TD3

    make_env, _ = _train_setup(spec)
    env = make_env()
    cls = {"ppo": PPO, "sac": SAC, "td3": TD3}[spec.algo]
    kwargs = copy.deepcopy(HP.hyperparams(spec.algo, spec.variant).get("policy_kwargs", {}))
    policy = cls.policy_aliases["MlpPolicy"](
        env.observation_space, env.action_space, lambda _: 0.0, **kwargs
    )
    policy.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))
    policy.set_training_mode(False)
    env.close()
    return policy


def score_run(spec: RunSpec, run: dict[str, Any], path: str | Path, opts: Options) -> dict:
    """``run`` with its evaluation: the policy at ``path`` on the report's evaluation episodes
    (the model-based controllers' episodes), its decision time and incomes."""
    _, policy_factory = _train_setup(spec)
    result = scored(policy_factory(load_policy(spec, path)), opts)
    # the training record first, its long lists last (as the summary files show them)
    head = {k: v for k, v in run.items() if k not in ("learning_curve", "dual_ascent")}
    tail = {k: run[k] for k in ("learning_curve", "dual_ascent")}
    return head | result | tail


def _end_with_parent(parent: int) -> None:
    """Initializer of the worker processes: on Linux, have the kernel send SIGTERM to this process
    when the main process ends, however it ends (``kill``, ``pkill -f benchmarks.compare_rl``, an
    out-of-memory kill). Without it a spawned worker outlives the main process and goes on training
    and writing ``runs/*.json``. Elsewhere it does nothing."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM))  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - no prctl: keep the old behaviour
        return
    if os.getppid() != parent:  # the main process ended before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)  # pragma: no cover


def _worker(spec: RunSpec, path: str, queue) -> dict[str, Any]:
    def report(name: str, steps: int) -> None:
        queue.put((name, steps))

    return train_run(spec, path, report)


def run_specs(opts: Options) -> list[RunSpec]:
    lc = HP.LEARNING_CURVE
    specs = []
    for algo in opts.algos:
        for variant in opts.variants:
            steps = opts.timesteps or (
                HP.QUICK_TIMESTEPS if opts.quick else HP.timesteps(algo, variant)
            )
            for seed in range(opts.seeds):
                specs.append(
                    RunSpec(
                        algo=algo,
                        variant=variant,
                        seed=seed,
                        timesteps=steps,
                        curve_points=3 if opts.quick else lc["points"],
                        curve_episodes=20 if opts.quick else lc["episodes"],
                        curve_seed=lc["seed"],
                    )
                )
    return specs


def train_all(opts: Options, specs: list[RunSpec], log) -> list[dict[str, Any]]:
    """Train every run not already in ``out/runs/`` (in ``opts.workers`` processes).

    Returns the training records (no evaluation: see :func:`score_run`), in the order of
    ``specs``. A cached run is reused if its fingerprint matches and its policy file exists.
    """
    run_dir = opts.out / "runs"
    run_dir.mkdir(parents=True, exist_ok=True)
    results: dict[str, dict] = {}
    todo = []
    for spec in specs:
        path = run_dir / f"{spec.name}.json"
        if path.exists() and policy_path(path).exists() and not opts.retrain:
            try:
                cached = json.loads(path.read_text())
            except json.JSONDecodeError:
                cached = {}
            if cached.get("fingerprint") == spec.fingerprint():
                results[spec.name] = cached
                continue
        todo.append(spec)
    # longest first (by estimated training time), so that the workers finish close together
    todo.sort(key=lambda s: -s.timesteps / HP.STEPS_PER_SECOND[s.algo])
    if results:
        log(f"reusing {len(results)} finished run(s) from {run_dir} (--retrain to train again)")
    total = sum(s.timesteps for s in todo)
    bar = tqdm(total=total, desc="training", unit="step", disable=opts.no_progress or not todo)
    progress: dict[str, int] = {}

    def on_progress(name: str, steps: int) -> None:
        bar.update(max(0, steps - progress.get(name, 0)))
        progress[name] = max(steps, progress.get(name, 0))

    def finished(res: dict[str, Any], spec: RunSpec) -> None:
        on_progress(spec.name, spec.timesteps)
        results[spec.name] = res
        last = res["learning_curve"][-1]
        log(
            f"[done] {spec.name}: {res['timesteps']} steps in {res['train_time_s']:.0f} s; last "
            f"learning-curve point: median cost {last['episode_cost_median']:.4g}, violations "
            f"{last['violation']:.3f}, diverged {last['diverged']}/{spec.curve_episodes}"
        )

    if opts.workers == 1 or len(todo) <= 1:
        for spec in todo:
            log(f"[train] {spec.name} ({spec.timesteps} steps)")
            finished(train_run(spec, str(run_dir / f"{spec.name}.json"), on_progress), spec)
    else:
        import multiprocessing as mp
        from multiprocessing.managers import SyncManager

        ctx = mp.get_context("spawn")
        manager = SyncManager(ctx=ctx)
        manager.start(_end_with_parent, (os.getpid(),))
        pool = ProcessPoolExecutor(
            opts.workers, mp_context=ctx, initializer=_end_with_parent, initargs=(os.getpid(),)
        )
        try:
            queue = manager.Queue()
            pending = {}
            for spec in todo:
                fut = pool.submit(_worker, spec, str(run_dir / f"{spec.name}.json"), queue)
                pending[fut] = spec
            started: set[str] = set()
            while pending:
                done, _ = wait(pending, timeout=2.0, return_when=FIRST_COMPLETED)
                while not queue.empty():
                    name, steps = queue.get()
                    if name not in started:
                        started.add(name)
                        log(f"[train] {name}")
                    on_progress(name, steps)
                for fut in done:
                    spec = pending.pop(fut)
                    finished(fut.result(), spec)
        except BaseException:
            # Ctrl-C, or a training that raised: stop the other trainings now instead of waiting
            # for them (shutdown(wait=True) would), so nothing trains on after the error.
            for proc in list(getattr(pool, "_processes", {}).values()):
                proc.terminate()
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        else:
            pool.shutdown(wait=True)
        finally:
            manager.shutdown()
    bar.close()
    return [results[s.name] for s in specs]


# ---------------------------------------------------------------------------- aggregation
def aggregate(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (algorithm, variant): seeds pooled.

    ``episode_cost`` is the mean over seeds of each seed's mean, with a Student-t 95% interval
    over seeds (the spread between trainings, which dominates; cut at 0, and for a single seed
    that seed's interval over episodes), and the median over seeds of each seed's median;
    ``violation`` is the pooled per-step frequency with its Wilson interval over all pooled
    steps; ``violation_seed_range`` shows the spread between seeds.
    """
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in runs:
        groups.setdefault((r["algo"], r["variant"]), []).append(r)
    rows = []
    for (algo, variant), rs in groups.items():
        means = np.array([r["episode_cost"]["mean"] for r in rs])
        if len(rs) == 1:  # no spread between trainings to show: the episodes' interval
            mean, (lo, hi) = float(means[0]), rs[0]["episode_cost"]["ci95"]
        else:
            mean, lo, hi = mean_ci(means, floor=0.0)
        steps = sum(r["episodes"] * r["steps"] for r in rs)
        count = int(round(sum(r["violation"]["freq"] * r["episodes"] * r["steps"] for r in rs)))
        vlo, vhi = wilson(count, steps)
        freqs = [r["violation"]["freq"] for r in rs]
        rows.append(
            {
                "name": f"{algo.upper()} {variant}",
                "kind": "rl-aggregate",
                "algo": algo,
                "variant": variant,
                "seeds": len(rs),
                "episodes": int(sum(r["episodes"] for r in rs)),
                "steps": rs[0]["steps"],
                "episode_cost": {
                    "mean": mean,
                    "ci95": [lo, hi],
                    "median": float(np.median([r["episode_cost"]["median"] for r in rs])),
                },
                "violation": {"freq": count / steps, "wilson95": [float(vlo), float(vhi)]},
                "violation_seed_range": [min(freqs), max(freqs)],
                "diverged": int(sum(r["diverged"] for r in rs)),
                "timesteps": int(np.mean([r["timesteps"] for r in rs])),
                "train_time_s": float(np.mean([r["train_time_s"] for r in rs])),
                "decision_time_s": {
                    key: float(np.mean([r["decision_time_s"][key] for r in rs]))
                    for key in ("batched", "single")
                },
                "final_beta": (
                    float(np.mean([r["final_beta"] for r in rs]))
                    if rs[0]["final_beta"] is not None
                    else None
                ),
            }
        )
    return rows


def interval_check(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """How far the per-step Wilson intervals can be trusted: the largest ratio of the width of
    the interval over episodes (``violation["episode_t95"]``, which allows for dependence between
    the steps of an episode) to the Wilson width, among the single-policy rows (model-based
    controllers, trained seeds) with no diverged episode, and among those with one.

    Returns ``{"stable": {"rows", "max_ratio", "name"}, "diverging": {...}}`` (a part is ``None``
    where no row qualifies), or ``None`` if no row has both intervals with a positive width.
    """
    ratios: dict[str, list[tuple[float, str]]] = {"stable": [], "diverging": []}
    for r in rows:
        v = r["violation"]
        wilson_width = v["wilson95"][1] - v["wilson95"][0]
        if v.get("episode_t95") is None or wilson_width <= 0:
            continue
        ratio = (v["episode_t95"][1] - v["episode_t95"][0]) / wilson_width
        ratios["diverging" if r["diverged"] else "stable"].append((ratio, r["name"]))
    if not any(ratios.values()):
        return None
    return {
        part: {"rows": len(rs), "max_ratio": max(rs)[0], "name": max(rs)[1]} if rs else None
        for part, rs in ratios.items()
    }


def comparable(row: dict[str, Any], target: float) -> bool:
    """Comparable with the RHC at risk level ``target``: no diverged episode and a violation
    frequency of at most ``target`` + 0.05."""
    return row["diverged"] == 0 and row["violation"]["freq"] <= target + 0.05


def best_config(aggs: list[dict[str, Any]], target: float) -> dict[str, Any] | None:
    """The trained configuration (seeds aggregated) with the lowest mean cost among the
    :func:`comparable` ones; if there is none, the one with the fewest diverged episodes, then
    the fewest violations."""
    if not aggs:
        return None
    ok = [a for a in aggs if comparable(a, target)]
    if ok:
        return min(ok, key=lambda a: a["episode_cost"]["mean"])
    return min(aggs, key=lambda a: (a["diverged"], a["violation"]["freq"]))


def best_agent(
    aggs: list[dict[str, Any]], runs: list[dict[str, Any]], target: float
) -> dict[str, Any] | None:
    """The run shown as "the best agent": of :func:`best_config`'s seeds, the one with the median
    mean cost (the lower middle one for an even count; not the cheapest: that would pick the
    luckiest training on the very episodes it is scored on)."""
    best = best_config(aggs, target)
    if best is None:
        return None
    seeds = sorted(
        (r for r in runs if (r["algo"], r["variant"]) == (best["algo"], best["variant"])),
        key=lambda r: r["episode_cost"]["mean"],
    )
    return seeds[(len(seeds) - 1) // 2]


#: Flatness test of the learning curves (:func:`curve_status`): the largest changes between the
#: last 30% of training and the 30% before it that still count as flat.
FLAT_TOL: dict[str, float] = {"cost_rel": 0.10, "violation": 0.02, "diverged": 0.05}


def curve_status(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Has the learning curve flattened? Per (algo, variant), seeds averaged.

    The evaluation points after 70% of training (the *late window*; 80%, 90% and 100% with the
    default 10 points) are averaged and compared with as many points just before them (the
    *earlier window*; 50%, 60%, 70%). Windows rather than single points, because one point is
    100 episodes per seed: its violation frequency alone moves by a few hundredths between
    neighbouring points of a curve that has stopped changing (100 is the default,
    :data:`benchmarks.rl_hyperparams.LEARNING_CURVE`).

    Flat when, between the windows, the violation frequency changes by less than 0.02, the share
    of diverged evaluation episodes by less than 0.05, and the median episode cost by less than
    10% of the late window's. The cost condition applies only if the median evaluation episode
    does not diverge (in every seed, less than half the episodes diverge at every point of both
    windows): the median cost of a diverging episode measures how far the state ran off in 20
    steps, a number that jumps by factors of 2 to 4 between evaluations of the same policy, not
    the policy's quality. ``cost_rel_change`` is then None.
    """
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in runs:
        groups.setdefault((r["algo"], r["variant"]), []).append(r)
    out = []
    for (algo, variant), rs in groups.items():
        usable = [r for r in rs if len(r["learning_curve"]) >= 3]
        if not usable:
            continue
        n = min(len(r["learning_curve"]) for r in usable)
        curves = [r["learning_curve"][:n] for r in usable]
        episodes = [r["config"]["curve_episodes"] for r in usable]
        cost = np.mean([[p["episode_cost_median"] for p in c] for c in curves], axis=0)
        viol = np.mean([[p["violation"] for p in c] for c in curves], axis=0)
        div_seeds = np.array(
            [[p["diverged"] / e for p in c] for c, e in zip(curves, episodes, strict=True)]
        )  # (seeds, points)
        div = div_seeds.mean(axis=0)
        steps = np.array([p["timesteps"] for p in curves[0]])
        # the earlier window must not reach the first point (the untrained policy)
        width = max(1, min(int(np.sum(steps > 0.7 * steps[-1])), (n - 1) // 2))
        late = np.arange(n - width, n)
        early = np.arange(n - 2 * width, n - width)
        window = np.concatenate([early, late])
        dv = float(abs(viol[late].mean() - viol[early].mean()))
        dd = float(abs(div[late].mean() - div[early].mean()))
        # per seed: the seeds' medians are averaged, and one diverging median swamps the rest
        median_diverges = bool(np.any(div_seeds[:, window] >= 0.5))
        dc = None
        if not median_diverges:
            dc = float(
                abs(cost[late].mean() - cost[early].mean()) / max(abs(cost[late].mean()), 1e-12)
            )
        tol = FLAT_TOL
        flat = dv < tol["violation"] and dd < tol["diverged"]
        if dc is not None:
            flat = flat and dc < tol["cost_rel"]
        out.append(
            {
                "algo": algo,
                "variant": variant,
                "timesteps": int(steps[-1]),
                "episodes_per_point": int(min(episodes)),
                "late_window": [int(steps[late[0]]), int(steps[late[-1]])],
                "earlier_window": [int(steps[early[0]]), int(steps[early[-1]])],
                "violation_late": float(viol[late].mean()),
                "diverged_share_late": float(div[late].mean()),
                "median_episode_diverges": median_diverges,
                "cost_rel_change": dc,
                "violation_change": dv,
                "diverged_share_change": dd,
                "flat": bool(flat),
            }
        )
    return out


# ---------------------------------------------------------------------------- figures
def make_figures(
    out: Path,
    mb: list[dict],
    aggs: list[dict],
    runs: list[dict],
    best: dict | None,
    status: list[dict],
) -> list[str]:
    """Write the figures into ``out``; ``status`` is :func:`curve_status` of ``runs``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    names = []
    model = macro()
    # env steps as 200k, 1.2M: matplotlib's plain labels of 100000..800000 run into each other
    steps_format = FuncFormatter(
        lambda v, _: ("-" if v < 0 else "") + _fmt_steps(int(round(abs(v))))
    )

    def save(fig, name: str) -> None:
        fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        names.append(name)

    def errbars(ax, row, **kw) -> None:
        v, c = row["violation"], row["episode_cost"]
        ax.errorbar(
            v["freq"],
            c["mean"],
            xerr=[[v["freq"] - v["wilson95"][0]], [v["wilson95"][1] - v["freq"]]],
            yerr=[[max(c["mean"] - c["ci95"][0], 0.0)], [max(c["ci95"][1] - c["mean"], 0.0)]],
            capsize=2,
            **kw,
        )

    # cost against violation frequency: everything (log scale), and a zoom on the stable ones
    colors = {"ppo": "C0", "sac": "C1", "td3": "C2"}
    vmarks = dict(zip(VARIANTS, ("o", "v", "^", "<", "*", "X"), strict=True))
    markers = {"RHC unconstrained": "s", "Linear feedback": "D", "MJLS LQR": "P"}
    # the chance-constrained RHC only: the unconstrained one diverges (its mean is ~1e11)
    rhc_costs = [
        r["episode_cost"]["mean"] for r in mb if r["family"] in ("RHC individual", "RHC joint")
    ]
    zoom_max = 3.0 * max(rhc_costs)
    flat = {(c["algo"], c["variant"]): c["flat"] for c in status}
    fig, axes = plt.subplots(1, 2, figsize=(14, 6))
    for panel, ax in enumerate(axes):
        keep = (lambda r: True) if panel == 0 else (lambda r: r["episode_cost"]["mean"] <= zoom_max)
        for family, color in (("RHC individual", "k"), ("RHC joint", "0.45")):
            pts = sorted((r for r in mb if r["family"] == family), key=lambda r: r["xi"])
            ax.plot(
                [r["violation"]["freq"] for r in pts],
                [r["episode_cost"]["mean"] for r in pts],
                "-",
                color=color,
                lw=1.2,
                label=f"{family}, xi = {pts[0]['xi']:g}..{pts[-1]['xi']:g}",
            )
            for r in pts:
                errbars(ax, r, fmt="o", color=color, ms=4)
                if family == "RHC individual" and r["xi"] in (0.3, 0.5, 0.7, 0.85, 0.99):
                    ax.annotate(f"xi={r['xi']:g}", (r["violation"]["freq"], r["episode_cost"]["mean"]),
                                textcoords="offset points", xytext=(3, 6), fontsize=7)  # fmt: skip
        for r in mb:
            if r["family"] in markers and keep(r):
                errbars(ax, r, fmt=markers[r["family"]], color="C7", ms=7, label=r["name"])
        for r in aggs:
            if keep(r):
                # hollow marker: the learning curve has not flattened (see curve_status)
                still = not flat.get((r["algo"], r["variant"]), True)
                errbars(
                    ax,
                    r,
                    fmt=vmarks.get(r["variant"], "o"),
                    color=colors.get(r["algo"], "C3"),
                    ms=8,
                    mfc="none" if still else None,
                    label=r["name"] + (" (still learning)" if still else ""),
                )
        ax.axvline(1 - XI, color="r", ls=":", lw=1, label=f"1 - xi = {1 - XI:.2f}")
        ax.set_xlim(-0.02, 1.02)
        ax.set_xlabel("per-step violation frequency (95% Wilson interval)")
        ax.grid(alpha=0.3, which="both")
        if panel == 0:
            ax.set_yscale("log")
            ax.set_ylabel("mean episode cost (95% interval), log scale")
            ax.set_title("All controllers (trained agents: seeds pooled)")
        else:
            ax.set_ylabel("mean episode cost (95% interval)")
            ax.set_title(f"Zoom: mean episode cost <= {zoom_max:.3g}")
            ax.legend(fontsize=6.5, ncol=2, loc="best")
    fig.suptitle(
        "Cost against violations: the RHC over xi, one point per other controller"
        + (" (hollow: learning curve not flat yet)" if not all(flat.values()) else "")
    )
    save(fig, "fig_cost_violation.png")

    # learning curves
    algos = list(dict.fromkeys(r["algo"] for r in runs))
    if algos:
        fig, axes = plt.subplots(2, len(algos), figsize=(4.6 * len(algos), 7), squeeze=False)
        rhc_ref = next((r for r in mb if r["name"] == f"RHC individual xi={XI:g}"), None)
        for j, algo in enumerate(algos):
            for variant in VARIANTS:
                rs = [r for r in runs if r["algo"] == algo and r["variant"] == variant]
                curves = [r["learning_curve"] for r in rs if r["learning_curve"]]
                if not curves:
                    continue
                n = min(len(c) for c in curves)
                steps = np.array([p["timesteps"] for p in curves[0][:n]])
                for i, key in enumerate(("episode_cost_median", "violation")):
                    vals = np.array([[p[key] for p in c[:n]] for c in curves])
                    ax = axes[i, j]
                    (line,) = ax.plot(steps, vals.mean(axis=0), "-o", ms=3, label=variant)
                    ax.fill_between(
                        steps,
                        vals.min(axis=0),
                        vals.max(axis=0),
                        color=line.get_color(),
                        alpha=0.15,
                    )
            if rhc_ref is not None:
                axes[0, j].axhline(rhc_ref["episode_cost"]["median"], color="k", ls="--", lw=1,
                                   label="RHC xi=0.85")  # fmt: skip
                axes[1, j].axhline(rhc_ref["violation"]["freq"], color="k", ls="--", lw=1,
                                   label="RHC xi=0.85")  # fmt: skip
            axes[0, j].set_yscale("log")
            axes[0, j].set_title(f"{algo.upper()}: median episode cost (eval)")
            axes[1, j].set_title(f"{algo.upper()}: violation frequency (eval)")
            axes[1, j].set_ylim(-0.02, 1.02)
            for i in range(2):
                axes[i, j].set_xlabel("training env steps")
                axes[i, j].xaxis.set_major_formatter(steps_format)
                axes[i, j].grid(alpha=0.3, which="both")
            axes[0, j].legend(fontsize=7)
        save(fig, "fig_learning_curves.png")

    lag = [r for r in runs if r["variant"] == "lagrangian" and r["dual_ascent"]]
    if lag:
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
        for r in lag:
            d = r["dual_ascent"]
            steps = [p["timesteps"] for p in d]
            color = colors.get(r["algo"], "C3")
            label = f"{r['algo'].upper()} seed {r['seed']}"
            axes[0].plot(steps, [p["beta"] for p in d], color=color, alpha=0.8, label=label)
            axes[1].plot(steps, [p["freq"] for p in d], color=color, alpha=0.8, label=label)
            if all("train_freq" in p for p in d):
                axes[1].plot(steps, [p["train_freq"] for p in d], color=color, alpha=0.35, ls="--")
        axes[1].axhline(1 - XI, color="r", ls=":", label="target 1 - xi")
        axes[0].set_ylabel("beta")
        axes[0].set_yscale("symlog", linthresh=1000.0)
        axes[1].set_ylabel("violation frequency\n(dashed: exploring policy)")
        for ax in axes:
            ax.set_xlabel("training env steps")
            ax.xaxis.set_major_formatter(steps_format)
            ax.grid(alpha=0.3)
        axes[1].legend(fontsize=7)
        fig.suptitle("Lagrangian variant: dual ascent on beta")
        save(fig, "fig_lagrangian_beta.png")

    # incomes: the best agent next to the RHC
    rhc_ref = next((r for r in mb if r["name"] == f"RHC individual xi={XI:g}"), None)
    panels = [(f"RHC individual, xi = {XI:g}", rhc_ref)]
    if best is not None:
        panels.append((f"best agent: {best['name']}", best))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 3.8), sharey=True,
                             squeeze=False)  # fmt: skip
    T = HORIZON
    ks = np.arange(T + 1)
    H = model.H(ks)
    for ax, (title, row) in zip(axes[0], panels, strict=True):
        for i, traj in enumerate(row["incomes"]):
            ax.plot(
                ks, traj, color="C0", lw=0.6, alpha=0.6, label="income $x_k(2)$" if i == 0 else None
            )
        ax.plot(ks, -H[:, 0], "r-", lw=1.5, label="target band")
        ax.plot(ks, H[:, 1], "r-", lw=1.5)
        v = row["violation"]["freq"]
        ax.set_title(
            f"{title}\nviolations {v:.3f}, cost {row['episode_cost']['mean']:.4g}", fontsize=9
        )
        ax.set_xlabel("k (quarters)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    axes[0, 0].set_ylabel("national income $x_k(2)$")
    lo = min(-5.0, float(np.min(H[:, 1])) - 10)
    axes[0, 0].set_ylim(lo, float(H[-1, 1]) + 10)
    save(fig, "fig_income.png")
    return names


# ---------------------------------------------------------------------------- outputs
CSV_HEADER = [
    "name", "kind", "algo", "variant", "seed", "xi", "episodes", "episode_cost_mean",
    "episode_cost_lo", "episode_cost_hi", "episode_cost_median", "violation", "violation_lo",
    "violation_hi", "diverged", "timesteps", "train_time_s", "decision_time_batched_s",
    "decision_time_single_s", "final_beta", "curve_gap", "curve_gap_lo", "curve_gap_hi",
    "violation_episode_lo", "violation_episode_hi",
]  # fmt: skip


def csv_row(r: dict[str, Any]) -> list[Any]:
    c, v, d = r["episode_cost"], r["violation"], r["decision_time_s"]
    beta, g = r.get("final_beta"), r.get("curve_gap")
    gap = (
        ["", "", ""]
        if g is None
        else [f"{g['mean']:.6g}", f"{g['ci95'][0]:.6g}", f"{g['ci95'][1]:.6g}"]
    )
    return [
        r["name"], r["kind"], r.get("algo", ""), r.get("variant", ""), r.get("seed", ""),
        r.get("xi", ""), r["episodes"], f"{c['mean']:.6g}", f"{c['ci95'][0]:.6g}",
        f"{c['ci95'][1]:.6g}", f"{c['median']:.6g}", f"{v['freq']:.6f}", f"{v['wilson95'][0]:.6f}",
        f"{v['wilson95'][1]:.6f}", r["diverged"], r.get("timesteps", 0), f"{r['train_time_s']:.1f}",
        f"{d['batched']:.3g}", f"{d['single']:.3g}", "" if beta is None else f"{beta:.6g}", *gap,
        *(["", ""] if v.get("episode_t95") is None else [f"{e:.6f}" for e in v["episode_t95"]]),
    ]  # fmt: skip


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_HEADER)
        for r in rows:
            w.writerow(csv_row(r))


def _fmt_cost(c: dict) -> str:
    return f"{c['mean']:.4g} ({c['ci95'][0]:.4g} to {c['ci95'][1]:.4g})"


def _fmt_v(v: dict) -> str:
    return f"{v['freq']:.3f} ({v['wilson95'][0]:.3f}-{v['wilson95'][1]:.3f})"


def _fmt_time(seconds: float) -> str:
    return f"{seconds * 1e6:.1f}" if seconds < 1 else f"{seconds:.3g} s"


def table(rows: list[dict[str, Any]]) -> list[str]:
    lines = [
        "| controller | episodes | mean episode cost (95% CI) | median cost | violation frequency "
        "(95% Wilson) | diverged | training steps | training time (s) | decision time per "
        "state, batched / single (us) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        d = r["decision_time_s"]
        steps = _fmt_steps(r["timesteps"]) if r.get("timesteps") else "-"
        lines.append(
            f"| {r['name']} | {r['episodes']} | {_fmt_cost(r['episode_cost'])} | "
            f"{r['episode_cost']['median']:.4g} | {_fmt_v(r['violation'])} | {r['diverged']} | "
            f"{steps} | {r['train_time_s']:.0f} | {_fmt_time(d['batched'])} / "
            f"{_fmt_time(d['single'])} |"
        )
    return lines


def _fmt_range(values: list[float], fmt) -> str:
    """``"lo to hi"`` of ``values`` formatted by ``fmt``, or one number where the two read alike."""
    lo, hi = fmt(min(values)), fmt(max(values))
    return lo if lo == hi else f"{lo} to {hi}"


def _variant_changes_text(changes: dict[str, dict[str, Any]]) -> str:
    """The report's words for the per-variant hyperparameter changes (``""`` if none)."""
    if not changes:
        return ""

    def value(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:g}"
        if isinstance(v, str) and v.startswith(HP.LINEAR_SCHEDULE_PREFIX):  # HP.learning_rate
            return f"{v.removeprefix(HP.LINEAR_SCHEDULE_PREFIX)} falling linearly to 0"
        return str(v)

    return ", except " + "; ".join(
        f"{name.split()[0].upper()} {name.split()[1]}: "
        + ", ".join(f"{k} {value(v)}" for k, v in c.items())
        for name, c in changes.items()
    )


def _fmt_steps(n: int) -> str:
    """Three significant digits: 2500608 -> '2.5M', 60006 -> '60k', 1056 -> '1.06k'."""
    if n >= 1_000_000:
        return f"{n / 1e6:.3g}M"
    if n >= 1000:
        return f"{n / 1e3:.3g}k"
    return str(n)


def curve_table(status: list[dict[str, Any]]) -> list[str]:
    """The flatness test of :func:`curve_status`, one row per (algorithm, variant)."""
    lines = [
        "| agent | training steps | late window (steps) | violation frequency, late | "
        "change | diverged share, late | change | median cost change | flat |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for s in status:
        dc = s["cost_rel_change"]
        if dc is None:
            cost = "- (median episode diverges)"
        else:
            cost = f"{100 * dc:.1f}%" if dc < 10 else "> 1000%"
        lo, hi = s["late_window"]
        lines.append(
            f"| {s['algo'].upper()} {s['variant']} | {_fmt_steps(s['timesteps'])} | "
            f"{_fmt_steps(lo)}-{_fmt_steps(hi)} | {s['violation_late']:.3f} | "
            f"{s['violation_change']:.4f} | {s['diverged_share_late']:.2f} | "
            f"{s['diverged_share_change']:.4f} | {cost} | {'yes' if s['flat'] else '**no**'} |"
        )
    return lines


def reading(summary: dict[str, Any]) -> list[str]:
    """A short reading of the numbers, every sentence computed from them."""
    mb = {r["name"]: r for r in summary["model_based"]}
    ref = mb[f"RHC individual xi={XI:g}"]
    joint = mb[f"RHC joint xi={XI:g}"]
    aggs = summary["rl_aggregates"]
    v_ref, c_ref = ref["violation"]["freq"], ref["episode_cost"]["mean"]
    lines = [
        f"* The paper's controller (individual constraints, xi = {XI:g}) violates the band at "
        f"{v_ref:.3f} of the steps for a mean episode cost of {c_ref:.4g}; with joint constraints "
        f"{joint['violation']['freq']:.3f} for {joint['episode_cost']['mean']:.4g}. The linear "
        f"feedback and the MJLS LQR ignore the band: they are cheaper "
        f"({mb['Linear feedback (nu = 0)']['episode_cost']['mean']:.4g}, "
        f"{mb['MJLS LQR']['episode_cost']['mean']:.4g}) and violate at almost every step "
        f"({mb['Linear feedback (nu = 0)']['violation']['freq']:.3f}, "
        f"{mb['MJLS LQR']['violation']['freq']:.3f}).",
    ]
    lines += _empty_band_lines(summary["model_based"])
    if not aggs:
        return lines
    rhc_curve = sorted(
        (r for r in summary["model_based"] if r["family"] == "RHC individual"),
        key=lambda r: r["violation"]["freq"],
    )

    v_lo = rhc_curve[0]["violation"]["freq"]
    v_hi = rhc_curve[-1]["violation"]["freq"]

    def seed_gaps(a: dict[str, Any]) -> str:
        """Each seed's cost minus the RHC curve's at that seed's own violation frequency, paired
        over the common episodes (:func:`paired_curve_gap`)."""
        parts = []
        for r in summary["rl_runs"]:
            if (r["algo"], r["variant"]) != (a["algo"], a["variant"]):
                continue
            g = r.get("curve_gap")
            at = f"at {r['violation']['freq']:.3f}"
            parts.append(
                f"seed {r['seed']}: outside the curve's range {at}"
                if g is None
                else f"seed {r['seed']}: {g['mean']:+.0f} ({g['ci95'][0]:+.0f} to "
                f"{g['ci95'][1]:+.0f}) {at}"
            )
        return "; ".join(parts)

    safest = rhc_curve[0]
    diverging, above, below, unresolved = [], [], [], []
    safer, riskier, straddling = [], [], []
    for a in aggs:
        v, c = a["violation"]["freq"], a["episode_cost"]["mean"]
        text = f"{a['name']} (violations {v:.3f}, cost {c:.4g})"
        seeds = [
            r for r in summary["rl_runs"] if (r["algo"], r["variant"]) == (a["algo"], a["variant"])
        ]
        gaps = [r.get("curve_gap") for r in seeds]
        seed_vs = [r["violation"]["freq"] for r in seeds]
        if a["diverged"] > 0:
            diverging.append(a["name"])
        elif all(sv < v_lo for sv in seed_vs):
            safer.append(text)
        elif all(sv > v_hi for sv in seed_vs):
            riskier.append(text)
        elif any(g is None for g in gaps):
            straddling.append(f"{text}: {seed_gaps(a)}")
        else:
            # the curve at each seed's own frequency, averaged like the seeds' costs: the
            # difference of the two is the mean of the seeds' gaps
            curve_cost = float(np.mean([g["curve_cost"] for g in gaps]))
            detail = (
                f"{a['name']} (violations {v:.3f}, cost {c:.4g} against the curve's "
                f"{curve_cost:.4g} at the seeds' own violation frequencies; per seed, cost minus "
                f"the curve's, paired over the common episodes, with its 95% bootstrap interval: "
                f"{seed_gaps(a)})"
            )
            if all(g["ci95"][0] > 0 for g in gaps):
                above.append(a["name"])
            elif all(g["ci95"][1] < 0 for g in gaps):
                below.append(detail)
            else:
                unresolved.append(detail)
    lines.append(
        f"* Against the RHC curve over xi (individual constraints, violation frequencies "
        f"{v_lo:.3f}..{v_hi:.3f}, interpolated at each seed's frequency, compared episode by "
        f"episode): of {len(aggs)} trained configurations, {len(diverging)} diverged in some "
        f"episode; {len(above)} cost more than the curve in every seed"
        + (f" ({', '.join(above)})" if above else "")
        + (
            f"; below the curve in every seed: {', '.join(below)}"
            if below
            else "; none is below it in every seed"
        )
        + (
            f"; seeds on both sides of it or not resolved: {', '.join(unresolved)}"
            if unresolved
            else ""
        )
        + (
            f"; safer than every point of the curve (compare them with its safest point, "
            f"{safest['name']}: violations {safest['violation']['freq']:.3f}, cost "
            f"{safest['episode_cost']['mean']:.4g}): {', '.join(safer)}"
            if safer
            else ""
        )
        + (
            f"; riskier than every point of the curve (compare them with the linear feedback "
            f"and the LQR instead): {', '.join(riskier)}"
            if riskier
            else ""
        )
        + (
            f"; some seeds inside the curve's range and some outside it: {'; '.join(straddling)}"
            if straddling
            else ""
        )
        + "."
    )
    div = [a for a in aggs if a["diverged"] > 0]
    if div:
        lines.append(
            "* Diverged evaluation episodes (|x| > 1e6: the episode ends there, its remaining steps "
            "count as violated, and its cost is astronomical, which dominates the mean): "
            + ", ".join(f"{a['name']} {a['diverged']}/{a['episodes']}" for a in div)
            + ". The median cost is the readable number for those."
        )
    cheapest = best_config(aggs, 1 - XI)
    if cheapest is not None and comparable(cheapest, 1 - XI):
        lines.append(
            f"* At a comparable risk level (violation frequency <= {1 - XI + 0.05:.2f}, no "
            f"diverged episode) the cheapest trained configuration is {cheapest['name']}: cost "
            f"{_fmt_cost(cheapest['episode_cost'])}, violations {_fmt_v(cheapest['violation'])}, "
            f"against the RHC's {c_ref:.4g} and {v_ref:.3f}. The income figure shows its seed "
            f"with the median cost, {summary['best_agent']}."
        )
    else:
        lines.append(
            f"* No trained configuration holds a violation frequency <= {1 - XI + 0.05:.2f} "
            "without diverging."
        )
    lag = [a for a in aggs if a["variant"] == "lagrangian"]
    for a in lag:
        lines.append(
            f"* Lagrangian {a['algo'].upper()}: beta ended at {a['final_beta']:.4g} (mean over "
            f"seeds); evaluation violation frequency {_fmt_v(a['violation'])} against the target "
            f"1 - xi = {1 - XI:.2f} (seeds range {a['violation_seed_range'][0]:.3f}-"
            f"{a['violation_seed_range'][1]:.3f})."
        )
    status = summary["learning_curves"]
    flat = [f"{s['algo'].upper()} {s['variant']}" for s in status if s["flat"]]
    moving = [f"{s['algo'].upper()} {s['variant']}" for s in status if not s["flat"]]
    tol = FLAT_TOL
    lines.append(
        f"* Learning curves (last 30% of training against the 30% before it: violation frequency "
        f"changed by < {tol['violation']:g}, diverged share by < {tol['diverged']:g} and, where the "
        f"median episode does not diverge, median cost by < {100 * tol['cost_rel']:g}%; see "
        f"[Learning curves](#learning-curves)): flat for {len(flat)} of {len(status)}: "
        + (", ".join(flat) if flat else "none")
        + "; **still changing** for "
        + (", ".join(moving) if moving else "none")
        + ". Where they still change, the budget was too small to call the result converged, "
        "and more training might move those points."
    )
    train: dict[str, list[float]] = {}
    decide: dict[str, list[float]] = {}
    for a in aggs:
        train.setdefault(a["algo"], []).append(a["train_time_s"])
        decide.setdefault(a["algo"], []).append(a["decision_time_s"]["single"])
    lines.append(
        "* Price: the RHC needs no training and decides in "
        f"{_fmt_time(ref['decision_time_s']['single'])} us per state on its own "
        f"({_fmt_time(ref['decision_time_s']['batched'])} us batched); each agent trained for "
        + ", ".join(
            f"{k.upper()} {_fmt_range(v, lambda t: f'{t:.0f}')} s" for k, v in train.items()
        )
        + " (mean per run of each variant, one CPU thread; the budgets differ by variant), "
        "and decides, one state at a time, in "
        + ", ".join(f"{k.upper()} {_fmt_range(v, _fmt_time)} us" for k, v in decide.items())
        + " per state (range over the variants)."
        + _shared_cpu_text(summary["rl_runs"])
    )
    return lines


#: A training whose wall time exceeds its CPU time by more than this factor is named in the
#: reading: it shared its core, and its training time is not comparable with the others'.
SHARED_CPU_RATIO = 1.2


def _shared_cpu_text(runs: list[dict[str, Any]]) -> str:
    """The reading's note on trainings that shared a core (``train_time_s / cpu_time_s``; runs
    recorded before ``cpu_time_s`` existed are not judged)."""
    shared = [
        r
        for r in runs
        if r.get("cpu_time_s", 0) > 0 and r["train_time_s"] > SHARED_CPU_RATIO * r["cpu_time_s"]
    ]
    if not shared:
        return ""
    return (
        " These trainings shared a core, so their training time overstates what they need: "
        + ", ".join(
            f"{r['name']} {r['train_time_s']:.0f} s for {r['cpu_time_s']:.0f} s of CPU"
            for r in shared
        )
        + "."
    )


def _empty_band_lines(model_based: list[dict[str, Any]]) -> list[str]:
    """The reading's sentence on the RHC points whose tightened band is empty
    (``tightened_band_empty``, :func:`empty_band_share`)."""
    rows = [r for r in model_based if r.get("tightened_band_empty", 0.0) > 0.0]
    if not rows:
        return []
    always = [r for r in rows if r["tightened_band_empty"] == 1.0]
    some = [r for r in rows if r["tightened_band_empty"] < 1.0]

    def names(group: list[dict[str, Any]]) -> str:
        by_kind: dict[str, list[str]] = {}
        for r in group:
            by_kind.setdefault(r["constraint"], []).append(f"{r['xi']:g}")
        return "; ".join(f"{k} xi = {', '.join(v)}" for k, v in by_kind.items())

    parts = []
    if always:
        scores = {(r["episode_cost"]["mean"], r["violation"]["freq"]) for r in always}
        text = (
            f"* The RHC's tightened band is empty at every step and in every mode for "
            f"{names(always)} (the tightened set {{y : G y <= H_(k+1) - t}} has no point, "
            "`controllers.tightened_set_empty`): the QP is feasible only through its slack, "
            "rho > 0 at every step, and the slack absorbs the excess tightening. "
        )
        if len(scores) == 1:
            (c, v), n = next(iter(scores)), len(always)
            text += (
                f"Those {n} controllers score the same (cost {c:.4g}, violations {v:.3f}): "
                "raising xi there changes nothing, and the safe end of the RHC curves is one "
                "controller, not several."
            )
        else:
            text += (
                "Their scores (cost / violations): "
                + ", ".join(
                    f"{r['name']} {r['episode_cost']['mean']:.4g} / {r['violation']['freq']:.3f}"
                    for r in always
                )
                + "."
            )
        if any(r["constraint"] == "joint" and r["xi"] == XI for r in always):
            text += f" The paper's joint-constraint controller at xi = {XI:g} is one of them."
        parts.append(text)
    if some:
        parts.append(
            "* The RHC's tightened band is empty at some steps (rho > 0 there) for "
            + ", ".join(
                f"{r['name']} ({100 * r['tightened_band_empty']:.0f}% of the steps and modes)"
                for r in some
            )
            + "."
        )
    return parts


def _interval_check_text(check: dict[str, Any] | None) -> str:
    """The report's sentence on :func:`interval_check`."""
    if check is None:
        return ""
    text = (
        " Checked against a Student-t interval over the episodes' shares of violated steps, which "
        "allows for dependence between the steps of an episode (`episode_t95` in summary.json):"
    )
    st, dv = check["stable"], check["diverging"]
    if st is not None:
        text += (
            f" for the {st['rows']} controllers and trained seeds without a diverged episode, that "
            f"interval is at most {st['max_ratio']:.2f} times as wide as the Wilson interval "
            f"({st['name']})"
        )
    if dv is not None:
        text += (
            ("; " if st is not None else " ")
            + f"where episodes diverge, their held steps are all violated together and the Wilson "
            f"interval is too narrow: up to {dv['max_ratio']:.1f} times ({dv['name']}, over "
            f"{dv['rows']} such rows)"
        )
    return text + "."


def write_report(opts: Options, summary: dict[str, Any]) -> str:
    cmd = summary["command"]
    mb_rows = summary["model_based"]
    main_mb = [r for r in mb_rows if r.get("xi") in (None, XI)]
    rhc_u_max = max(r["max_abs_u"] for r in main_mb if r.get("xi") == XI)
    lines = [
        "# The receding-horizon controller against RL agents (SDJLS-Macro-v0)",
        "",
        f"Generated by `{cmd}`; every number below is computed by that command.",
        "",
        f"Every controller is scored on the same {opts.eval_episodes} episodes of 20 steps "
        f"(noise seed {opts.seed}, common random numbers). Episode cost: the sum of "
        "x'Qx + u'Ru over the episode, mean with a 95% Student-t interval (over episodes; for the "
        "aggregate of trained seeds, over the seeds' means; cut at 0), and the median (for the "
        "aggregates, the median of the seeds' medians). Violation frequency: the share of "
        "steps k = 1..20 whose state leaves the band G x <= H_k (any row), with a 95% Wilson "
        "interval (pooled over seeds for the aggregates, treating steps as independent: it shows "
        "the sampling error of one policy's frequency, not the spread between trainings, which "
        "the per-seed table shows)."
        + _interval_check_text(summary.get("violation_interval_check"))
        + " Diverged: episodes in which |x| exceeded 1e6; such an episode "
        "ends there (its cost is the cost up to then) and its remaining steps count as violated. "
        "Decision time: per state, over a batch of 1000 visited states and for one state at a "
        "time, every controller measured in the same process after the training. Training time: "
        "mean wall time per run on one CPU thread, with the evaluations made during training "
        "(learning curve; for `lagrangian` the dual ascent's, part of the method). Agents learn "
        "from a transformed reward, -log(1 + c / 100) of the penalized per-step cost c (see "
        "`benchmarks/rl_hyperparams.py`); every number here "
        "is the true cost.",
        "",
        f"Agents act on u, |u| <= {HP.U_BOUND:g} (the environment's bound is {ACTION_BOUND:g}; "
        f"the largest |u| of the RHC at xi = {XI:g} in these episodes is {rhc_u_max:.1f}), "
        "rescaled to [-1, 1], or, for `residual`, on nu with u = K x + nu, "
        f"|nu| <= {HP.RESIDUAL_NU_BOUND:g}; `beta<b>` trains on reward - b * info['cost']; "
        f"`residual` trains on reward - {HP.RESIDUAL_BETA:g} * info['cost']; "
        f"`lagrangian` adapts beta by dual ascent towards a violation frequency of 1 - xi = "
        f"{1 - XI:.2f} (start {HP.LAGRANGIAN['beta0']:g}, step {HP.LAGRANGIAN['lr_dual']:g}), "
        f"the frequency measured on {HP.LAGRANGIAN['episodes']} fresh episodes of the "
        "deterministic policy at each update. "
        "Budgets (env steps per run): "
        + "; ".join(
            f"{algo.upper()} " + ", ".join(f"{v} {_fmt_steps(n)}" for v, n in budgets.items())
            for algo, budgets in summary["timesteps"].items()
        )
        + f"; {opts.seeds} seed(s). Hyperparameters: `benchmarks/rl_hyperparams.py` "
        "(from rl-zoo3's Pendulum-v1 entries)"
        + _variant_changes_text(summary["hyperparams"]["variant_changes"])
        + ".",
        "",
        "## Results",
        "",
        *table(main_mb + summary["rl_aggregates"]),
        "",
        "## Reading",
        "",
        *reading(summary),
        "",
        "## Figures",
        "",
    ]
    captions = {
        "fig_cost_violation.png": "Mean episode cost against violation frequency: the RHC over "
        "xi (individual and joint constraints), one point per other controller (trained agents: "
        "seeds aggregated), 95% interval bars; hollow markers: agents whose learning curve has "
        "not flattened"
        + ("" if any(not c["flat"] for c in summary["learning_curves"]) else ", none in this run")
        + " (see Learning curves)",
        "fig_learning_curves.png": "Learning curves: median evaluation cost and violation "
        "frequency against training steps (mean over seeds, band from min to max), "
        f"{HP.LEARNING_CURVE['episodes']} fixed evaluation episodes per point",
        "fig_lagrangian_beta.png": "Lagrangian variant: beta, and the violation frequency it is "
        "updated from (the deterministic policy's, solid; the exploring policy's, dashed)",
        "fig_income.png": "Incomes under the RHC (xi = 0.85) and under the best trained agent: "
        + (
            "of the configuration with the lowest cost among those with violation frequency <= "
            f"{1 - XI + 0.05:.2f} and no diverged episode, "
            if summary["best_config_comparable"]
            else "no configuration holds a violation frequency <= "
            f"{1 - XI + 0.05:.2f} without diverging; of the one with the fewest diverged "
            "episodes, then the fewest violations, "
        )
        + "the seed with the median cost",
    }
    for name in summary["figures"]:
        lines += [f"![{captions[name]}]({name})", "", f"*{captions[name]}*", ""]
    if summary["learning_curves"]:
        lines += [
            "## Learning curves",
            "",
            "Seeds averaged. The late window is the evaluation points after 70% of training; it is "
            "compared with as many points just before it. Single points are too noisy for this: "
            f"each is {summary['learning_curves'][0]['episodes_per_point']} fixed evaluation "
            "episodes per seed. Where the median evaluation episode "
            "diverges, its cost measures how far the state ran off, so only the violation "
            "frequency and the diverged share are compared (`curve_status` in "
            "`benchmarks/compare_rl.py`).",
            "",
            *curve_table(summary["learning_curves"]),
            "",
        ]
    lines += [
        "## The RHC over xi",
        "",
        *table(mb_rows),
        "",
        "## Every trained run",
        "",
        *table(summary["rl_runs"]),
        "",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    argv = sys.argv[1:] if argv is None else list(argv)
    opts = parse_args(argv)
    opts.out.mkdir(parents=True, exist_ok=True)
    cmd = "python -m benchmarks.compare_rl" + ("" if not argv else " " + " ".join(argv))

    def log(msg: str) -> None:
        tqdm.write(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr)

    model = macro()
    specs = run_specs(opts)
    log(
        f"{len(specs)} training runs: {', '.join(opts.algos)} x {', '.join(opts.variants)} x "
        f"{opts.seeds} seed(s)"
    )
    trained = train_all(opts, specs, log)
    # every controller is scored after the training, in this process: the same machine load
    # for the decision times of all of them
    log(f"evaluating the model-based controllers on {opts.eval_episodes} episodes")
    mb = evaluate_model_based(model, opts)
    log(f"evaluating the {len(specs)} trained agents on the same episodes")
    import torch

    torch.set_num_threads(1)  # as in training, and for the agents' decision times
    runs = [
        score_run(spec, run, policy_path(opts.out / "runs" / f"{spec.name}.json"), opts)
        for spec, run in zip(specs, trained, strict=True)
    ]
    for r in runs:  # where the RHC curve is a fair reference: no divergence, inside its range
        r["curve_gap"] = (
            paired_curve_gap(r["_episode_costs"], r["_episode_violations"], mb)
            if r["diverged"] == 0
            else None
        )
    for r in mb + runs:
        del r["_episode_costs"], r["_episode_violations"]
    aggs = aggregate(runs)
    best = best_agent(aggs, runs, 1 - XI)
    best_row = best_config(aggs, 1 - XI)
    summary: dict[str, Any] = {
        "command": cmd,
        "options": {k: str(v) if isinstance(v, Path) else v for k, v in asdict(opts).items()},
        "timesteps": {
            a: {s.variant: s.timesteps for s in specs if s.algo == a and s.seed == 0}
            for a in opts.algos
        },
        "hyperparams": _jsonable(
            {
                "algorithms": {a: HP.HYPERPARAMS[a] for a in opts.algos},
                "variant_changes": {
                    f"{a} {v}": changes
                    for (a, v), changes in HP.HYPERPARAMS_VARIANT.items()
                    if a in opts.algos and v in opts.variants
                },
                "env": HP.ENV,
                "betas": HP.BETAS,
                "lagrangian": HP.LAGRANGIAN,
                "residual_nu_bound": HP.RESIDUAL_NU_BOUND,
                "learning_curve": HP.LEARNING_CURVE,
            }
        ),
        "model_based": mb,
        "rl_aggregates": aggs,
        "rl_runs": [{k: v for k, v in r.items() if k != "config"} for r in runs],
        "learning_curves": curve_status(runs),
        "violation_interval_check": interval_check(mb + runs),
        "best_config": None if best is None else f"{best['algo'].upper()} {best['variant']}",
        "best_config_comparable": bool(best_row is not None and comparable(best_row, 1 - XI)),
        "best_agent": None if best is None else best["name"],
    }
    summary["figures"] = make_figures(opts.out, mb, aggs, runs, best, summary["learning_curves"])
    summary = _jsonable(summary)
    (opts.out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    write_csv(opts.out / "summary.csv", mb + aggs + summary["rl_runs"])
    (opts.out / "REPORT.md").write_text(write_report(opts, summary))
    log(f"wrote {opts.out}/REPORT.md")
    for line in reading(summary):
        print(line)
    return summary


if __name__ == "__main__":
    main()
