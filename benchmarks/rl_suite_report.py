"""The suite comparison's report (issue 31): every kept agent on its task against both
model-based curves, and rliable's statistics across the tasks.

``python -m benchmarks.compare_rl`` (any ``--tasks`` but the macro task alone) scores the runs
after training them; ``--score-only`` scores the runs kept so far and trains nothing. Either way
:func:`report_suite` scores what is kept and names what is missing: the report states, per task
and configuration, the seeds it has and the seeds it lacks, and never pools fewer seeds silently.

Per task (:func:`score_task`), on common random numbers:

* each kept run's agent (:func:`benchmarks.rl_train.load_policy`) is scored by
  :func:`benchmarks.evaluate.evaluate` on ``--eval-episodes`` episodes from noise seed ``--seed``;
  its *normalized gap* is the suite's (:mod:`benchmarks.suite`): its cost minus the task's
  one-step RHC curve (:func:`benchmarks.reference.reference_curve`) at its own violation
  frequency, paired over the episodes, in % of the curve's cost, with a 95% bootstrap interval;
* the 3-step scenario tree (:func:`benchmarks.reference.tree_rhc`) is swept over the levels and
  episodes of ``results/suite`` (:func:`tree_plan`: its decisions cost 100 to 1000 times the
  one-step controller's); each agent is rolled out again on those episodes (same noise seed),
  and its paired gap to the tree's curve is measured there, in % of the tree's cost;
* the table of ``results/rl/REPORT.md`` (:func:`benchmarks.rl_report.table`: mean and median
  cost, violation frequency with its Wilson interval, divergences), each run's two paired gaps,
  the flatness test of the learning curves, and the figures of :mod:`benchmarks.rl_suite_figures`.

Across tasks (:func:`across_tasks`), per configuration, with rliable
(:func:`benchmarks.aggregate.aggregate_gaps`): the IQM of the normalized gaps with its
stratified-bootstrap 95% interval, the probability of improvement over the one-step RHC, and a
performance profile; the same statistics of the gaps to the 3-step tree give the probability of
improvement over the tree. rliable needs a gap on every (run, task) cell of a table. The rule
for partial or undefined cells (:func:`gap_table`): a task where a kept run has no gap (an
episode diverged, or its violation frequency lies outside the curve's range) is left out of that
configuration's table, not the run (which would keep the lucky seeds); of the remaining tasks the
seeds kept on all of them are used. What is left out is listed with its reason, and the table
states how many tasks and seeds each aggregate covers. The sample-efficiency figure is the IQM
of the normalized gap along training, from the learning curves (:func:`sample_efficiency`).

Scoring cost, measured on the shared 2-core machine (load average about 4; CPU seconds): one
agent on one task, 1000 episodes, 2.1 s (the rollout itself 0.1 s; the rest is the bootstrap of
its gap and the decision-time measurement); the one-step curve of a task on 1000 episodes
1.3-2.7 s; the 3-step tree 0.04-0.12 s per episode and level (VTOL more). The suite's 150 runs
and 6 tasks: about 150 x 2.2 s + 6 x 80 s, some 14 CPU-minutes, plus the bootstrap of the
aggregates (about 12 s per configuration and table).
"""

from __future__ import annotations

import csv
import io
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.aggregate import AGGREGATE_RESAMPLES, SuiteAggregate, aggregate_gaps, iqm_interval
from benchmarks.evaluate import evaluate, resolve_env
from benchmarks.files import stable_floats, write_atomic
from benchmarks.montecarlo import rollout
from benchmarks.reference import ReferenceCurve, reference_curve, tree_rhc
from benchmarks.rl_report import RunResult, aggregate, curve_table, result_json, table
from benchmarks.rl_train import (
    RunRecord,
    RunSpec,
    kept_run_path,
    load_policy,
    load_run,
    policy_path,
)
from benchmarks.stats import CurveGap, CurveStatus, curve_status
from benchmarks.suite import gap_reason
from benchmarks.suite_report import QUICK_TREE, TREE_BY_TASK, TREE_EPISODES, TREE_STEPS, TREE_XIS
from sdjls_gym.systems import TASKS

