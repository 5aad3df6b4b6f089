"""The suite comparison's report: every kept agent on its task against both model-based curves,
and rliable's statistics across the tasks.

``python -m benchmarks.compare_rl`` (any ``--tasks`` but the macro task alone) scores the runs
after training them; ``--score-only`` scores the runs kept so far and trains nothing. Either way
:func:`report_suite` scores what is kept and names what is missing: the report states, per task
and configuration, the seeds it has and the seeds it lacks, and never pools fewer seeds silently.

Per task (:func:`score_task`), on common random numbers (``--eval-episodes`` episodes from each
of ``--eval-seeds`` noise seeds, pooled) and with equal action limits (every controller and agent
on the comparison's environment, :func:`benchmarks.rl.envs.comparison_env_kwargs`):

* each kept run's agent (:func:`benchmarks.rl.train.load_policy`) is scored by the core's
  protocol (:func:`benchmarks.core.evaluate.score_policy`): its gap at equal risk to the task's
  one-step RHC curve (refined at the agent's violation frequency, :mod:`benchmarks.core.frontier`)
  and its bounded gap, which every run has;
* the 3-step scenario tree (:func:`benchmarks.core.frontier.tree_curve`) on the same episodes
  (:func:`tree_plan`), and each agent's bounded gap to it;
* the learning curves' points against the one-step curve on their own episodes
  (:func:`point_gap`), the flatness test (:mod:`benchmarks.rl.suite_tables`), the figures of
  :mod:`benchmarks.rl.suite_figures`.

Across tasks (:func:`across_tasks`), per configuration, with rliable
(:func:`benchmarks.core.aggregate.aggregate_gaps`): the IQM of every run's bounded gaps with its
stratified-bootstrap 95% interval, the probability of improvement and a performance profile,
against the one-step RHC and against the tree; as a second view the same on the gaps at equal
risk, where a task whose kept run has none is left out whole (:func:`gap_table`). The
conclusions are sentences written from these numbers (:mod:`benchmarks.rl.claims`). What a
scoring costs is in ``results/rl_suite/HISTORY.md``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.aggregate import (
    AGGREGATE_RESAMPLES,
    SuiteAggregate,
    aggregate_gaps,
    iqm_interval,
)
from benchmarks.core.evaluate import resolve_env, score_policy
from benchmarks.core.files import jsonable, stable_floats, write_atomic
from benchmarks.core.frontier import (
    WORST_GAP,
    BoundedGap,
    ReferenceCurve,
    as_seeds,
    bounded_gap,
    reference_curve,
    tree_curve,
)
from benchmarks.core.montecarlo import rollouts
from benchmarks.core.reference import (
    QUICK_TREE,
    TREE_BY_TASK,
    TREE_STEPS,
    TREE_XIS,
)
from benchmarks.core.stats import CurveGap, CurveStatus, curve_status, efficient_points
from benchmarks.core.tree_levels import TREE_STORE, LevelStore
from benchmarks.rl.claims import (
    RunCounts,
    across_sentence,
    headline_sentence,
    run_counts,
    task_sentence,
)
from benchmarks.rl.envs import comparison_env_kwargs
from benchmarks.rl.report import RunResult, aggregate, result_json
from benchmarks.rl.suite_tables import gap_text, report_lines, write_csv
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
    "conclusion_lines",
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
    evaluation episodes (its score holds the gap at equal risk to the one-step curve and the
    bounded gap), its bounded gap to the 3-step tree's curve (on the same episodes), the
    normalized gap at each learning-curve point, and the CPU time its scoring took."""

    result: RunResult
    tree: BoundedGap
    curve_gaps: tuple[float, ...]  # along the learning curve: bounded gaps, % (point_gap)
    scoring_cpu_s: float

    @property
    def run(self) -> RunRecord:
        return self.result.run

    @property
    def config(self) -> str:
        return f"{self.run.algo}_{self.run.variant}"

    @property
    def gap(self) -> CurveGap | None:
        return self.result.score.curve_gap

    @property
    def reason(self) -> str | None:
        return self.result.score.curve_gap_reason

    @property
    def bounded(self) -> float:
        value = self.result.score.bounded_gap
        if value is None:  # a task of the suite always has its curve
            raise ValueError(f"{self.run.name}: no bounded gap")
        return value

    @property
    def tree_gap(self) -> CurveGap | None:
        return self.tree.equal_risk_gap

    @property
    def tree_reason(self) -> str | None:
        return self.tree.reason

    def to_json(self) -> dict[str, Any]:
        data = result_json(self.result)
        data["curve_gap_reason"] = self.reason
        data["tree_gap"] = None if self.tree_gap is None else asdict(self.tree_gap)
        data["tree_gap_reason"] = self.tree_reason
        data["tree_bounded_gap"] = self.tree.value
        data["learning_curve_gaps"] = list(self.curve_gaps)
        data["scoring_cpu_s"] = self.scoring_cpu_s
        return data


