"""Every design of the hidden setting scored on one task, on the same evaluation episodes.

With the mode hidden (``env_kwargs={"observe": "state"}``), on a task of the suite:

* the *oracle*: the task's receding-horizon controller seeing the true mode, at the task's ``xi``
  (the reference curve's point there); its sweep over ``xi`` is the reference curve
  (:func:`benchmarks.core.frontier.reference_curve`, on the episodes of every seed of
  :data:`EVAL_SEEDS` pooled), so a design's gap to the curve at its own violation frequency
  (:attr:`benchmarks.core.evaluate.Score.curve_gap`) is the price of not seeing the mode at
  equal risk, and its *bounded gap* (:attr:`benchmarks.core.evaluate.Score.bounded_gap`) the
  score every run has (every run counts: +100 for a diverged run or one riskier than the
  curve);
* *certainty equivalence*: the same controller given the mode filter's most probable mode
  (``HiddenModePolicy(RecedingHorizonController(...))``);
* the *belief RHC*: problem P3 on the filter's belief
  (``HiddenModePolicy(BeliefRecedingHorizonController(...))``);
* every kept agent of the hidden comparison (``benchmarks.rl``'s ``hidden_runs`` and
  ``load_agent``).

Each is scored by :func:`benchmarks.core.evaluate.evaluate`'s protocol on the episodes of every seed of
:data:`EVAL_SEEDS` (pooled); a design *keeps the system bounded* when none of its evaluation
episodes diverged. For the designs that decide from the filter (certainty equivalence, the
belief RHC, the agents fed the belief) the filter's accuracy is measured on the same episodes
(:func:`filter_accuracy`, on the rollouts the score was computed from).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from benchmarks.core.environment import resolve_env
from benchmarks.core.evaluate import Score, score_policy_rollouts
from benchmarks.core.frontier import ReferenceCurve, reference_curve
from benchmarks.core.montecarlo import Rollouts
from benchmarks.core.stats import EpisodeStatistics
from controllers import (
    BeliefRecedingHorizonController,
    HiddenModePolicy,
    ModeFilter,
    RecedingHorizonController,
)
from sdjls_gym.errors import ImpossibleObservationError
from sdjls_gym.systems import TASKS

__all__ = [
    "CONTROLLERS",
    "EVAL_SEEDS",
    "HIDDEN",
    "ORACLE",
    "DesignScore",
    "FilterAccuracy",
    "TaskResult",
    "filter_accuracy",
    "score_task",
]

#: The noise seeds of the evaluation episodes, one constant for every design: the core pools
#: their episodes (``benchmarks.core.evaluate.evaluate(seed=EVAL_SEEDS)``, the oracle's curve
#: ``reference_curve(task, episodes, EVAL_SEEDS)``), and the filter's accuracy pools the same.
EVAL_SEEDS: tuple[int, ...] = (0, 1, 2)
#: The environment's keyword arguments of the hidden setting.
HIDDEN: dict[str, Any] = {"observe": "state"}
#: The names of the model-based designs.
ORACLE = "oracle (RHC seeing the mode)"
CE = "certainty equivalence"
BELIEF = "belief RHC"
CONTROLLERS = (CE, BELIEF)


@dataclass(frozen=True)
class FilterAccuracy:
    """The mode filter along a design's evaluation episodes, at its decisions ``k = 1 .. T-1``
    (at ``k = 0`` the belief is the model's known ``mode0``) of the episodes not yet diverged.

    ``top_share``: share of those steps whose most probable mode (ties: the smallest index) is
    the true one; ``true_probability``: the mean probability the belief gives the true mode."""

    steps: int
    top_share: float
    true_probability: float


@dataclass(frozen=True)
class DesignScore(EpisodeStatistics):
    """One design on one task: ``kind`` is ``"oracle"``, ``"controller"`` or ``"agent"``
    (``configuration`` its configuration's name, ``seed`` its training seed).

    ``episodes`` counts every seed's. ``gap`` is the cost minus the oracle's curve at the
    design's violation frequency, paired over the episodes, in % of the curve's cost
    (``gap_ci95`` its 95% bootstrap interval), None with ``gap_reason`` when there is none (a
    diverged episode, a violation frequency outside the curve's range). ``bounded_gap`` is the
    score every run has (:func:`benchmarks.core.frontier.bounded_gap`, in ``[-100, 100]``) and
    ``bounded_gap_rule`` the rule that gave it (``"gap"``, ``"diverged"``, ``"riskier than the
    curve"``, ``"safer than the curve"``); the oracle's are 0 and ``"gap"``."""

    name: str
    kind: str
    configuration: str
    seed: int | None
    gap: float | None
    gap_ci95: tuple[float, float] | None
    gap_reason: str | None
    bounded_gap: float
    bounded_gap_rule: str
    xi_equivalent: float | None = None  # the oracle's level that violates as often
    filter: FilterAccuracy | None = None
    decision_time_s: float | None = None  # per state, batched
    scoring_cpu_s: float = 0.0

    @property
    def bounded(self) -> bool:
        """No evaluation episode diverged."""
        return self.diverged == 0


@dataclass
class TaskResult:
    """One task: its level ``xi``, the evaluation episodes (every seed's: ``episodes`` in all,
    ``episodes // len(seeds)`` per seed), the oracle's curve (its points on those episodes),
    every design, and the agent runs asked for but not kept (configuration -> seeds)."""

    env_id: str
    xi: float
    episodes: int
    seeds: tuple[int, ...]
    curve: list[dict[str, Any]]
    designs: list[DesignScore]
    missing: dict[str, list[int]] = field(default_factory=dict)

    def of(self, kind: str) -> list[DesignScore]:
        return [d for d in self.designs if d.kind == kind]


# ----------------------------------------------------------------------------- the filter
def _step_rows(mode_filter: ModeFilter, log_belief: np.ndarray, x: np.ndarray, u: np.ndarray,
               x_next: np.ndarray, k: int) -> np.ndarray:  # fmt: skip
    """One filter step of every row; a row no mode can explain goes back to the prior."""
    try:
        return mode_filter.step_batch(log_belief, x, u, x_next, k, log=True)
    except ImpossibleObservationError:
        pass
    out = np.empty_like(log_belief)
    with np.errstate(divide="ignore"):
        prior = np.log(mode_filter.initial_belief())
    for i in range(len(x)):  # rare
        try:
            out[i] = mode_filter.step_batch(log_belief[i : i + 1], x[i : i + 1], u[i : i + 1],
                                            x_next[i : i + 1], k, log=True)[0]  # fmt: skip
        except ImpossibleObservationError:
            out[i] = prior
    return out


def filter_accuracy(model: Any, rollouts: Sequence[Rollouts]) -> FilterAccuracy:
    """:class:`FilterAccuracy` of :class:`controllers.ModeFilter` run on the states and applied
    inputs of ``rollouts`` (the filter a hidden-mode policy keeps, re-run here with the true
    modes beside it), pooled over the rollouts."""
    mode_filter = ModeFilter(model)
    with np.errstate(divide="ignore"):
        prior = np.log(mode_filter.initial_belief())
    hits = probability = 0.0
    steps = 0
    for ro in rollouts:
        runs, T = ro.ended.shape
        log = np.tile(prior, (runs, 1))
        for k in range(T):
            live = ~ro.ended[:, k] & np.all(np.isfinite(ro.x[:, k]), axis=1)
            if k > 0:
                belief = np.exp(log - log.max(axis=1, keepdims=True))
                belief /= belief.sum(axis=1, keepdims=True)
                true = ro.mode[:, k]
                hits += float(np.sum((np.argmax(belief, axis=1) == true)[live]))
                probability += float(np.sum(belief[np.arange(runs), true][live]))
                steps += int(live.sum())
            if k + 1 < T:
                go = live & np.all(np.isfinite(ro.x[:, k + 1]), axis=1)
                if go.any():
                    log[go] = _step_rows(mode_filter, log[go], ro.x[go, k], ro.u[go, k],
                                         ro.x[go, k + 1], k)  # fmt: skip
    if steps == 0:
        return FilterAccuracy(0, float("nan"), float("nan"))
    return FilterAccuracy(steps, hits / steps, probability / steps)


# ----------------------------------------------------------------------------- scoring
def _evaluate(policy: Any, env_id: str, episodes: int) -> tuple[Score, Rollouts]:
    """:func:`benchmarks.core.evaluate.evaluate`'s protocol with the mode hidden on
    ``episodes`` episodes of each seed of :data:`EVAL_SEEDS`, pooled, and those rollouts (the
    filter's accuracy is measured on them)."""
    spec = resolve_env(env_id, {**TASKS[env_id].env_kwargs, **HIDDEN})
    return score_policy_rollouts(policy, spec, episodes, EVAL_SEEDS)


def design_score(name: str, kind: str, configuration: str, seed: int | None, score: Score,
                 accuracy: FilterAccuracy | None = None, cpu_s: float = 0.0) -> DesignScore:  # fmt: skip
    """A :class:`DesignScore` of an evaluation's :class:`Score` (on a task of the suite: it has
    a bounded gap)."""
    g = score.curve_gap
    gap = None if g is None else g.relative
    if score.bounded_gap is None or score.bounded_gap_rule is None:
        raise ValueError(f"{name}: {score.env_id} has no reference curve, so no bounded gap")
    return DesignScore(
        name=name, kind=kind, configuration=configuration, seed=seed, episodes=score.episodes,
        cost_mean=score.cost_mean, cost_ci95=score.cost_ci95, cost_median=score.cost_median,
        violation=score.violation, violation_wilson95=score.violation_wilson95,
        diverged=score.diverged, gap=gap, gap_ci95=None if g is None else g.relative_ci95,
        gap_reason=score.curve_gap_reason if gap is None else None,
        bounded_gap=float(score.bounded_gap), bounded_gap_rule=score.bounded_gap_rule,
        xi_equivalent=None if g is None else g.xi, filter=accuracy,
        decision_time_s=score.decision_time_batched_s, scoring_cpu_s=cpu_s,
    )  # fmt: skip


def _curve(env_id: str, episodes: int) -> ReferenceCurve:
    """The oracle's curve on the evaluation episodes (``episodes`` of each seed of
    :data:`EVAL_SEEDS`, pooled; the curve :func:`_evaluate` scores against), with the task's
    ``xi`` among its levels."""
    task = TASKS[env_id]
    s = resolve_env(env_id, {**task.env_kwargs, **HIDDEN})
    curve = reference_curve(task, episodes, EVAL_SEEDS, horizon=s.horizon,
                            action_bound=s.action_bound, divergence_bound=s.divergence_bound)  # fmt: skip
    return curve.with_levels([float(task.rhc["xi"])])


def _oracle(curve: ReferenceCurve, xi: float) -> DesignScore:
    """The oracle's row: the curve's point at the task's ``xi`` (its gap and bounded gap are 0
    by definition)."""
    p = curve.point(curve.xis.index(xi))
    return DesignScore(
        name=ORACLE, kind="oracle", configuration=ORACLE, seed=None,
        episodes=curve.costs.shape[1], cost_mean=p["cost_mean"], cost_ci95=p["cost_ci95"],
        cost_median=p["cost_median"], violation=p["violation"],
        violation_wilson95=p["violation_wilson95"], diverged=p["diverged"], gap=0.0,
        gap_ci95=(0.0, 0.0), gap_reason=None, bounded_gap=0.0, bounded_gap_rule="gap",
        xi_equivalent=xi,
    )  # fmt: skip


def controllers(env_id: str) -> dict[str, HiddenModePolicy]:
    """The model-based designs of the hidden setting on ``env_id``, by name."""
    task = TASKS[env_id]
    rhc = RecedingHorizonController(task.model, task.K, horizon=task.horizon, **task.rhc)
    belief = BeliefRecedingHorizonController(task.model, task.K, horizon=task.horizon, **task.rhc)
    return {CE: HiddenModePolicy(rhc), BELIEF: HiddenModePolicy(belief)}


def score_task(env_id: str, runs: Sequence[Any], episodes: int, log: Any = None) -> TaskResult:
    """Every design of the hidden setting on ``env_id`` (see the module), the agents of
    ``runs`` (``benchmarks.rl.KeptRun`` of this task; those without a path are missing)."""
    task = TASKS[env_id]
    xi = float(task.rhc["xi"])
    curve = _curve(env_id, episodes)
    designs = [_oracle(curve, xi)]
    for name, policy in controllers(env_id).items():
        c0 = time.process_time()
        score, ro = _evaluate(policy, env_id, episodes)
        accuracy = filter_accuracy(task.model, [ro])
        designs.append(design_score(name, "controller", name, None, score, accuracy,
                                    time.process_time() - c0))  # fmt: skip
        if log is not None:
            log(f"{env_id}: {name}: cost {score.cost_mean:.4g}, violation "
                f"{score.violation:.3f}, diverged {score.diverged}, bounded gap "
                f"{score.bounded_gap:+.1f}% ({score.bounded_gap_rule})")  # fmt: skip
    missing: dict[str, list[int]] = {}
    kept = [r for r in runs if r.path is not None]
    for r in runs:
        if r.path is None:
            missing.setdefault(r.configuration, []).append(r.seed)
    if kept:
        from benchmarks.rl import load_agent, parse_config

        for r in kept:
            c0 = time.process_time()
            agent = load_agent(r.path)
            score, ro = _evaluate(agent, env_id, episodes)
            fed = parse_config(r.configuration)[2] == "belief"  # decides from the filter
            seen = filter_accuracy(task.model, [ro]) if fed else None
            designs.append(design_score(f"{r.configuration} s{r.seed}", "agent", r.configuration,
                                        r.seed, score, seen, time.process_time() - c0))  # fmt: skip
    points = [curve.point(i) for i in range(len(curve.xis))]
    return TaskResult(env_id, xi, curve.costs.shape[1], curve.seeds, points, designs, missing)