__all__ = [
    "AgentScore",
    "ConfigAcross",
    "TaskReport",
    "across_tasks",
    "gap_table",
    "kept_runs",
    "point_gap",
    "report_suite",
    "sample_efficiency",
    "score_task",
    "tree_plan",
]

#: Stratified-bootstrap resamples of the aggregates with ``--quick``.
QUICK_RESAMPLES = 200


# ----------------------------------------------------------------------------- records
@dataclass(frozen=True)
class AgentScore:
    """One kept run scored on its task: its :class:`~benchmarks.rl_report.RunResult` on the
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
    (:data:`benchmarks.suite_report.TREE_EPISODES` at :data:`~benchmarks.suite_report.TREE_XIS`,
    fewer on the slow tasks) with the task's own ``xi``; ``quick``: its smoke-test plan."""
    episodes, xis = QUICK_TREE if quick else TREE_BY_TASK.get(env_id, (TREE_EPISODES, TREE_XIS))
    return episodes, tuple(sorted({*xis, float(TASKS[env_id].rhc["xi"])}))


def _arrays(model: Any, policy: Any, episodes: int, seed: int, spec: Any) -> tuple:
    """Episode costs, shares of violated steps and the diverged count of ``policy``'s rollouts
    (the rule of :func:`benchmarks.reference.reference_curve`)."""
    ro = rollout(model, policy, episodes, spec.horizon, seed, spec.action_bound, None,
                 spec.divergence_bound)  # fmt: skip
    diverged = int(np.any(np.abs(ro.x) > spec.divergence_bound, axis=(1, 2)).sum())
    return ro.episode_cost, ro.any_violation.mean(axis=1), diverged


def _curve_gap(curve: ReferenceCurve, costs: np.ndarray, viols: np.ndarray,
               diverged: int) -> tuple[CurveGap | None, str | None]:  # fmt: skip
    gap = None if diverged else curve.gap(costs, viols)
    reason = gap_reason(float(viols.mean()), diverged, gap, curve.violations)
    return (gap if reason is None else None), reason


def point_gap(cost_mean: float, violation: float, diverged: int,
              curve: ReferenceCurve) -> float | None:  # fmt: skip
    """A learning-curve point's normalized gap (%): its mean cost minus ``curve``'s mean cost
    at its violation frequency (linear between the bracketing points, as
    :func:`benchmarks.stats.paired_curve_gap`'s point estimate), in % of the latter; None with
    a diverged episode, outside the curve's range, or where the curve's cost is not positive.
    The point holds statistics only, so the gap has no interval."""
    v, c = curve.violations.mean(axis=1), curve.costs.mean(axis=1)
    if diverged or not v.min() <= violation <= v.max():
        return None
    order = np.argsort(v, kind="stable")
    ref = float(np.interp(violation, v[order], c[order]))
    return None if ref <= 0 else 100.0 * (cost_mean - ref) / ref