@dataclass
class TaskReport:
    """One task: its two model-based curves, its kept agents and its missing runs."""

    env_id: str
    xi: float
    env_kwargs: dict[str, Any]  # the comparison's environment (equal action limits)
    rhc: ReferenceCurve  # the one-step curve on the evaluation episodes (its base grid)
    tree: ReferenceCurve  # the 3-step tree's curve on the same episodes
    tree_score: BoundedGap  # the tree at the task's xi against the one-step curve
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
    """One configuration across tasks: rliable's statistics of every run's bounded gaps (to the
    one-step RHC and to the 3-step tree), and of the gaps at equal risk where every cell has one
    (the second view), with what that view left out."""

    config: str
    bounded_rhc: SuiteAggregate | None  # every kept run, every task: the headline
    bounded_tree: SuiteAggregate | None
    bounded_tasks: tuple[str, ...]
    bounded_seeds: tuple[int, ...]
    vs_rhc: SuiteAggregate | None  # gaps at equal risk to the one-step RHC
    rhc_tasks: tuple[str, ...]
    rhc_seeds: tuple[int, ...]
    rhc_left_out: tuple[str, ...]
    vs_tree: SuiteAggregate | None  # gaps at equal risk to the 3-step tree's curve
    tree_tasks: tuple[str, ...]
    tree_seeds: tuple[int, ...]
    tree_left_out: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        for key in ("bounded_rhc", "bounded_tree", "vs_rhc", "vs_tree"):
            value = getattr(self, key)
            out[key] = None if value is None else value.to_dict()
        return jsonable(out)


# ----------------------------------------------------------------------------- kept runs
def kept_runs(specs: list[RunSpec], run_dir: Path) -> list[RunRecord | None]:
    """The kept run of each of ``specs`` under ``run_dir`` (None where it is missing)."""
    return [load_run(run_dir, s) for s in specs]


def tree_plan(env_id: str, quick: bool, episodes: int) -> tuple[int, tuple[float, ...]]:
    """Episodes per noise seed and levels of a task's 3-step tree curve: the evaluation's
    ``episodes`` (an agent's gap to the tree rests on as many episodes as its gap to the
    one-step RHC, and on the same ones) at :data:`~benchmarks.core.reference.TREE_XIS` with
    :data:`TREE_EXTRA_XIS` and the task's own ``xi`` (the tasks of
    :data:`~benchmarks.core.reference.TREE_BY_TASK`: their own levels); ``quick``: the smoke
    test's plan, whose agents are rolled out again on the tree's fewer episodes."""
    xi = float(TASKS[env_id].rhc["xi"])
    if quick:
        return QUICK_TREE[0], tuple(sorted({*QUICK_TREE[1], xi}))
    if env_id in TREE_BY_TASK:
        return episodes, tuple(sorted({*TREE_BY_TASK[env_id], xi}))
    return episodes, tuple(sorted({*TREE_XIS, *TREE_EXTRA_XIS, xi}))


