"""The suite comparison's report (issue 31): every kept agent on its task against both
model-based curves, and rliable's statistics across the tasks.

``python -m benchmarks.compare_rl`` (any ``--tasks`` but the macro task alone) scores the runs
after training them; ``--score-only`` scores the runs kept so far and trains nothing. Either way
:func:`report_suite` scores what is kept and names what is missing: the report states, per task
and configuration, the seeds it has and the seeds it lacks, and never pools fewer seeds silently.

Per task (:func:`score_task`), on common random numbers:

* each kept run's agent (:func:`benchmarks.rl.train.load_policy`) is scored by
  :func:`benchmarks.evaluate.evaluate` on ``--eval-episodes`` episodes from noise seed ``--seed``;
  its *normalized gap* is the suite's (:mod:`benchmarks.suite`): its cost minus the task's
  one-step RHC curve (:func:`benchmarks.core.reference.reference_curve`) at its own violation
  frequency, paired over the episodes, in % of the curve's cost, with a 95% bootstrap interval;
* the 3-step scenario tree (:func:`benchmarks.core.reference.tree_rhc`) is swept over the levels and
  episodes of ``results/suite`` and xi = 0.96 to 0.99 (:func:`tree_plan`: its decisions cost 100
  to 1000 times the one-step controller's); each agent is rolled out again on those episodes
  (same noise seed), and its paired gap to the tree's curve is measured there, in % of the
  tree's cost;
* both gaps are measured against the curve's efficient points only
  (:func:`benchmarks.core.stats.efficient_points`: a level that another level beats on both cost and
  violation frequency is left out);
* the table of ``results/rl/REPORT.md`` (:func:`benchmarks.rl.report.table`: mean and median
  cost, violation frequency with its Wilson interval, divergences), each run's two paired gaps,
  the flatness test of the learning curves (:mod:`benchmarks.rl.suite_tables`), and the figures
  of :mod:`benchmarks.rl.suite_figures`.

Across tasks (:func:`across_tasks`), per configuration, with rliable
(:func:`benchmarks.core.aggregate.aggregate_gaps`): the IQM of the normalized gaps with its
stratified-bootstrap 95% interval, the probability of improvement over the one-step RHC, and a
performance profile; the same statistics of the gaps to the 3-step tree give the probability of
improvement over the tree. rliable needs a gap on every (run, task) cell of a table. The rule
for partial or undefined cells (:func:`gap_table`): a task where a kept run has no gap (an
episode diverged, or its violation frequency lies outside the curve's range) is left out of that
configuration's table, not the run (which would keep the lucky seeds); of the remaining tasks the
seeds kept on all of them are used. What is left out is listed with its reason, and the table
states how many tasks and seeds each aggregate covers. The sample-efficiency figure is the IQM
of the normalized gap along training, from the learning curves, at the steps where every run of
the configuration has a point (:func:`sample_efficiency`; budgets may differ by task).

Scoring cost (CPU seconds, measured on the shared 2-core machine at load average 9-10, one
torch thread): one agent on one task, 1000 episodes, 2.1 s (the rollout itself 0.1 s; the rest
is the bootstrap of its gap and the decision-time measurement), 2.1-3.0 s with its rollout on
the tree's episodes (10.6 s for the first agent on VTOL, which also paid for the one-step curve
on its learning curve's 100 episodes, computed once per task); a task's references (the one-step
curve on 1000 episodes, 1.3-2.7 s; the tree's curve, 0.04-0.2 s per episode and level, and the
one-step curve on the tree's and on the learning curves' episodes) about 55 s (110 s on the
three-state task with the tree's 6 levels). The report on the
4 runs kept then and all 6 tasks took 340 CPU-s (34 min of wall time at that load). The suite's
150 runs: about 6 x 80 s + 150 x 2.5 s + the aggregates' bootstrap (with 5 seeds, 2000
resamples of a Mann-Whitney test per task, about 1 ms each: some 2 min), about 16 CPU-minutes
in one process (``results/rl_suite/HISTORY.md``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.aggregate import (
    AGGREGATE_RESAMPLES,
    SuiteAggregate,
    aggregate_gaps,
    iqm_interval,
)
from benchmarks.core.evaluate import evaluate, resolve_env
from benchmarks.core.files import stable_floats, write_atomic
from benchmarks.core.montecarlo import rollout
from benchmarks.core.reference import (
    QUICK_TREE,
    TREE_BY_TASK,
    TREE_EPISODES,
    TREE_STEPS,
    TREE_XIS,
    ReferenceCurve,
    reference_curve,
    tree_rhc,
)
from benchmarks.core.stats import CurveGap, CurveStatus, curve_status, efficient_points
from benchmarks.core.suite import gap_reason
from benchmarks.rl.report import RunResult, aggregate, result_json
from benchmarks.rl.suite_tables import (
    across_section,
    gap_text,
    runs_section,
    task_section,
    write_csv,
)
from benchmarks.rl.train import (
    RunRecord,
    RunSpec,
    kept_run_path,
    load_policy,
    load_run,
    policy_path,
)
from sdjls_gym.systems import TASKS

__all__ = [
    "TREE_EXTRA_XIS",
    "AgentScore",
    "ConfigAcross",
    "TaskReport",
    "across_tasks",
    "gap_table",
    "kept_runs",
    "point_gap",
    "relative_gap",
    "report_suite",
    "sample_efficiency",
    "score_task",
    "tree_plan",
]

#: Levels added to ``results/suite``'s tree curve: agents safer than the tree at xi = 0.95
#: have no gap to it (the first SAC Lagrangian run on the three-state task violates in 0.013 of
#: its steps, the one-step curve's xi = 0.983 there, below the tree's range 0.035..0.421), and
#: the Lagrangian agents sit between 0.95 and 0.99, where the tree's cost can climb steeply (the
#: generated task: 3.3 at 0.95, 9.5 at 0.97, 52.7 at 0.99, with 0.99 riskier than 0.97).
TREE_EXTRA_XIS: tuple[float, ...] = (0.96, 0.97, 0.98, 0.99)
#: Stratified-bootstrap resamples of the aggregates with ``--quick``.
QUICK_RESAMPLES = 200


# ----------------------------------------------------------------------------- records
@dataclass(frozen=True)
class AgentScore:
    """One kept run scored on its task: its :class:`~benchmarks.rl.report.RunResult` on the
    evaluation episodes, its gaps to both curves (None where undefined, with the reason), the
    normalized gap at each learning-curve point, and the CPU time its scoring took."""

    result: RunResult
    reason: str | None  # why no gap to the one-step RHC curve (None: result.score.curve_gap)
    tree_gap: CurveGap | None
    tree_reason: str | None
    curve_gaps: tuple[float | None, ...]  # along the learning curve (% of the one-step curve)
    scoring_cpu_s: float

    @property
    def run(self) -> RunRecord:
        return self.result.run

    @property
    def config(self) -> str:
        return f"{self.run.algo}_{self.run.variant}"

    @property
    def gap(self) -> CurveGap | None:
        return None if self.reason is not None else self.result.score.curve_gap

    def to_json(self) -> dict[str, Any]:
        data = result_json(self.result)
        data["curve_gap_reason"] = self.reason
        data["tree_gap"] = None if self.tree_gap is None else asdict(self.tree_gap)
        data["tree_gap_reason"] = self.tree_reason
        data["learning_curve_gaps"] = list(self.curve_gaps)
        data["scoring_cpu_s"] = self.scoring_cpu_s
        return data


@dataclass
class TaskReport:
    """One task: its two model-based curves, its kept agents and its missing runs."""

    env_id: str
    xi: float
    rhc: ReferenceCurve  # the one-step curve on the evaluation episodes
    tree: ReferenceCurve  # the 3-step tree's curve on its own episodes
    tree_gap: CurveGap | None  # the tree at the task's xi against the one-step curve
    tree_reason: str | None
    agents: list[AgentScore]
    missing: dict[str, list[int]]  # configuration -> seeds without a kept run
    expected: dict[str, list[int]]  # configuration -> seeds asked for
    status: list[CurveStatus] = field(default_factory=list)

    @property
    def aggregates(self) -> list[Any]:
        return aggregate([a.result for a in self.agents])

    def reference_rows(self) -> list[tuple[str, dict[str, Any]]]:
        """``(name, statistics)`` of the one-step RHC and the tree at the task's ``xi``."""
        return [(f"RHC one-step, xi = {self.xi:g}", self.rhc.point(self.rhc.xis.index(self.xi))),
                (f"RHC 3-step tree, xi = {self.xi:g}", self.tree.point(self.tree.xis.index(self.xi)))]  # fmt: skip


