"""The scoring protocol across the suite: a policy scored on every task, as one benchmark.

>>> from benchmarks.core.suite import evaluate_suite
>>> from controllers import LinearFeedbackController
>>> suite = evaluate_suite(lambda task: LinearFeedbackController(task.model, task.K),
...                        tasks=("SDJLS-Solar-v0", "SDJLS-Degradation-v0"), episodes=20)
>>> tuple(round(r.scores[0].violation, 2) for r in suite.results)
(0.04, 0.33)

The protocol: on each task, ``make_policy(task)``'s policy is scored by
:func:`benchmarks.evaluate.evaluate` on ``episodes`` episodes of the raw environment from noise
seed ``seed`` (common random numbers: every policy, and every point of the task's reference
curve, sees the same noise). Its *normalized gap* is its cost minus the task's one-step
receding-horizon curve's at its own violation frequency, paired over the episodes, in percent of
the curve's cost, with a 95% bootstrap interval (:mod:`benchmarks.core.reference`): 0 is on the curve,
-10 is 10% cheaper than the RHC at the same violation frequency, +50 half as costly again. The
gap is undefined where an episode diverged or the policy's violation frequency lies outside the
curve's range (more often than the RHC at its loosest level, e.g. a controller that ignores the
constraint, or less often than at its strictest); the task then has no gap, and its reason is
stated.

Across tasks, with ``rliable`` (Agarwal et al. 2021, the reference implementation): the score of
a run on a task is the *improvement over the one-step RHC*, ``-gap`` (rliable expects higher is
better), and from it the interquartile mean (IQM) of the gaps with a stratified-bootstrap 95%
interval, the probability of improvement over the one-step RHC (whose own score is 0 on every
task: the share of tasks where the policy is cheaper than the curve, ties counting one half) and
a performance profile (the share of runs x tasks whose improvement exceeds each threshold). A
*run* is one independently trained copy of the policy (a training seed): ``make_policy(task)``
may return a list of policies, one per run, the same number on every task. A deterministic
controller is one run. The stratified bootstrap resamples runs within each task: **with one
run there is nothing to resample, and the interval is the point itself**; it measures the spread
between training seeds, not the evaluation noise of each task's gap, which the per-task 95%
intervals state. The aggregate needs a gap on every (run, task); otherwise it is None and
:attr:`SuiteScore.missing` says which are missing and why.

The command line is :mod:`benchmarks.suite` (``python -m benchmarks.suite``).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from benchmarks.core.aggregate import (
    AGGREGATE_RESAMPLES,
    PROFILE_TAUS,
    SuiteAggregate,
    aggregate_gaps,
    rliable_modules,
)
from benchmarks.core.evaluate import Score, check_evaluation, evaluate, resolve_env
from benchmarks.core.files import jsonable
from benchmarks.core.reference import curve_xis, gap_reason, reference_curve
from benchmarks.core.stats import CurveGap
from sdjls_gym import SUITE
from sdjls_gym.messages import a_type, describe
from sdjls_gym.systems import TASKS, Task
from sdjls_gym.validation import check_int

__all__ = [
    "AGGREGATE_RESAMPLES",
    "PROFILE_TAUS",
    "SuiteAggregate",
    "SuiteScore",
    "TaskResult",
    "aggregate_gaps",
    "check_tasks",
    "describe_suite",
    "evaluate_suite",
    "gap_reason",
]


# ----------------------------------------------------------------------------- records
@dataclass(frozen=True)
class TaskResult:
    """One task's scores: one :class:`~benchmarks.evaluate.Score` per run.

    Attributes
    ----------
    env_id : str
    scores : tuple of Score
        One per run, on the same episodes.
    gaps : tuple of (CurveGap or None)
        Each run's paired gap to the task's one-step RHC curve (``relative``: in percent of the
        curve's cost), None where undefined (see :attr:`reasons`).
    reasons : tuple of (str or None)
        Why a run's gap is undefined (None where it is defined).
    curve_xis : tuple of float
        The levels ``xi`` of the task's reference curve.
    """

    env_id: str
    scores: tuple[Score, ...]
    gaps: tuple[CurveGap | None, ...]
    reasons: tuple[str | None, ...]
    curve_xis: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        return {
            "env_id": self.env_id,
            "curve_xis": list(self.curve_xis),
            "runs": [
                {**s.to_dict(), "curve_gap": None if g is None else asdict(g), "reason": r}
                for s, g, r in zip(self.scores, self.gaps, self.reasons, strict=True)
            ],
        }


@dataclass(frozen=True)
class SuiteScore:
    """A policy scored on every task of the suite (see the module docstring).

    Attributes
    ----------
    tasks : tuple of str
        Env ids, in the order of :attr:`results` and of the columns of :attr:`gap_table`.
    episodes, seed, runs : int
    results : tuple of TaskResult
    gap_table : (runs, tasks) array or None
        Normalized gaps (%), None unless every (run, task) has one.
    aggregate : SuiteAggregate or None
        rliable's statistics of :attr:`gap_table`, None with it.
    missing : tuple of str
        Each undefined gap: ``"<env_id> run <i>: <reason>"``.
    """

    tasks: tuple[str, ...]
    episodes: int
    seed: int
    runs: int
    results: tuple[TaskResult, ...]
    gap_table: np.ndarray | None = field(repr=False, compare=False)
    aggregate: SuiteAggregate | None
    missing: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types (no per-episode arrays)."""
        return {
            "tasks": list(self.tasks),
            "episodes": self.episodes,
            "seed": self.seed,
            "runs": self.runs,
            "results": [r.to_dict() for r in self.results],
            "gap_table": None if self.gap_table is None else self.gap_table.tolist(),
            "aggregate": None if self.aggregate is None else self.aggregate.to_dict(),
            "missing": list(self.missing),
        }


# ----------------------------------------------------------------------------- scoring
def check_tasks(tasks: Any) -> tuple[Task, ...]:
    """``tasks`` as :class:`Task` records: a non-empty list or tuple of env ids of
    :data:`sdjls_gym.SUITE` or ``Task`` records, without repeats."""
    if isinstance(tasks, (str, Task)) or not isinstance(tasks, (list, tuple)):
        raise TypeError(
            f"tasks = {describe(tasks)} is {a_type(tasks)}; expected a list or tuple of env ids "
            "(str) or Task records"
        )
    if not tasks:
        raise ValueError("tasks = () is empty; expected at least one task")
    out = []
    for i, item in enumerate(tasks):
        if isinstance(item, Task):
            out.append(item)
        elif isinstance(item, str):
            if item not in TASKS:
                raise ValueError(f"tasks[{i}] = {item!r} is not a task of the suite; expected "
                                 f"one of {', '.join(SUITE)} (or a Task record)")  # fmt: skip
            out.append(TASKS[item])
        else:
            raise TypeError(
                f"tasks[{i}] = {describe(item)} is {a_type(item)}; expected an env id or a Task"
            )
    keys = [(t.env_id, json.dumps(jsonable(dict(t.env_kwargs)), sort_keys=True)) for t in out]
    if len(set(keys)) != len(keys):
        raise ValueError(f"tasks = {describe(tasks)} names a task twice; expected each once")
    return tuple(out)


def _policies(make_policy: Callable[[Task], Any], task: Task) -> list[Any]:
    made = make_policy(task)
    runs = list(made) if isinstance(made, (list, tuple)) else [made]
    if not runs:
        raise ValueError(f"make_policy({task.env_id!r}) returned no policy; expected a policy "
                         "or a non-empty list of them (one per run)")  # fmt: skip
    return runs


def evaluate_suite(
    make_policy: Callable[[Task], Any],
    tasks: Sequence[str | Task] = SUITE,
    episodes: int = 1000,
    seed: int = 0,
    *,
    progress: bool = False,
    resamples: int = AGGREGATE_RESAMPLES,
) -> SuiteScore:
    """Score the policies ``make_policy(task)`` on every task (see the module docstring).

    Parameters
    ----------
    make_policy : callable
        ``make_policy(task: Task)`` returns a policy for the task's raw environment (a controller
        with ``act_batch``, an SB3 agent, through ``RawEnvPolicy`` if it was trained behind
        wrappers, or a callable ``obs -> action``), or a list of them, one per run (training
        seed), the same number on every task.
    tasks : sequence of str or Task
        Env ids of :data:`sdjls_gym.SUITE` (default: all) or ``Task`` records (e.g.
        :func:`sdjls_gym.systems.random_task` with other arguments).
    episodes, seed : int
        As :func:`benchmarks.evaluate.evaluate`: episodes per task (>= 2), noise seed (>= 0).
    progress : bool
        Show a progress bar over the tasks.
    resamples : int
        Stratified-bootstrap resamples of the aggregate's intervals (>= 100).

    Returns
    -------
    SuiteScore

    Raises
    ------
    TypeError, ValueError
        A bad argument (checked before any episode is run), a policy :func:`evaluate`
        refuses, or a different number of runs on two tasks.
    """
    if not callable(make_policy):
        raise TypeError(f"make_policy = {describe(make_policy)} is {a_type(make_policy)}; "
                        "expected a function task -> policy")  # fmt: skip
    episodes, seed = check_evaluation(episodes, seed)
    resamples = check_int("resamples", resamples, low=100)
    checked = check_tasks(tasks)
    rliable_modules()  # the aggregate's dependency, before hours of scoring
    from tqdm import tqdm

    results: list[TaskResult] = []
    n_runs: int | None = None
    for task in tqdm(checked, desc="suite", unit="task", disable=not progress):
        policies = _policies(make_policy, task)
        if n_runs is not None and len(policies) != n_runs:
            raise ValueError(
                f"make_policy({task.env_id!r}) returned {len(policies)} policies and "
                f"{n_runs} on the tasks before; expected the same number of runs on every task"
            )
        n_runs = len(policies)
        scores = [
            evaluate(p, episodes=episodes, seed=seed, env_id=task.env_id,
                     env_kwargs=dict(task.env_kwargs))
            for p in policies
        ]  # fmt: skip
        spec = resolve_env(task.env_id, dict(task.env_kwargs))  # the curve evaluate draws
        curve = reference_curve(
            task, episodes, seed, horizon=spec.horizon, action_bound=spec.action_bound,
            divergence_bound=spec.divergence_bound,
        )  # fmt: skip
        gaps, reasons = [], []
        for s in scores:
            g = None if s.diverged else curve.gap(s.episode_costs, s.episode_violations)
            reason = gap_reason(s.violation, s.diverged, g, curve.violations, curve.costs)
            gaps.append(g if reason is None else None)
            reasons.append(reason)
        results.append(TaskResult(task.env_id, tuple(scores), tuple(gaps), tuple(reasons),
                                  curve_xis(task)))  # fmt: skip
    assert n_runs is not None
    missing = tuple(
        f"{r.env_id} run {i}: {reason}"
        for r in results
        for i, reason in enumerate(r.reasons)
        if reason is not None
    )
    table = agg = None
    if not missing:
        table = np.array([[_percent(g)[0] for g in r.gaps] for r in results]).T  # (runs, tasks)
        agg = aggregate_gaps(table, resamples)
    return SuiteScore(tuple(r.env_id for r in results), episodes, seed, n_runs, tuple(results),
                      table, agg, missing)  # fmt: skip


# ----------------------------------------------------------------------------- report lines
def _percent(gap: CurveGap | None) -> tuple[float, tuple[float, float]]:
    """A run's gap in percent; None here is a bug (a run with a reason has no gap)."""
    if gap is None:
        raise ValueError("gap = None; expected the CurveGap of a run scored against the curve")
    return gap.percent()


def _ci(lo: float, hi: float, fmt: str = "+.1f") -> str:
    return f"{lo:{fmt}} to {hi:{fmt}}"


def describe_suite(suite: SuiteScore) -> list[str]:
    """The per-task table and the aggregate of ``suite``, as Markdown lines."""
    lines = [
        "| task | run | mean episode cost (95% CI) | violation frequency (95% Wilson) | diverged "
        "| gap to the RHC curve, % of its cost (95% CI) | at xi |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in suite.results:
        for i, (s, g, reason) in enumerate(zip(r.scores, r.gaps, r.reasons, strict=True)):
            gap = "-" if g is None else f"{_percent(g)[0]:+.1f} ({_ci(*_percent(g)[1])})"
            at = "-" if g is None or g.xi is None else f"{g.xi:.3f}"
            lines.append(
                f"| {r.env_id} | {i} | {s.cost_mean:.4g} ({s.cost_ci95[0]:.4g} to "
                f"{s.cost_ci95[1]:.4g}) | {s.violation:.3f} ({_ci(*s.violation_wilson95, '.3f')}) "
                f"| {s.diverged} | {gap if reason is None else 'none: ' + reason} | {at} |"
            )
    a = suite.aggregate
    if a is None:
        lines.append(f"\nNo aggregate: {len(suite.missing)} (run, task) pair(s) without a gap "
                     "(the aggregate needs all):")  # fmt: skip
        lines += [f"- {m}" for m in suite.missing]
    else:
        lines.append(
            f"\nAcross {a.tasks} task(s) x {a.runs} run(s) (rliable, {a.resamples} stratified "
            f"bootstrap resamples): IQM of the gaps {a.iqm_gap:+.2f}% (95% interval "
            f"{_ci(*a.iqm_gap_ci95, '+.2f')}{'; one run: the interval is the point' if a.runs == 1 else ''}); "
            f"probability of improvement over the one-step RHC {a.probability_of_improvement:.2f} "
            f"({_ci(*a.probability_of_improvement_ci95, '.2f')})."
        )  # fmt: skip
    return lines
