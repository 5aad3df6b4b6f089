"""The text of the suite comparison's report (:mod:`benchmarks.rl.suite_report`): the sections
of ``REPORT.md`` (the runs kept and missing, rliable's statistics across tasks, one section per
task) and ``summary.csv``."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

from benchmarks.core.aggregate import SuiteAggregate
from benchmarks.core.files import stable_floats, write_atomic
from benchmarks.core.score_table import table
from benchmarks.core.stats import CurveGap
from benchmarks.rl.claims import conclusions_section
from benchmarks.rl.report import curve_table

__all__ = [
    "CSV_HEADER",
    "across_section",
    "gap_text",
    "report_lines",
    "runs_section",
    "task_section",
    "write_csv",
]


def gap_text(g: CurveGap | None, reason: str | None) -> str:
    """A gap in % with its 95% interval and the curve's xi there, or why it has none."""
    if g is None or g.relative is None or g.relative_ci95 is None:
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


def runs_section(reports: list[Any]) -> list[str]:
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


def across_section(across: list[Any], tree_refs: dict[str, Any]) -> list[str]:
    """rliable's statistics per configuration (:class:`~benchmarks.rl.suite_report.ConfigAcross`)
    and the 3-step tree's own gaps (``tree_refs``: ``aggregate``, ``per_task``)."""
    lines = [
        "## Across tasks (rliable)",
        "",
        "Every run counts: a run's *bounded gap* is its cost minus the one-step RHC curve at its "
        "own violation frequency, paired over the episodes, in % of the curve's cost, clipped "
        "to [-100, +100]; a run with a diverged episode, or riskier than the curve's loosest "
        "efficient level, takes the worst value +100; a run safer than the curve's strictest "
        "level is measured against that level. Per configuration, rliable on the (seeds x "
        "tasks) table of its bounded gaps: the interquartile mean (IQM) with a 95% "
        "stratified-bootstrap interval (seeds resampled within each task), and the probability "
        "of improvement P(gap < 0) averaged over the tasks. Against the 3-step tree: the same "
        "with the tree's curve on the same episodes.",
        "",
        "| configuration | seeds x tasks | IQM of the bounded gaps to the one-step RHC, % "
        "(95% CI) | P(improvement over the one-step RHC) (95% CI) | IQM of the bounded gaps to "
        "the 3-step tree, % (95% CI) | P(improvement over the 3-step tree) (95% CI) |",
        "|---|---|---|---|---|---|",
    ]
    for c in across:
        rhc = _agg_cells(c.bounded_rhc, c.bounded_tasks, c.bounded_seeds)
        tree = _agg_cells(c.bounded_tree, c.bounded_tasks, c.bounded_seeds)[1:]
        lines.append("| " + " | ".join([c.config, *rhc, *tree]) + " |")
    lines += [
        "",
        "The second view, the gaps at equal risk (undefined for a run with a diverged episode or "
        "outside the curve's range): a task where a kept run has none is left out whole, and of "
        "the other tasks the seeds kept on all of them are used (column 'left out').",
        "",
        "| configuration | seeds x tasks | IQM of the gaps to the one-step RHC, % (95% CI) | "
        "P(improvement over the one-step RHC) (95% CI) | seeds x tasks | IQM of the gaps to the "
        "3-step tree, % (95% CI) | P(improvement over the 3-step tree) (95% CI) | left out |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in across:
        left = [x if x in c.tree_left_out else f"vs RHC: {x}" for x in c.rhc_left_out]
        left += [f"vs tree: {x}" for x in c.tree_left_out if x not in c.rhc_left_out]
        cells = [c.config, *_agg_cells(c.vs_rhc, c.rhc_tasks, c.rhc_seeds),
                 *_agg_cells(c.vs_tree, c.tree_tasks, c.tree_seeds), "<br>".join(left) or "-"]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    ref = tree_refs.get("aggregate")
    lines += ["", "The 3-step tree itself at each task's xi, against the one-step curve on the "
              "same episodes: " + (f"IQM of its bounded gaps {ref.iqm_gap:+.1f}% over "
                                   f"{ref.tasks} task(s)"
                                   if isinstance(ref, SuiteAggregate) else "no aggregate")
              + "; " + "; ".join(f"{t} {v}" for t, v in tree_refs["per_task"].items()) + ".", ""]  # fmt: skip
    return lines


def task_section(r: Any, figures: list[str], sentence: str = "") -> list[str]:
    """One task's section (:class:`~benchmarks.rl.suite_report.TaskReport`): its references,
    missing runs, agents' table, each run's two gaps, the sentence written from them (by
    :func:`benchmarks.rl.claims.task_sentence`), the flatness test and ``figures``."""
    lines = [
        f"## {r.env_id}",
        "",
        f"Level xi = {r.xi:g} (target violation frequency {1 - r.xi:.2f}); "
        f"{r.rhc.episodes} evaluation episodes x noise seeds {_seeds(list(r.rhc.seeds))}; the "
        f"action bound of every controller and agent |u_i| <= {r.env_kwargs['action_bound']:g}; "
        f"the one-step curve's base grid {len(r.rhc.xis)} levels, refined at each agent's "
        f"violation frequency; the 3-step tree on {r.tree.episodes} episodes x "
        f"{len(r.tree.seeds)} seed(s) at xi {', '.join(f'{x:g}' for x in r.tree.xis)}.",
        "",
        "| reference | episodes | mean episode cost (95% CI) | median cost | violation frequency "
        "(95% Wilson) | diverged |",
        "|---|---|---|---|---|---|",
    ]
    for name, p in r.reference_rows():
        (lo, hi), (vlo, vhi) = p["cost_ci95"], p["violation_wilson95"]
        eps = (r.rhc.episodes * len(r.rhc.seeds) if "one-step" in name
               else r.tree.episodes * len(r.tree.seeds))  # fmt: skip
        lines.append(f"| {name} | {eps} | {p['cost_mean']:.4g} ({lo:.4g} to {hi:.4g}) | "
                     f"{p['cost_median']:.4g} | {p['violation']:.3f} ({vlo:.3f}-{vhi:.3f}) | "
                     f"{p['diverged']} |")  # fmt: skip
    lines += ["", f"The tree at xi = {r.xi:g} against the one-step curve, % of its cost: "
              f"{gap_text(r.tree_score.equal_risk_gap, r.tree_score.reason)}.", ""]  # fmt: skip
    missing = [f"{c} seed(s) {_seeds(s)}" for c, s in r.missing.items()]
    lines += [f"Missing runs: {'; '.join(missing)}." if missing else "No run is missing.", ""]
    if r.agents:
        lines += ["Agents (seeds pooled as in results/rl/REPORT.md):", "",
                  *table(r.aggregates), "",
                  "Paired gaps of each run, in % of the curve's cost (95% bootstrap interval; "
                  "the xi of the curve at the run's violation frequency):", "",
                  "| run | violation frequency | mean episode cost | gap to the one-step RHC, % "
                  "| gap to the 3-step tree, % | bounded gaps, % (RHC / tree) |",
                  "|---|---|---|---|---|---|"]  # fmt: skip
        for a in sorted(r.agents, key=lambda a: a.run.name):
            s = a.result.score
            lines.append(f"| {a.run.name} | {s.violation:.3f} | {s.cost_mean:.4g} | "
                         f"{gap_text(a.gap, a.reason)} | {gap_text(a.tree_gap, a.tree_reason)} | "
                         f"{a.bounded:+.1f} / {a.tree.value:+.1f} |")  # fmt: skip
        if sentence:
            lines += ["", sentence]
        lines += ["", "Learning curves (the flatness test of results/rl):", "",
                  *curve_table(r.status), ""]  # fmt: skip
    for name in figures:
        lines += [f"![{name}]({name})", ""]
    return lines


CSV_HEADER = ["task", "name", "kind", "algo", "variant", "seed", "xi", "episodes", "cost_mean",
              "cost_ci95_low", "cost_ci95_high", "cost_median", "violation",
              "violation_wilson95_low", "violation_wilson95_high", "diverged", "timesteps",
              "gap_rhc_pct", "gap_rhc_pct_low", "gap_rhc_pct_high", "gap_tree_pct",
              "gap_tree_pct_low", "gap_tree_pct_high", "bounded_gap_rhc_pct",
              "bounded_gap_tree_pct", "reason"]  # fmt: skip


def _gap_cells(g: CurveGap | None) -> list[Any]:
    if g is None or g.relative is None or g.relative_ci95 is None:
        return ["", "", ""]
    return [g.relative, *g.relative_ci95]


def write_csv(path: Path, reports: list[Any]) -> None:
    """``summary.csv``: a row per reference point at the task's xi and per kept run."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_HEADER)
    for r in reports:
        for (name, p), gap, reason, eps in zip(r.reference_rows(),
                                               (None, r.tree_score.equal_risk_gap),
                                               (None, r.tree_score.reason),
                                               (r.rhc.episodes, r.tree.episodes), strict=True):  # fmt: skip
            w.writerow(stable_floats([r.env_id, name, "model-based", "", "", "", r.xi, eps,
                                      p["cost_mean"], *p["cost_ci95"], p["cost_median"],
                                      p["violation"], *p["violation_wilson95"], p["diverged"],
                                      "", *_gap_cells(None), *_gap_cells(gap), "",
                                      r.tree_score.value if name.startswith("RHC 3") else "",
                                      reason or ""]))  # fmt: skip
        for a in r.agents:
            s = a.result.score
            w.writerow(stable_floats([r.env_id, a.run.name, "rl-seed", a.run.algo,
                                      a.run.variant, a.run.seed, "", s.episodes, s.cost_mean,
                                      *s.cost_ci95, s.cost_median, s.violation,
                                      *s.violation_wilson95, s.diverged, a.run.timesteps,
                                      *_gap_cells(a.gap), *_gap_cells(a.tree_gap), a.bounded,
                                      a.tree.value,
                                      "; ".join(x for x in (a.reason, a.tree_reason) if x)]))  # fmt: skip
    write_atomic(path, buf.getvalue())


def report_lines(command: str, opts: Any, seeds: tuple[int, ...], scoring: dict[str, Any],
                 conclusions: list[str], reports: list[Any], across: list[Any],
                 tree_refs: dict[str, Any], drawn: list[str], figures: dict[str, list[str]],
                 sentences: dict[str, str]) -> list[str]:  # fmt: skip
    """REPORT.md's lines: how the agents are scored, the conclusions, the runs, the aggregates
    across the tasks and their figures (``drawn``), then a section per task: its ``figures`` and
    its sentence against the one-step RHC (``sentences``, by task)."""
    lines = [
        "# RL agents on the tasks of the suite",
        "",
        f"Generated by `{command}`; numbers in `summary.json` and `summary.csv`. Every agent "
        f"is scored by the protocol of `benchmarks.evaluate.evaluate` on the same "
        f"{opts.eval_episodes} episodes x {len(seeds)} noise seeds ({', '.join(map(str, seeds))}) "
        "of its task as the task's one-step RHC curve and the 3-step tree's (common random "
        "numbers), every controller and agent within the same action bound (the agents' "
        "`u_bound`: each task's section names it). Cost, "
        "violation and divergence as in results/rl/REPORT.md; the model-based references of "
        "every task are also in results/suite. Scoring took "
        f"{scoring['wall_s'] / 60:.1f} min ({scoring['cpu_s'] / 60:.1f} "
        "CPU-min).",
        "",
        *conclusions_section(conclusions),
        *runs_section(reports),
        *across_section(across, tree_refs),
        *[f"![{name}]({name})\n" for name in drawn],
    ]
    for r in reports:
        lines += task_section(r, figures[r.env_id], sentences[r.env_id])
    return lines