def point_gap(cost_mean: float, violation: float, diverged: int,
              curve: ReferenceCurve) -> float:  # fmt: skip
    """A learning-curve point's bounded gap (%; the rule of
    :func:`benchmarks.core.frontier.bounded_gap` on its statistics): its mean cost minus
    ``curve``'s mean cost at its violation frequency (linear between the bracketing efficient
    levels of the curve's base grid, as :func:`benchmarks.core.stats.paired_curve_gap`'s point
    estimate), in % of the latter, clipped to ``[-WORST_GAP, WORST_GAP]``; ``+WORST_GAP`` with a
    diverged episode or above the curve's range; against the strictest level below it. The
    point holds statistics only, so the gap has no interval and no refinement."""
    if diverged:
        return WORST_GAP
    v, c = curve.violations.mean(axis=1), curve.costs.mean(axis=1)
    keep = efficient_points(v, c)
    v, c = v[keep], c[keep]
    if violation > v[-1]:
        return WORST_GAP
    ref = float(np.interp(violation, v, c))  # the strictest level's cost below the range
    if ref <= 0:
        return WORST_GAP
    return float(np.clip(100.0 * (cost_mean - ref) / ref, -WORST_GAP, WORST_GAP))


def score_task(env_id: str, runs: list[tuple[RunSpec, RunRecord | None]], run_dir: Path,
               episodes: int, seed: int | tuple[int, ...], quick: bool = False,
               log: Any = None, store: LevelStore | None = None,
               workers: int = 1) -> TaskReport:  # fmt: skip
    """Score the kept runs of ``runs`` (``(spec, record or None)`` of one task) and the task's
    two model-based curves on the comparison's environment
    (:func:`benchmarks.rl.envs.comparison_env_kwargs`; see the module docstring). ``store``
    and ``workers``: where the tree's level runs are kept and on how many processes the
    missing ones run (:func:`benchmarks.core.frontier.tree_curve`)."""
    task = TASKS[env_id]
    env_kwargs = comparison_env_kwargs(task)
    spec = replace(resolve_env(env_id, env_kwargs), task=task)
    kw: dict[str, Any] = {"horizon": spec.horizon, "action_bound": spec.action_bound,
                          "divergence_bound": spec.divergence_bound}  # fmt: skip
    xi = float(task.rhc["xi"])
    rhc = reference_curve(task, episodes, seed, **kw)
    t_eps, t_xis = tree_plan(env_id, quick, episodes)
    same = t_eps == episodes
    if log is not None:
        log(f"{env_id}: the 3-step tree on {t_eps} episodes x {len(as_seeds(seed))} seed(s) at "
            f"xi {', '.join(f'{x:g}' for x in t_xis)}")  # fmt: skip
    tree = tree_curve(task, t_eps, seed, t_xis, steps=TREE_STEPS, store=store, workers=workers,
                      **kw)  # fmt: skip
    rhc_on_tree = rhc if same else reference_curve(task, t_eps, seed, **kw)
    i = t_xis.index(xi)
    tree_score = bounded_gap(rhc_on_tree, tree.costs[i], tree.violations[i], int(tree.diverged[i]))
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
        score = score_policy(policy, spec, episodes, seed)
        if same:  # the tree on the evaluation episodes: the agent's own rollouts
            arrays = (score.episode_costs, score.episode_violations, score.diverged)
        else:
            arrays = _arrays(task.model, policy, t_eps, seed, spec)
        lc = reference_curve(task, record.curve_episodes, int(record.config["curve_seed"]), **kw)
        gaps = tuple(point_gap(p.episode_cost_mean, p.violation, p.diverged, lc)
                     for p in record.learning_curve)  # fmt: skip
        agents.append(AgentScore(RunResult(record, score), bounded_gap(tree, *arrays), gaps,
                                 time.process_time() - c0))  # fmt: skip
    report = TaskReport(env_id, xi, env_kwargs, rhc, tree, tree_score, agents, missing, expected)
    report.status = curve_status([a.run for a in agents])
    return report