# ----------------------------------------------------------------------------- per task
def score_task(env_id: str, runs: list[tuple[RunSpec, RunRecord | None]], run_dir: Path,
               episodes: int, seed: int, quick: bool = False, log: Any = None) -> TaskReport:  # fmt: skip
    """Score the kept runs of ``runs`` (``(spec, record or None)`` of one task) and the task's
    two model-based curves (see the module docstring)."""
    task = TASKS[env_id]
    spec = resolve_env(env_id, dict(task.env_kwargs))
    kw = {"horizon": spec.horizon, "action_bound": spec.action_bound,
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
        policy = load_policy(s, policy_path(kept_run_path(run_dir, s)))
        score = evaluate(policy, episodes=episodes, seed=seed, env_id=env_id,
                         env_kwargs=dict(task.env_kwargs))  # fmt: skip
        reason = gap_reason(score.violation, score.diverged, score.curve_gap, rhc.violations)
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
    for task, runs in cells.items():
        bad = [
            f"seed {s}: {_short(reason)}" for s, (g, reason) in sorted(runs.items()) if g is None
        ]
        if not runs:
            left.append(f"{task}: no kept run")
        elif bad:
            left.append(f"{task}: " + "; ".join(bad))
        else:
            tasks.append(task)
    seeds = sorted(set.intersection(*(set(cells[t]) for t in tasks))) if tasks else []
    extra = sorted(set().union(*(set(cells[t]) for t in tasks)) - set(seeds))
    if extra:
        left.append(f"seed(s) {', '.join(map(str, extra))}: not kept on every task used")
    if not seeds:
        return None, (), (), tuple(left)
    table = np.array([[cells[t][s][0] for t in tasks] for s in seeds], dtype=np.float64)
    return table, tuple(tasks), tuple(seeds), tuple(left)


def _cells(reports: list[TaskReport], config: str, which: str) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for r in reports:
        out[r.env_id] = {}
        for a in r.agents:
            if a.config != config:
                continue
            if which == "rhc":
                g, reason = a.gap, a.reason
            else:
                g, reason = a.tree_gap, a.tree_reason
            value = None if g is None or g.relative is None else g.relative
            out[r.env_id][a.run.seed] = (value, reason or ("no relative gap" if value is None
                                                           else None))  # fmt: skip
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
    """Per configuration, along its learning curves: the training steps (median over runs at
    each point), the IQM of the normalized gaps over the runs and tasks of its aggregate
    (:attr:`ConfigAcross.rhc_tasks`, :attr:`~ConfigAcross.rhc_seeds`) with its 95% interval,
    None at a point where one of those cells has no gap, and the share of all its kept runs x
    tasks with a gap there."""
    out: dict[str, dict[str, list]] = {}
    for c in across:
        agents = [a for r in reports for a in r.agents if a.config == c.config]
        if not agents:
            continue
        n = min(len(a.curve_gaps) for a in agents)
        used = [a for a in agents if a.run.task in c.rhc_tasks and a.run.seed in c.rhc_seeds]
        entry: dict[str, list] = {"steps": [], "iqm": [], "ci95": [], "share_with_gap": []}
        for j in range(n):
            entry["steps"].append(int(np.median([a.run.learning_curve[j].timesteps
                                                 for a in agents])))  # fmt: skip
            entry["share_with_gap"].append(
                float(np.mean([a.curve_gaps[j] is not None for a in agents]))
            )
            cells = {(a.run.seed, a.run.task): a.curve_gaps[j] for a in used}
            point = ci = None
            if used and all(v is not None for v in cells.values()):
                grid = np.array([[cells[(s, t)] for t in c.rhc_tasks] for s in c.rhc_seeds])
                point, ci = iqm_interval(grid, resamples)
            entry["iqm"].append(point)
            entry["ci95"].append(ci)
        out[c.config] = entry
    return out


# ----------------------------------------------------------------------------- outputs
def _pct(g: CurveGap | None, reason: str | None) -> str:
    if g is None or g.relative is None:
        return "none: " + (reason or "-")
    lo, hi = g.relative_ci95
    at = "" if g.xi is None else f" at xi {g.xi:.3f}"
    return f"{g.relative:+.1f} ({lo:+.1f} to {hi:+.1f}){at}"


def _seeds(seeds: list[int]) -> str:
    return ", ".join(map(str, seeds)) if seeds else "-"


def _agg_cells(a: SuiteAggregate | None, tasks: tuple, seeds: tuple) -> list[str]:
    if a is None:
        return ["none", "-", "-"]
    lo, hi = a.iqm_gap_ci95
    plo, phi = a.probability_of_improvement_ci95
    return [f"{len(seeds)} x {len(tasks)}", f"{a.iqm_gap:+.1f} ({lo:+.1f} to {hi:+.1f})",
            f"{a.probability_of_improvement:.2f} ({plo:.2f} to {phi:.2f})"]  # fmt: skip


def runs_section(reports: list[TaskReport]) -> list[str]:
    """The kept and missing runs, per task and configuration."""
    expected = sum(len(s) for r in reports for s in r.expected.values())
    kept = sum(len(r.agents) for r in reports)
    lines = [
        "## Runs",
        "",
        f"{kept} of the {expected} runs asked for are kept and scored, "
        + ("none missing." if kept == expected else f"{expected - kept} missing:"),
        "",
        "| task | configuration | seeds kept | seeds missing |",
        "|---|---|---|---|",
    ]
    for r in reports:
        for config, seeds in r.expected.items():
            miss = r.missing.get(config, [])
            have = [s for s in seeds if s not in miss]
            lines.append(f"| {r.env_id} | {config} | {len(have)} of {len(seeds)} "
                         f"({_seeds(have)}) | {_seeds(miss)} |")  # fmt: skip
    return lines + [""]


def across_section(across: list[ConfigAcross], tree_refs: dict[str, Any]) -> list[str]:
    lines = [
        "## Across tasks (rliable)",
        "",
        "Normalized gap: cost minus the one-step RHC curve at the agent's own violation "
        "frequency, paired over the episodes, in % of the curve's cost (the suite's). Per "
        "configuration, rliable on the (seeds x tasks) table of its gaps: the interquartile mean "
        "(IQM) with a 95% stratified-bootstrap interval (seeds resampled within each task; one "
        "seed: the interval is the point), and the probability of improvement P(gap < 0) "
        "averaged over the tasks. Against the 3-step tree: the same on the gaps to the tree's "
        "curve (% of its cost; on the tree's own episodes). A task where a kept run has no gap "
        "is left out whole, and of the other tasks the seeds kept on all of them are used "
        "(column 'left out'; each run's reason is in its task's section).",
        "",
        "| configuration | seeds x tasks | IQM of the gaps to the one-step RHC, % (95% CI) | "
        "P(improvement over the one-step RHC) (95% CI) | seeds x tasks | IQM of the gaps to the "
        "3-step tree, % (95% CI) | P(improvement over the 3-step tree) (95% CI) | left out |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in across:
        left = [f"vs RHC: {x}" for x in c.rhc_left_out] + [f"vs tree: {x}" for x in c.tree_left_out]
        cells = [c.config, *_agg_cells(c.vs_rhc, c.rhc_tasks, c.rhc_seeds),
                 *_agg_cells(c.vs_tree, c.tree_tasks, c.tree_seeds), "<br>".join(left) or "-"]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    ref = tree_refs.get("aggregate")
    lines += ["", "The 3-step tree itself at each task's xi, against the one-step curve on its "
              "own episodes: " + (f"IQM {ref.iqm_gap:+.1f}% over {ref.tasks} task(s)"
                                  if isinstance(ref, SuiteAggregate) else "no aggregate")
              + "; " + "; ".join(f"{t} {v}" for t, v in tree_refs["per_task"].items()) + ".", ""]  # fmt: skip
    return lines


def task_section(r: TaskReport, figures: list[str]) -> list[str]:
    lines = [
        f"## {r.env_id}",
        "",
        f"Level xi = {r.xi:g} (target violation frequency {1 - r.xi:.2f}); "
        f"{r.rhc.episodes} evaluation episodes (noise seed {r.rhc.seed}); the 3-step tree on "
        f"{r.tree.episodes} episodes at xi {', '.join(f'{x:g}' for x in r.tree.xis)}.",
        "",
        "| reference | episodes | mean episode cost (95% CI) | median cost | violation frequency "
        "(95% Wilson) | diverged |",
        "|---|---|---|---|---|---|",
    ]
    for name, p in r.reference_rows():
        (lo, hi), (vlo, vhi) = p["cost_ci95"], p["violation_wilson95"]
        eps = r.rhc.episodes if "one-step" in name else r.tree.episodes
        lines.append(f"| {name} | {eps} | {p['cost_mean']:.4g} ({lo:.4g} to {hi:.4g}) | "
                     f"{p['cost_median']:.4g} | {p['violation']:.3f} ({vlo:.3f}-{vhi:.3f}) | "
                     f"{p['diverged']} |")  # fmt: skip
    lines += ["", f"The tree at xi = {r.xi:g} against the one-step curve, % of its cost: "
              f"{_pct(r.tree_gap, r.tree_reason)}.", ""]  # fmt: skip
    missing = [f"{c} seed(s) {_seeds(s)}" for c, s in r.missing.items()]
    lines += [f"Missing runs: {'; '.join(missing)}." if missing else "No run is missing.", ""]
    if r.agents:
        lines += ["Agents (seeds pooled as in results/rl/REPORT.md):", "",
                  *table(r.aggregates), "",
                  "Paired gaps of each run, in % of the curve's cost (95% bootstrap interval; "
                  "the xi of the curve at the run's violation frequency):", "",
                  "| run | violation frequency | mean episode cost | gap to the one-step RHC, % "
                  "| gap to the 3-step tree, % |", "|---|---|---|---|---|"]  # fmt: skip
        for a in sorted(r.agents, key=lambda a: a.run.name):
            s = a.result.score
            lines.append(f"| {a.run.name} | {s.violation:.3f} | {s.cost_mean:.4g} | "
                         f"{_pct(a.gap, a.reason)} | {_pct(a.tree_gap, a.tree_reason)} |")  # fmt: skip
        lines += ["", "Learning curves (the flatness test of results/rl):", "",
                  *curve_table(r.status), ""]  # fmt: skip
    for name in figures:
        lines += [f"![{name}]({name})", ""]
    return lines


CSV_HEADER = ["task", "name", "kind", "algo", "variant", "seed", "xi", "episodes", "cost_mean",
              "cost_ci95_low", "cost_ci95_high", "cost_median", "violation",
              "violation_wilson95_low", "violation_wilson95_high", "diverged", "timesteps",
              "gap_rhc_pct", "gap_rhc_pct_low", "gap_rhc_pct_high", "gap_tree_pct",
              "gap_tree_pct_low", "gap_tree_pct_high", "reason"]  # fmt: skip


def _gap_cells(g: CurveGap | None) -> list[Any]:
    if g is None or g.relative is None:
        return ["", "", ""]
    return [g.relative, *g.relative_ci95]


def write_csv(path: Path, reports: list[TaskReport]) -> None:
    """``summary.csv``: a row per reference point at the task's xi and per kept run."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_HEADER)
    for r in reports:
        for (name, p), gap, reason, eps in zip(r.reference_rows(), (None, r.tree_gap),
                                               (None, r.tree_reason),
                                               (r.rhc.episodes, r.tree.episodes), strict=True):  # fmt: skip
            w.writerow(stable_floats([r.env_id, name, "model-based", "", "", "", r.xi, eps,
                                      p["cost_mean"], *p["cost_ci95"], p["cost_median"],
                                      p["violation"], *p["violation_wilson95"], p["diverged"],
                                      "", *_gap_cells(None), *_gap_cells(gap), reason or ""]))  # fmt: skip
        for a in r.agents:
            s = a.result.score
            w.writerow(stable_floats([r.env_id, a.run.name, "rl-seed", a.run.algo,
                                      a.run.variant, a.run.seed, "", s.episodes, s.cost_mean,
                                      *s.cost_ci95, s.cost_median, s.violation,
                                      *s.violation_wilson95, s.diverged, a.run.timesteps,
                                      *_gap_cells(a.gap), *_gap_cells(a.tree_gap),
                                      "; ".join(x for x in (a.reason, a.tree_reason) if x)]))  # fmt: skip
    write_atomic(path, buf.getvalue())


def report_suite(specs: list[RunSpec], records: list[RunRecord | None], run_dir: Path,
                 opts: Any, argv: list[str], log: Any = print) -> dict[str, Any]:  # fmt: skip
    """Score the kept runs of ``specs`` (``records``: each spec's kept run or None) and write
    ``summary.json``, ``summary.csv``, the figures and ``REPORT.md`` into ``opts.out`` (each
    file atomically; the numbers before the figures). Returns the summary's dict."""
    import torch

    from benchmarks.rl_suite_figures import across_figures, task_figures
    from benchmarks.versions import PACKAGES, package_versions

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
    per_task = {r.env_id: _pct(r.tree_gap, r.tree_reason) for r in reports}
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