@dataclass(frozen=True)
class ConfigAcross:
    """One configuration across tasks: the tables rliable was given and what they left out."""

    config: str
    vs_rhc: SuiteAggregate | None  # gaps to the one-step RHC (the suite's normalization)
    rhc_tasks: tuple[str, ...]
    rhc_seeds: tuple[int, ...]
    rhc_left_out: tuple[str, ...]
    vs_tree: SuiteAggregate | None  # gaps to the 3-step tree's curve
    tree_tasks: tuple[str, ...]
    tree_seeds: tuple[int, ...]
    tree_left_out: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        for key in ("vs_rhc", "vs_tree"):
            value = getattr(self, key)
            out[key] = None if value is None else value.to_dict()
        return json.loads(json.dumps(out))


# ----------------------------------------------------------------------------- kept runs
def kept_runs(specs: list[RunSpec], run_dir: Path) -> list[RunRecord | None]:
    """The kept run of each of ``specs`` under ``run_dir`` (None where it is missing)."""
    return [load_run(run_dir, s) for s in specs]


def tree_plan(env_id: str, quick: bool) -> tuple[int, tuple[float, ...]]:
    """Episodes and levels of a task's 3-step tree curve: ``results/suite``'s
    (:data:`benchmarks.core.reference.TREE_EPISODES` at :data:`~benchmarks.core.reference.TREE_XIS`,
    fewer on the slow tasks) with :data:`TREE_EXTRA_XIS` and the task's own ``xi``; ``quick``:
    ``results/suite``'s smoke-test plan."""
    if quick:
        episodes, xis = QUICK_TREE
    else:
        episodes, xis = TREE_BY_TASK.get(env_id, (TREE_EPISODES, TREE_XIS))
        xis = (*xis, *TREE_EXTRA_XIS)
    return episodes, tuple(sorted({*xis, float(TASKS[env_id].rhc["xi"])}))