def _arrays(model: Any, policy: Any, episodes: int, seed: int | tuple[int, ...],
            spec: Any) -> tuple[np.ndarray, np.ndarray, int]:  # fmt: skip
    """Episode costs, shares of violated steps and the diverged count of ``policy``'s rollouts
    (the rule of :class:`benchmarks.core.frontier.LevelRunner`)."""
    ro = rollouts(model, policy, episodes, spec.horizon, as_seeds(seed), spec.action_bound, None,
                  spec.divergence_bound)  # fmt: skip
    return ro.outcomes(spec.divergence_bound)


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


def bounded_table(
    reports: list[TaskReport], config: str, which: str
) -> tuple[np.ndarray | None, tuple[str, ...], tuple[int, ...]]:
    """The (seeds, tasks) table of ``config``'s bounded gaps to the one-step RHC (``which =
    "rhc"``) or to the tree (``"tree"``): every kept run counts; the seeds kept on every task
    with a kept run (a run not kept is missing, named in the report's runs section)."""
    cells = {r.env_id: {a.run.seed: (a.bounded if which == "rhc" else a.tree.value)
                        for a in r.agents if a.config == config} for r in reports}  # fmt: skip
    tasks = tuple(t for t, c in cells.items() if c)
    if not tasks:
        return None, (), ()
    seeds = tuple(sorted(set.intersection(*(set(cells[t]) for t in tasks))))
    if not seeds:
        return None, tasks, ()
    return np.array([[cells[t][s] for t in tasks] for s in seeds]), tasks, seeds


