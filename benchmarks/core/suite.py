"""The scoring protocol across the suite: a policy scored on every task, as one benchmark.

>>> from benchmarks.core.suite import evaluate_suite
>>> from controllers import LinearFeedbackController
>>> suite = evaluate_suite(lambda task: LinearFeedbackController(task.model, task.K),
...                        tasks=("SDJLS-Solar-v0", "SDJLS-Degradation-v0"), episodes=20)
>>> tuple(round(r.scores[0].violation, 2) for r in suite.results)
(0.04, 0.33)

The protocol: on each task, ``make_policy(task)``'s policy is scored by
:func:`benchmarks.core.evaluate.score_policy` (the protocol of :func:`benchmarks.evaluate.evaluate`)
on ``episodes`` episodes of the raw environment from each noise seed of ``seed`` (common random
numbers: every policy, and every level of the task's reference curve, sees the same noise). Each
run gets two numbers against the task's one-step receding-horizon curve
(:mod:`benchmarks.core.frontier`), both in percent of the curve's cost, 0 on the curve, -10 for
10% cheaper at the same violation frequency:

* its *bounded gap*, which every run has: the paired gap at its own violation frequency
  clipped to ``[-100, 100]``; ``+100`` (the worst value) for a run with a diverged episode or
  riskier than the curve's loosest efficient level; for a run safer than its strictest level,
  the gap to that level. Every run counts in the aggregate;
* its *gap at equal risk* (the second view), with a 95% bootstrap interval: undefined where an
  episode diverged or the violation frequency lies outside the curve's range, and the reason
  is stated.

Across tasks, with ``rliable`` (Agarwal et al. 2021, the reference implementation): the score of
a run on a task is the *improvement over the one-step RHC*, ``-gap`` (rliable expects higher is
better), and from it the interquartile mean (IQM) with a stratified-bootstrap 95% interval, the
probability of improvement over the one-step RHC (whose own score is 0 on every task: the share
of tasks where the policy is cheaper than the curve, ties counting one half) and a performance
profile. :attr:`SuiteScore.aggregate` is over the bounded gaps of every (run, task);
:attr:`SuiteScore.equal_risk_aggregate` over the gaps at equal risk, None unless every (run,
task) has one (:attr:`SuiteScore.missing` says which do not, and why). A *run* is one
independently trained copy of the policy (a training seed): ``make_policy(task)`` may return a
list of policies, one per run, the same number on every task. A deterministic controller is one
run. The stratified bootstrap resamples runs within each task: **with one run there is nothing
to resample, and the interval is the point itself**; it measures the spread between training
seeds, not the evaluation noise of each task's gap, which the per-task 95% intervals state.

The command line is :mod:`benchmarks.suite` (``python -m benchmarks.suite``).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from benchmarks.core.aggregate import (
    AGGREGATE_RESAMPLES,
    PROFILE_TAUS,
    SuiteAggregate,
    aggregate_gaps,
    rliable_modules,
)
from benchmarks.core.evaluate import Score, check_evaluation, resolve_env, score_policy
from benchmarks.core.files import jsonable
from benchmarks.core.reference import curve_xis
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
]


# ----------------------------------------------------------------------------- records
@dataclass(frozen=True)
class TaskResult:
    """One task's scores: one :class:`~benchmarks.core.evaluate.Score` per run.

    Attributes
    ----------
    env_id : str
    scores : tuple of Score
        One per run, on the same episodes; each holds its gap at equal risk
        (``curve_gap``, None with its ``curve_gap_reason``) and its bounded gap
        (``bounded_gap``, every run has one).
    curve_xis : tuple of float
        The levels ``xi`` of the task's reference curve (its base grid).
    """

    env_id: str
    scores: tuple[Score, ...]
    curve_xis: tuple[float, ...]

    @property
    def gaps(self) -> tuple[CurveGap | None, ...]:
        """Each run's gap at equal risk (None where undefined, see :attr:`reasons`)."""
        return tuple(s.curve_gap for s in self.scores)

    @property
    def reasons(self) -> tuple[str | None, ...]:
        """Why a run has no gap at equal risk (None where it has one)."""
        return tuple(s.curve_gap_reason for s in self.scores)

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
        Env ids, in the order of :attr:`results` and of the columns of the tables.
    episodes, runs : int
        Episodes per task (per noise seed), runs (training seeds) per task.
    seed : int or tuple of int
        The evaluation's noise seed(s).
    results : tuple of TaskResult
    gap_table : (runs, tasks) array
        Every run's bounded gap (%; :func:`benchmarks.core.frontier.bounded_gap`): the score
        every run has.
    aggregate : SuiteAggregate
        rliable's statistics of :attr:`gap_table`.
    equal_risk_table : (runs, tasks) array or None
        The gaps at equal risk (%), None unless every (run, task) has one.
    equal_risk_aggregate : SuiteAggregate or None
        rliable's statistics of :attr:`equal_risk_table` (the second view), None with it.
    missing : tuple of str
        Each undefined gap at equal risk: ``"<env_id> run <i>: <reason>"``.
    """

    tasks: tuple[str, ...]
    episodes: int
    seed: int | tuple[int, ...]
    runs: int
    results: tuple[TaskResult, ...]
    gap_table: np.ndarray = field(repr=False, compare=False)
    aggregate: SuiteAggregate
    equal_risk_table: np.ndarray | None = field(repr=False, compare=False)
    equal_risk_aggregate: SuiteAggregate | None
    missing: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types (no per-episode arrays)."""
        risk = self.equal_risk_aggregate
        return {
            "tasks": list(self.tasks),
            "episodes": self.episodes,
            "seed": self.seed if isinstance(self.seed, int) else list(self.seed),
            "runs": self.runs,
            "results": [r.to_dict() for r in self.results],
            "gap_table": self.gap_table.tolist(),
            "aggregate": self.aggregate.to_dict(),
            "equal_risk_table": (
                None if self.equal_risk_table is None else self.equal_risk_table.tolist()
            ),  # fmt: skip
            "equal_risk_aggregate": None if risk is None else risk.to_dict(),
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
    seed: int | Sequence[int] = 0,
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
    episodes : int
        As :func:`benchmarks.evaluate.evaluate`: episodes per task and noise seed (>= 2).
    seed : int or sequence of int
        Noise seed(s) (>= 0): their episodes pooled.
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
    episodes, seeds = check_evaluation(episodes, seed)
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
        # the task itself is the reference, a user's Task too (no lookup by its model)
        spec = replace(resolve_env(task.env_id, dict(task.env_kwargs)), task=task)
        scores = tuple(score_policy(p, spec, episodes, seeds) for p in policies)
        results.append(TaskResult(task.env_id, scores, curve_xis(task)))
    assert n_runs is not None
    missing = tuple(
        f"{r.env_id} run {i}: {reason}"
        for r in results
        for i, reason in enumerate(r.reasons)
        if reason is not None
    )
    bounded = np.array([[_bounded(s) for s in r.scores] for r in results]).T  # (runs, tasks)
    risk_table = risk_agg = None
    if not missing:
        risk_table = np.array([[_percent(g)[0] for g in r.gaps] for r in results]).T
        risk_agg = aggregate_gaps(risk_table, resamples)
    return SuiteScore(tuple(r.env_id for r in results), episodes, seeds, n_runs, tuple(results),
                      bounded, aggregate_gaps(bounded, resamples), risk_table, risk_agg,
                      missing)  # fmt: skip


def _bounded(score: Score) -> float:
    if score.bounded_gap is None:  # a task of the suite always has its curve
        raise ValueError(f"{score.env_id}: no bounded gap; expected a task with a reference curve")
    return score.bounded_gap


# ----------------------------------------------------------------------------- report lines
def _percent(gap: CurveGap | None) -> tuple[float, tuple[float, float]]:
    """A run's gap in percent; None here is a bug (a run with a reason has no gap)."""
    if gap is None:
        raise ValueError("gap = None; expected the CurveGap of a run scored against the curve")
    return gap.percent()


def _ci(lo: float, hi: float, fmt: str = "+.1f") -> str:
    return f"{lo:{fmt}} to {hi:{fmt}}"


def describe_suite(suite: SuiteScore) -> list[str]:
    """The per-task table and the aggregates of ``suite``, as Markdown lines."""
    lines = [
        "| task | run | mean episode cost (95% CI) | violation frequency (95% Wilson) | diverged "
        "| gap at equal risk, % of the RHC curve's cost (95% CI) | at xi | bounded gap % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in suite.results:
        for i, (s, g, reason) in enumerate(zip(r.scores, r.gaps, r.reasons, strict=True)):
            gap = "-" if g is None else f"{_percent(g)[0]:+.1f} ({_ci(*_percent(g)[1])})"
            at = "-" if g is None or g.xi is None else f"{g.xi:.3f}"
            lines.append(
                f"| {r.env_id} | {i} | {s.cost_mean:.4g} ({s.cost_ci95[0]:.4g} to "
                f"{s.cost_ci95[1]:.4g}) | {s.violation:.3f} ({_ci(*s.violation_wilson95, '.3f')}) "
                f"| {s.diverged} | {gap if reason is None else 'none: ' + reason} | {at} "
                f"| {_bounded(s):+.1f} ({s.bounded_gap_rule}) |"
            )
    lines.append("\n" + _aggregate_line("bounded gaps (every run counts)", suite.aggregate))
    risk = suite.equal_risk_aggregate
    if risk is None:
        lines.append(f"\nGaps at equal risk: no aggregate, {len(suite.missing)} (run, task) "
                     "pair(s) without one (that view needs all):")  # fmt: skip
        lines += [f"- {m}" for m in suite.missing]
    else:
        lines.append("\n" + _aggregate_line("gaps at equal risk", risk))
    return lines


def _aggregate_line(what: str, a: SuiteAggregate) -> str:
    one = "; one run: the interval is the point" if a.runs == 1 else ""
    return (
        f"Across {a.tasks} task(s) x {a.runs} run(s), {what} (rliable, {a.resamples} "
        f"stratified bootstrap resamples): IQM {a.iqm_gap:+.2f}% (95% interval "
        f"{_ci(*a.iqm_gap_ci95, '+.2f')}{one}); probability of improvement over the one-step "
        f"RHC {a.probability_of_improvement:.2f} ({_ci(*a.probability_of_improvement_ci95, '.2f')})."
    )