def _arrays(model: Any, policy: Any, episodes: int, seed: int, spec: Any) -> tuple:
    """Episode costs, shares of violated steps and the diverged count of ``policy``'s rollouts
    (the rule of :func:`benchmarks.core.reference.reference_curve`)."""
    ro = rollout(model, policy, episodes, spec.horizon, seed, spec.action_bound, None,
                 spec.divergence_bound)  # fmt: skip
    diverged = int(np.any(np.abs(ro.x) > spec.divergence_bound, axis=(1, 2)).sum())
    return ro.episode_cost, ro.any_violation.mean(axis=1), diverged


def _curve_gap(curve: ReferenceCurve, costs: np.ndarray, viols: np.ndarray,
               diverged: int) -> tuple[CurveGap | None, str | None]:  # fmt: skip
    gap = None if diverged else curve.gap(costs, viols)
    reason = gap_reason(float(viols.mean()), diverged, gap, curve.violations, curve.costs)
    return (gap if reason is None else None), reason


def point_gap(cost_mean: float, violation: float, diverged: int,
              curve: ReferenceCurve) -> float | None:  # fmt: skip
    """A learning-curve point's normalized gap (%): its mean cost minus ``curve``'s mean cost
    at its violation frequency (linear between the bracketing points, as
    :func:`benchmarks.core.stats.paired_curve_gap`'s point estimate), in % of the latter; None with
    a diverged episode, outside the range of the curve's efficient points (the only points
    it is measured against, :func:`benchmarks.core.stats.efficient_points`), or where the curve's
    cost is not positive. The point holds statistics only, so the gap has no interval."""
    if diverged:
        return None
    v, c = curve.violations.mean(axis=1), curve.costs.mean(axis=1)
    keep = efficient_points(v, c)
    v, c = v[keep], c[keep]
    if not v[0] <= violation <= v[-1]:
        return None
    ref = float(np.interp(violation, v, c))
    return None if ref <= 0 else 100.0 * (cost_mean - ref) / ref