def across_tasks(reports: list[TaskReport], configs: list[str],
                 resamples: int = AGGREGATE_RESAMPLES) -> list[ConfigAcross]:  # fmt: skip
    """Per configuration, rliable's statistics across ``reports``' tasks: of every run's bounded
    gaps (to the one-step RHC and to the 3-step tree: every run counts), and of the gaps at
    equal risk (:func:`gap_table`'s rule for cells without one)."""
    out = []
    for config in configs:
        parts: list[Any] = []
        for which in ("rhc", "tree"):
            table_, tasks, seeds = bounded_table(reports, config, which)
            parts.append(None if table_ is None else aggregate_gaps(table_, resamples))
        parts += [tasks, seeds]
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
    trained twice as long contributes every other point), the IQM of the bounded gaps
    (:func:`point_gap`) over the runs and tasks of its aggregate (:attr:`ConfigAcross.bounded_tasks`,
    :attr:`~ConfigAcross.bounded_seeds`) with its 95% interval."""
    out: dict[str, dict[str, list]] = {}
    for c in across:
        agents = [a for r in reports for a in r.agents if a.config == c.config
                  and a.run.task in c.bounded_tasks and a.run.seed in c.bounded_seeds]  # fmt: skip
        if not agents:
            continue
        gap_at = [
            {p.timesteps: g for p, g in zip(a.run.learning_curve, a.curve_gaps, strict=False)}
            for a in agents
        ]
        steps = sorted(set.intersection(*(set(g) for g in gap_at)))
        entry: dict[str, list] = {"steps": [], "iqm": [], "ci95": []}
        for step in steps:
            cells = {(a.run.seed, a.run.task): g[step] for a, g in zip(agents, gap_at, strict=True)}
            grid = np.array([[cells[(s, t)] for t in c.bounded_tasks] for s in c.bounded_seeds])
            point, ci = iqm_interval(grid, resamples)
            entry["steps"].append(int(step))
            entry["iqm"].append(point)
            entry["ci95"].append(ci)
        out[c.config] = entry
    return out


def conclusion_lines(reports: list[TaskReport], across: list[ConfigAcross]) -> list[str]:
    """The report's conclusions (:mod:`benchmarks.rl.claims`): across tasks against both
    curves, then per task against the one-step RHC."""
    lines = [
        across_sentence("one-step RHC", [(c.config, c.bounded_rhc) for c in across]),
        across_sentence("3-step tree", [(c.config, c.bounded_tree) for c in across]),
    ]
    for r in reports:
        lines.append(headline_sentence(r.env_id, "one-step RHC", task_counts(r)))
    return lines


def task_counts(r: TaskReport) -> list[RunCounts]:
    """Per configuration of a task, its seeds against the one-step RHC (:mod:`.claims`)."""
    counts = []
    for config in dict.fromkeys(a.config for a in r.agents):
        mine = [a for a in r.agents if a.config == config]
        counts.append(run_counts(config, [a.gap for a in mine], [a.bounded for a in mine]))
    return counts


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
    seeds = tuple(range(opts.seed, opts.seed + opts.eval_seeds))
    reports = _score_tasks(specs, records, run_dir, opts, seeds, log)
    log("rliable's aggregates across the tasks")
    across = across_tasks(reports, list(opts.configs), resamples)
    efficiency = sample_efficiency(reports, across, resamples)
    per_task = {r.env_id: gap_text(r.tree_score.equal_risk_gap, r.tree_score.reason)
                for r in reports}  # fmt: skip
    conclusions = conclusion_lines(reports, across)
    tree_agg = aggregate_gaps(np.array([[r.tree_score.value for r in reports]]), resamples)
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
        "tasks": {r.env_id: _task_json(r) for r in reports},
        "conclusions": conclusions,
        "across_tasks": {c.config: c.to_json() for c in across},
        "tree_across_tasks": tree_agg.to_dict(),
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
    sentences = {r.env_id: task_sentence(r.env_id, "one-step RHC", task_counts(r))
                 for r in reports}  # fmt: skip
    lines = report_lines(command, opts, seeds, summary["scoring"], conclusions, reports, across,
                         tree_refs, drawn, figures, sentences)  # fmt: skip
    write_atomic(out / "REPORT.md", "\n".join(lines) + "\n")
    log(f"wrote {out}/REPORT.md")
    return summary


def _score_tasks(specs: list[RunSpec], records: Sequence[RunRecord | None], run_dir: Path,
                 opts: Any, seeds: tuple[int, ...], log: Any) -> list[TaskReport]:  # fmt: skip
    """:func:`score_task` on each task of ``opts.tasks``, with its specs and kept runs."""
    reports = []
    for task in opts.tasks:
        pairs = [(s, r) for s, r in zip(specs, records, strict=True) if s.task == task]
        kept = sum(r is not None for _, r in pairs)
        log(f"scoring {task}: {kept} of {len(pairs)} run(s) kept, {opts.eval_episodes} episodes "
            f"x {len(seeds)} noise seed(s)")  # fmt: skip
        reports.append(score_task(task, pairs, run_dir, opts.eval_episodes, seeds, opts.quick,
                                  log, LevelStore(Path(opts.out) / TREE_STORE),
                                  opts.workers))  # fmt: skip
    return reports


def _task_json(r: TaskReport) -> dict[str, Any]:
    """One task's section of ``summary.json``."""
    gap = r.tree_score.equal_risk_gap
    return {
        "xi": r.xi,
        "episodes": r.rhc.episodes,
        "seeds": list(r.rhc.seeds),
        "references": {name: p for name, p in r.reference_rows()},
        "env_kwargs": jsonable(r.env_kwargs),
        "curve": {"xis": list(r.rhc.xis), "seeds": list(r.rhc.seeds)},
        "tree": {
            "episodes": r.tree.episodes,
            "bounded_gap_at_xi": r.tree_score.value,
            "xis": list(r.tree.xis),
            "gap_at_xi": None if gap is None else asdict(gap),
            "gap_reason": r.tree_score.reason,
        },  # fmt: skip
        "rl_runs": [a.to_json() for a in r.agents],
        "rl_aggregates": [asdict(a) for a in r.aggregates],
        "learning_curves": [asdict(c) for c in r.status],
        "missing": r.missing,
    }
