"""The hidden setting's files: ``summary.json``, ``summary.csv`` and ``REPORT.md``, its tables
made by code and its sentences generated from the numbers (:mod:`benchmarks.hidden.summary`).

Every run counts: the aggregate across tasks is of the runs' bounded gaps
(:func:`benchmarks.core.frontier.bounded_gap`), and the per-task tables give each design's
bounded gap beside its gap at equal risk."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from benchmarks.core.files import stable_floats, write_atomic
from benchmarks.core.frontier import WORST_GAP
from benchmarks.hidden.score import CONTROLLERS, EVAL_SEEDS, DesignScore, TaskResult
from benchmarks.hidden.summary import (
    ConfigSummary,
    DesignAcross,
    bounded_designs,
    bounded_text,
    config_summaries,
    overall_sentences,
    price_text,
    task_sentences,
    unbounded_tasks,
)

__all__ = ["short_table", "summary_json", "write_outputs"]

#: The bounded gap's rule, in words (the protocol paragraph and the across-tasks section).
BOUNDED_RULE = (
    f"its bounded gap, +{WORST_GAP:g} for a diverged run or one riskier than the curve's "
    f"loosest efficient level, its gap at equal risk clipped to [-{WORST_GAP:g}, "
    f"+{WORST_GAP:g}] where there is one, and for a run safer than the curve's strictest "
    "efficient level its cost above that level's in % (clipped alike: no credit for the extra "
    "safety)"
)


def _fmt(value: float | None, spec: str = ".4g") -> str:
    return "-" if value is None else format(value, spec)


def _filter(s: ConfigSummary) -> str:
    if s.filter_top_share is None:
        return "-"
    return f"{s.filter_top_share:.3f} / {_fmt(s.filter_true_probability, '.3f')}"


def _per_seed(r: TaskResult) -> int:
    """Evaluation episodes per noise seed of ``r`` (``r.episodes`` counts every seed's)."""
    return r.episodes // max(len(r.seeds), 1)


def summary_table(results: Sequence[TaskResult]) -> list[str]:
    """One row per task and design: the oracle, the controllers, each agent configuration
    (medians over its kept seeds), its gap at equal risk and its bounded gap."""
    lines = [
        "| task | design | seeds | mean episode cost | violation frequency | diverged episodes "
        "| bounded | gap to the oracle's curve at equal risk | bounded gap (every run counts) "
        "| filter: likeliest mode right / p(true mode) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        summaries = config_summaries(r)
        oracle = summaries[0]
        for s in summaries:
            seeds = "-" if s.kind != "agent" else str(s.seeds)
            bounded = ("yes" if s.bounded else "no") if s.kind != "agent" else (
                f"{s.bounded_seeds} of {s.seeds}")  # fmt: skip
            gap = price_text(s, oracle) + (f" ({s.gap_seeds} seeds)" if s.kind == "agent" and
                                     s.gap is not None and s.gap_seeds < s.seeds else "")  # fmt: skip
            lines.append(f"| {r.env_id} | {s.configuration} | {seeds} | {s.cost_mean:.4g} | "
                         f"{s.violation:.3f} | {s.diverged:g} of {s.episodes} | {bounded} | "
                         f"{gap} | {bounded_text(s)} | {_filter(s)} |")  # fmt: skip
    return lines


def short_table(results: Sequence[TaskResult]) -> list[str]:
    """One row per task: how many designs (the controllers and the agent configurations, each
    agent configuration on every kept seed) kept every episode bounded, the bounded gap of
    each controller, and the agent configuration with the smallest median bounded gap."""
    lines = [
        "| task | designs that kept every episode bounded | certainty equivalence | belief RHC "
        "| the agent configuration of smallest bounded gap |",
        "|---|---|---|---|---|",
    ]
    for r in results:
        summaries = config_summaries(r)
        by = {s.configuration: s for s in summaries}
        bounded, unbounded = bounded_designs(summaries)
        agents = [s for s in summaries if s.kind == "agent" and s.seeds > 0]
        best = "-"
        if agents:
            a = min(agents, key=lambda s: s.bounded_gap)
            best = f"{a.configuration} {bounded_text(a)}"
        cells = [bounded_text(by[c]) if c in by else "-" for c in CONTROLLERS]
        lines.append(f"| {r.env_id} | {len(bounded)} of {len(bounded) + len(unbounded)} | "
                     f"{cells[0]} | {cells[1]} | {best} |")  # fmt: skip
    return lines


def _gap_ci(d: DesignScore) -> str:
    if d.gap is None:
        return f"none: {d.gap_reason}"
    ci = "" if d.gap_ci95 is None else f" ({d.gap_ci95[0]:+.1f} to {d.gap_ci95[1]:+.1f})"
    return f"{d.gap:+.1f}%{ci}"


def design_table(r: TaskResult) -> list[str]:
    """Every design of one task, each seed of each agent on its own row."""
    lines = [
        "| design | mean episode cost (95% CI) | median | violation (95% Wilson) | diverged | "
        "gap to the oracle's curve at equal risk, % (95% CI) | bounded gap, % (its rule) | "
        "oracle's xi at that risk | filter: likeliest mode right / p(true mode) | decision "
        "time (us) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for d in r.designs:
        f = "-" if d.filter is None else (
            f"{d.filter.top_share:.3f} / {d.filter.true_probability:.3f}")  # fmt: skip
        t = "-" if d.decision_time_s is None else f"{1e6 * d.decision_time_s:.1f}"
        lines.append(
            f"| {d.name} | {d.cost_mean:.4g} ({d.cost_ci95[0]:.4g} to {d.cost_ci95[1]:.4g}) | "
            f"{d.cost_median:.4g} | {d.violation:.3f} ({d.violation_wilson95[0]:.3f}-"
            f"{d.violation_wilson95[1]:.3f}) | {d.diverged} | {_gap_ci(d)} | "
            f"{d.bounded_gap:+.1f} ({d.bounded_gap_rule}) | {_fmt(d.xi_equivalent, '.3f')} | "
            f"{f} | {t} |"
        )
    return lines


def across_table(across: Sequence[DesignAcross]) -> list[str]:
    """One row per design: rliable's IQM of its bounded gaps across the tasks, the probability
    of improvement, the runs each rule scored, and the missing runs left out."""
    lines = [
        "| design | seeds x tasks | IQM of the bounded gaps, % (95% CI) | P(bounded gap < 0) "
        "(95% CI) | runs by rule | left out (missing runs) |",
        "|---|---|---|---|---|---|",
    ]
    for a in across:
        g = a.aggregate
        left = "<br>".join(a.left_out) or "-"
        if g is None:
            lines.append(f"| {a.configuration} | none | - | - | - | {left} |")
            continue
        size = f"{len(a.seeds) or 1} x {len(a.tasks)}"
        lo, hi = g.iqm_gap_ci95
        plo, phi = g.probability_of_improvement_ci95
        rules = ", ".join(f"{rule}: {n}" for rule, n in a.rules.items()) or "-"
        lines.append(f"| {a.configuration} | {size} | {g.iqm_gap:+.1f} ({lo:+.1f} to {hi:+.1f}) "
                     f"| {g.probability_of_improvement:.2f} ({plo:.2f} to {phi:.2f}) | {rules} | "
                     f"{left} |")  # fmt: skip
    return lines


def summary_json(results: Sequence[TaskResult], across: Sequence[DesignAcross],
                 meta: dict[str, Any]) -> dict[str, Any]:  # fmt: skip
    """Everything the report states, as plain JSON (every design's and every summary's bounded
    gap among them; the across-tasks aggregates are of the bounded gaps)."""
    per_task = {r.env_id: config_summaries(r) for r in results}
    return {
        **meta,
        "evaluation_seeds": list(EVAL_SEEDS),
        "worst_gap": WORST_GAP,
        "unbounded_tasks": unbounded_tasks(per_task),
        "conclusions": overall_sentences(per_task),
        "tasks": {
            r.env_id: {
                "xi": r.xi,
                "episodes": r.episodes,
                "episodes_per_seed": _per_seed(r),
                "seeds": list(r.seeds),
                "oracle_curve": r.curve,
                "designs": [asdict(d) for d in r.designs],
                "summaries": [asdict(s) for s in per_task[r.env_id]],
                "missing": r.missing,
                "conclusions": task_sentences(r.env_id, per_task[r.env_id]),
            }
            for r in results
        },
        "across_tasks": {a.configuration: a.to_json() for a in across},
    }


def write_csv(path: Path, results: Sequence[TaskResult]) -> None:
    """One row per design and task (each agent's seed its own), with its gap at equal risk and
    its bounded gap."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["task", "name", "kind", "configuration", "seed", "episodes", "cost_mean",
                "cost_median", "violation", "diverged", "gap_percent", "gap_ci95_low",
                "gap_ci95_high", "gap_reason", "bounded_gap_percent", "bounded_gap_rule",
                "filter_top_share", "filter_true_probability"])  # fmt: skip
    for r in results:
        for d in r.designs:
            ci = d.gap_ci95 or (None, None)
            f = d.filter
            w.writerow(stable_floats([r.env_id, d.name, d.kind, d.configuration, d.seed,
                                      d.episodes, d.cost_mean, d.cost_median, d.violation,
                                      d.diverged, d.gap, ci[0], ci[1], d.gap_reason,
                                      d.bounded_gap, d.bounded_gap_rule,
                                      None if f is None else f.top_share,
                                      None if f is None else f.true_probability]))  # fmt: skip
    write_atomic(path, buf.getvalue())


def _episodes_text(results: Sequence[TaskResult]) -> str:
    """The evaluation episodes as the data have them: ``1000 episodes x 3 noise seeds (0, 1,
    2), 3000 per task``."""
    if not results:
        return f"no episodes (noise seeds {', '.join(map(str, EVAL_SEEDS))})"
    r = results[0]
    seeds = "seed" if len(r.seeds) == 1 else "seeds"
    return (f"{_per_seed(r)} episodes x {len(r.seeds)} noise {seeds} "
            f"({', '.join(map(str, r.seeds))}), {r.episodes} per task")  # fmt: skip


def _protocol(results: Sequence[TaskResult], meta: dict[str, Any]) -> str:
    """The report's protocol paragraph."""
    runs = meta["runs"]
    return (
        f"Generated by `{meta['command']}`; numbers in `summary.json` and `summary.csv`. Every "
        'design acts on the environment made with `observe="state"` (it sees `x_k` and `k`, '
        "never `θ_k`) and is scored by `benchmarks.evaluate.evaluate` on the same "
        f"{_episodes_text(results)} (the seeds' episodes pooled, common random numbers). The "
        "*oracle* is the task's one-step RHC seeing the true mode at the task's xi; its sweep "
        "over xi is the reference curve, on the same episodes, so a design's gap to it at the "
        "design's own violation frequency, paired over the episodes, in % of the curve's cost, "
        f"is the price of not seeing the mode at equal risk. Every run counts: {BOUNDED_RULE}. "
        "A design keeps the system *bounded* when none of its episodes diverged. The filter's "
        "accuracy (designs deciding from the mode filter) is over the decisions at k >= 1 of "
        "the episodes not diverged: the share whose most probable mode is the true one / the "
        f"mean probability of the true mode. Agents: {runs['kept']} of {runs['expected']} runs "
        "kept"
        + (f", trained in {runs['train_cpu_h']:.2f} CPU-hours" if runs.get("train_cpu_h") else "")
        + f"; scoring took {meta['scoring_cpu_min']:.1f} CPU-min."
    )


def write_outputs(out: Path, results: Sequence[TaskResult], across: Sequence[DesignAcross],
                  meta: dict[str, Any], figures: dict[str, list[str]]) -> dict[str, Any]:  # fmt: skip
    """``summary.json``, ``summary.csv`` and ``REPORT.md`` in ``out``, each atomically;
    ``figures``: file names by task (and ``"across"``). Returns the summary."""
    summary = summary_json(results, across, meta)
    summary["figures"] = figures
    write_atomic(out / "summary.json",
                 json.dumps(stable_floats(json.loads(json.dumps(summary))), indent=1) + "\n")  # fmt: skip
    write_csv(out / "summary.csv", results)
    lines = [
        "# The mode hidden: what not seeing it costs",
        "",
        _protocol(results, meta),
        "",
        "## Conclusions",
        "",
        *[f"- {line}" for line in summary["conclusions"]],
        "",
        "## The price in short",
        "",
        "Bounded gaps to the oracle's curve (every run counts; agents: the median over their "
        "kept seeds).",
        "",
        *short_table(results),
        "",
        "## The price of the hidden mode, per task",
        "",
        "Agents: medians over their kept seeds (the gap at equal risk over the seeds that have "
        "one, the bounded gap over all of them).",
        "",
        *summary_table(results),
        "",
        "## Across tasks (rliable)",
        "",
        f"The aggregate is of bounded gaps. Every run counts: {BOUNDED_RULE}. Per design, "
        "rliable's interquartile mean of its bounded gaps over the (seeds x tasks) table of "
        "its kept runs, with a 95% stratified-bootstrap interval, and the probability that its "
        "bounded gap is negative (cheaper than the oracle's curve). No task is left out because "
        "a run has no gap at equal risk; only missing runs are (a task without a kept run, a "
        "seed not kept on every task).",
        "",
        *across_table(across),
        "",
        *[f"![{name}]({name})\n" for name in figures.get("across", [])],
    ]
    for r in results:
        lines += [f"## {r.env_id}", "",
                  *[f"- {s}" for s in summary["tasks"][r.env_id]["conclusions"]], ""]  # fmt: skip
        if r.missing:
            lines += ["Missing runs: " + "; ".join(
                f"{c} seed(s) {', '.join(map(str, s))}" for c, s in r.missing.items()) + ".", ""]  # fmt: skip
        lines += [*design_table(r), "", *[f"![{n}]({n})\n" for n in figures.get(r.env_id, [])]]
    write_atomic(out / "REPORT.md", "\n".join(lines) + "\n")
    return summary