# ----------------------------------------------------------------------------- per task
def score_task(env_id: str, runs: list[tuple[RunSpec, RunRecord | None]], run_dir: Path,
               episodes: int, seed: int, quick: bool = False, log: Any = None) -> TaskReport:  # fmt: skip
    """Score the kept runs of ``runs`` (``(spec, record or None)`` of one task) and the task's
    two model-based curves (see the module docstring)."""
    task = TASKS[env_id]
    spec = resolve_env(env_id, dict(task.env_kwargs))
    kw: dict[str, Any] = {"horizon": spec.horizon, "action_bound": spec.action_bound,
                          "divergence_bound": spec.divergence_bound}  # fmt: skip
    xi = float(task.rhc["xi"])
    rhc = reference_curve(task, episodes, seed, **kw)
    t_eps, t_xis = tree_plan(env_id, quick)
    if log is not None:
        log(f"{env_id}: the 3-step tree on {t_eps} episodes at xi {', '.join(map(str, t_xis))}")
    arrays = [_arrays(task.model, tree_rhc(task, x, TREE_STEPS, horizon=spec.horizon), t_eps,
                      seed, spec) for x in t_xis]  # fmt: skip
    tree = ReferenceCurve(env_id, t_xis, "individual", t_eps, seed, spec.horizon,
                          np.stack([a[0] for a in arrays]), np.stack([a[1] for a in arrays]),
                          np.array([a[2] for a in arrays]))  # fmt: skip
    rhc_on_tree = reference_curve(task, t_eps, seed, **kw)
    i = t_xis.index(xi)
    tree_gap, tree_reason = _curve_gap(rhc_on_tree, tree.costs[i], tree.violations[i],
                                       int(tree.diverged[i]))  # fmt: skip
    expected: dict[str, list[int]] = {}
    missing: dict[str, list[int]] = {}
    agents = []
    for s, record in runs:
        config = f"{s.algo}_{s.variant}"
        expected.setdefault(config, []).append(s.seed)
        if record is None:
            missing.setdefault(config, []).append(s.seed)
            continue
        c0 = time.process_time()
        kept = kept_run_path(run_dir, s)
        if kept is None:  # the record was read from this path a moment ago
            raise FileNotFoundError(f"the kept run of {s.name} left {run_dir} while scoring")
        policy = load_policy(s, policy_path(kept))
        score = evaluate(policy, episodes=episodes, seed=seed, env_id=env_id,
                         env_kwargs=dict(task.env_kwargs))  # fmt: skip
        reason = gap_reason(
            score.violation, score.diverged, score.curve_gap, rhc.violations, rhc.costs
        )
        t_gap, t_reason = _curve_gap(tree, *_arrays(task.model, policy, t_eps, seed, spec))
        lc = reference_curve(task, record.curve_episodes, int(record.config["curve_seed"]), **kw)
        gaps = tuple(point_gap(p.episode_cost_mean, p.violation, p.diverged, lc)
                     for p in record.learning_curve)  # fmt: skip
        agents.append(AgentScore(RunResult(record, score), reason, t_gap, t_reason, gaps,
                                 time.process_time() - c0))  # fmt: skip
    report = TaskReport(env_id, xi, rhc, tree, tree_gap, tree_reason, agents, missing, expected)
    report.status = curve_status([a.run for a in agents])
    return report


# ----------------------------------------------------------------------------- across tasks
def _short(reason: str | None) -> str:
    """A reason of :func:`benchmarks.suite.gap_reason` in a few words."""
    text = reason or "no gap"
    for key, short in (("diverged", text), ("above", "riskier than the curve"),
                       ("below", "safer than the curve")):  # fmt: skip
        if key in text:
            return short
    return text


def gap_table(
    cells: dict[str, dict[int, tuple[float | None, str | None]]],
) -> tuple[np.ndarray | None, tuple[str, ...], tuple[int, ...], tuple[str, ...]]:
    """The (seeds, tasks) table rliable is given, from ``cells[task][seed] = (gap, reason)``
    of the kept runs (gap None: ``reason`` says why).

    A task with no kept run, or where a kept run has no gap, is left out (whole: leaving out
    only the runs without a gap would keep the lucky seeds); of the other tasks, the seeds kept
    on all of them are used. Returns the table (None if nothing is left), the tasks and seeds
    used, and what was left out with its reason.
    """
    tasks, left = [], []
    empty = [task for task, runs in cells.items() if not runs]
    if empty:
        left.append(f"no kept run on {', '.join(empty)}")
    for task, runs in cells.items():
        bad = [
            f"seed {s}: {_short(reason)}" for s, (g, reason) in sorted(runs.items()) if g is None
        ]
        if bad:
            left.append(f"{task}: " + "; ".join(bad))
        elif runs:
            tasks.append(task)
    seeds = sorted(set.intersection(*(set(cells[t]) for t in tasks))) if tasks else []
    extra = sorted(set().union(*(set(cells[t]) for t in tasks)) - set(seeds))
    if extra:
        left.append(f"seed(s) {', '.join(map(str, extra))}: not kept on every task used")
    if not seeds:
        return None, (), (), tuple(left)
    table = np.array([[cells[t][s][0] for t in tasks] for s in seeds], dtype=np.float64)
    return table, tuple(tasks), tuple(seeds), tuple(left)


def relative_gap(agent: AgentScore, which: str) -> tuple[float | None, str | None]:
    """``(gap in %, None)`` of a scored run against the one-step RHC curve (``which = "rhc"``)
    or the 3-step tree's (``"tree"``), or ``(None, why there is none)``."""
    if which == "rhc":
        g, reason = agent.gap, agent.reason
    else:
        g, reason = agent.tree_gap, agent.tree_reason
    value = None if g is None or g.relative is None else g.relative
    return value, reason or ("no relative gap" if value is None else None)


def _cells(reports: list[TaskReport], config: str, which: str) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for r in reports:
        out[r.env_id] = {a.run.seed: relative_gap(a, which) for a in r.agents if a.config == config}
    return out


def across_tasks(reports: list[TaskReport], configs: list[str],
                 resamples: int = AGGREGATE_RESAMPLES) -> list[ConfigAcross]:  # fmt: skip
    """Per configuration, rliable's statistics of its gaps to the one-step RHC and to the
    3-step tree across ``reports``' tasks (:func:`gap_table`'s rule for missing cells)."""
    out = []
    for config in configs:
        parts: list[Any] = []
        for which in ("rhc", "tree"):
            table_, tasks, seeds, left = gap_table(_cells(reports, config, which))
            agg = None if table_ is None else aggregate_gaps(table_, resamples)
            parts += [agg, tasks, seeds, left]
        out.append(ConfigAcross(config, *parts))
    return out


def sample_efficiency(reports: list[TaskReport], across: list[ConfigAcross],
                      resamples: int = AGGREGATE_RESAMPLES) -> dict[str, dict[str, list]]:  # fmt: skip
    """Per configuration, along its learning curves: at each training step that every kept run
    of the configuration has a learning-curve point at (budgets may differ by task: a task
    trained twice as long contributes every other point), the IQM of the normalized gaps over
    the runs and tasks of its aggregate (:attr:`ConfigAcross.rhc_tasks`,
    :attr:`~ConfigAcross.rhc_seeds`) with its 95% interval, None at a step where one of those
    cells has no gap, and the share of all its kept runs x tasks with a gap there."""
    out: dict[str, dict[str, list]] = {}
    for c in across:
        agents = [a for r in reports for a in r.agents if a.config == c.config]
        if not agents:
            continue
        gap_at = [
            {p.timesteps: g for p, g in zip(a.run.learning_curve, a.curve_gaps, strict=False)}
            for a in agents
        ]
        steps = sorted(set.intersection(*(set(g) for g in gap_at)))
        used = [(a, g) for a, g in zip(agents, gap_at, strict=True)
                if a.run.task in c.rhc_tasks and a.run.seed in c.rhc_seeds]  # fmt: skip
        entry: dict[str, list] = {"steps": [], "iqm": [], "ci95": [], "share_with_gap": []}
        for step in steps:
            entry["steps"].append(int(step))
            entry["share_with_gap"].append(float(np.mean([g[step] is not None for g in gap_at])))
            cells = {(a.run.seed, a.run.task): g[step] for a, g in used}
            point = ci = None
            if used and all(v is not None for v in cells.values()):
                grid = np.array([[cells[(s, t)] for t in c.rhc_tasks] for s in c.rhc_seeds])
                point, ci = iqm_interval(grid, resamples)
            entry["iqm"].append(point)
            entry["ci95"].append(ci)
        out[c.config] = entry
    return out


# ----------------------------------------------------------------------------- outputs
def report_suite(specs: list[RunSpec], records: Sequence[RunRecord | None], run_dir: Path,
                 opts: Any, argv: list[str], log: Any = print) -> dict[str, Any]:  # fmt: skip
    """Score the kept runs of ``specs`` (``records``: each spec's kept run or None) and write
    ``summary.json``, ``summary.csv``, the figures and ``REPORT.md`` into ``opts.out`` (each
    file atomically; the numbers before the figures). Returns the summary's dict."""
    import torch

    from benchmarks.core.versions import PACKAGES, package_versions
    from benchmarks.rl.suite_figures import across_figures, task_figures

    torch.set_num_threads(1)  # as in training, and for the agents' decision times
    start, cpu0 = time.perf_counter(), time.process_time()
    resamples = QUICK_RESAMPLES if opts.quick else AGGREGATE_RESAMPLES
    reports = []
    for task in opts.tasks:
        pairs = [(s, r) for s, r in zip(specs, records, strict=True) if s.task == task]
        kept = sum(r is not None for _, r in pairs)
        log(f"scoring {task}: {kept} of {len(pairs)} run(s) kept, {opts.eval_episodes} episodes")
        reports.append(score_task(task, pairs, run_dir, opts.eval_episodes, opts.seed,
                                  opts.quick, log))  # fmt: skip
    log("rliable's aggregates across the tasks")
    across = across_tasks(reports, list(opts.configs), resamples)
    efficiency = sample_efficiency(reports, across, resamples)
    per_task = {r.env_id: gap_text(r.tree_gap, r.tree_reason) for r in reports}
    tree_gaps = [r.tree_gap.relative for r in reports if r.tree_gap is not None]
    tree_agg = (aggregate_gaps(np.array([tree_gaps]), resamples)
                if len(tree_gaps) == len(reports) else None)  # fmt: skip
    tree_refs = {"aggregate": tree_agg, "per_task": per_task}
    command = "python -m benchmarks.compare_rl" + ("" if not argv else " " + " ".join(argv))
    summary: dict[str, Any] = {
        "command": command,
        "options": {k: str(v) if isinstance(v, Path) else v for k, v in vars(opts).items()},
        "versions": package_versions(PACKAGES + ("rliable",)),
        "runs": {
            "expected": len(specs),
            "kept": sum(r is not None for r in records),
            "missing": {r.env_id: r.missing for r in reports},
        },  # fmt: skip
        "tasks": {
            r.env_id: {
                "xi": r.xi,
                "episodes": r.rhc.episodes,
                "references": {name: p for name, p in r.reference_rows()},
                "tree": {
                    "episodes": r.tree.episodes,
                    "xis": list(r.tree.xis),
                    "gap_at_xi": None if r.tree_gap is None else asdict(r.tree_gap),
                    "gap_reason": r.tree_reason,
                },  # fmt: skip
                "rl_runs": [a.to_json() for a in r.agents],
                "rl_aggregates": [asdict(a) for a in r.aggregates],
                "learning_curves": [asdict(c) for c in r.status],
                "missing": r.missing,
            }
            for r in reports
        },
        "across_tasks": {c.config: c.to_json() for c in across},
        "tree_across_tasks": None if tree_agg is None else tree_agg.to_dict(),
        "sample_efficiency": efficiency,
        "scoring": {
            "wall_s": time.perf_counter() - start,
            "cpu_s": time.process_time() - cpu0,
            "agent_cpu_s": [a.scoring_cpu_s for r in reports for a in r.agents],
        },  # fmt: skip
    }
    figures = {r.env_id: [f"fig_{r.env_id}_cost_violation.png",
                          f"fig_{r.env_id}_learning_curves.png"] for r in reports}  # fmt: skip
    summary["figures"] = [f for fs in figures.values() for f in fs] + [
        "fig_aggregate.png", "fig_profiles.png", "fig_sample_efficiency.png"]  # fmt: skip
    out = Path(opts.out)
    # the numbers first: a failing figure must not lose the scoring
    write_atomic(out / "summary.json",
                 json.dumps(stable_floats(json.loads(json.dumps(summary))), indent=1) + "\n")  # fmt: skip
    write_csv(out / "summary.csv", reports)
    for r in reports:
        figures[r.env_id] = task_figures(out, r)
    drawn = across_figures(out, across, efficiency, reports)
    lines = [
        "# RL agents on the tasks of the suite",
        "",
        f"Generated by `{command}`; numbers in `summary.json` and `summary.csv`. Every agent "
        f"is scored by `benchmarks.evaluate.evaluate` on the same {opts.eval_episodes} episodes "
        f"of its task as the task's one-step RHC curve (noise seed {opts.seed}, common random "
        "numbers), and again on the 3-step tree's episodes for the gap to the tree. Cost, "
        "violation and divergence as in results/rl/REPORT.md; the model-based references of "
        "every task are also in results/suite. Scoring took "
        f"{summary['scoring']['wall_s'] / 60:.1f} min ({summary['scoring']['cpu_s'] / 60:.1f} "
        "CPU-min).",
        "",
        *runs_section(reports),
        *across_section(across, tree_refs),
        *[f"![{name}]({name})\n" for name in drawn],
    ]
    for r in reports:
        lines += task_section(r, figures[r.env_id])
    write_atomic(out / "REPORT.md", "\n".join(lines) + "\n")
    log(f"wrote {out}/REPORT.md")
    return summary
