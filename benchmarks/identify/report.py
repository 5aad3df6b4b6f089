"""``results/identify/``: ``summary.json``, ``summary.csv`` and ``REPORT.md`` of the study.

The tables are made here from the task summaries (:func:`benchmarks.identify.summary.
task_summary`); so are the sentences of the report, each read off a number of a table.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

from benchmarks.core.files import jsonable, stable_floats, write_atomic
from benchmarks.core.score_table import fmt_steps
from benchmarks.identify.learner import EXPLORATION, EXPLORATION_SEED_OFFSET, FALLBACKS
from benchmarks.identify.steps import AGENT_CURVE_POINTS, WITHIN
from benchmarks.identify.summary import POINT_FIELDS

__all__ = [
    "LEARNER",
    "steps_table",
    "within_cell",
    "write_csv",
    "write_report",
    "write_summary",
]

#: The learner's name in the tables.
LEARNER = "identify + RHC"
RULE_WORDS = {
    "kept": "the first budget from which every later point of the curve is within",
    "first": "the first budget that is within",
}


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{value:+.1f}"


def within_cell(w: dict[str, Any], budget: int | None = None) -> str:
    """One cell of the steps table: ``"250 (50 to 500; 5/5)"``, or ``"not within 600k (1/5)"``
    (``w`` an entry of :func:`~benchmarks.identify.steps.across_seeds`)."""
    count = f"{w['within']}/{w['seeds']}"
    if w["median"] is None:
        return f"not within{'' if budget is None else ' ' + fmt_steps(budget)} ({count})"
    return f"{fmt_steps(w['median'])} ({fmt_steps(w['low'])} to {fmt_steps(w['high'])}; {count})"


def steps_table(tasks: list[dict[str, Any]], rule: str = "kept") -> list[str]:
    """Markdown rows: per task, the steps each learner needs to come within by ``rule``."""
    configs = list(dict.fromkeys(c for t in tasks for c in t["agents"]))
    lines = [f"| task | {LEARNER} | " + " | ".join(configs) + " |",
             "|---|---|" + "---|" * len(configs)]  # fmt: skip
    for t in tasks:
        cells = [within_cell(t["learner"]["within"][rule], t["grid"][-1])]
        for c in configs:
            a = t["agents"].get(c)
            cells.append("-" if a is None else within_cell(a["within"][rule], a["budget"]))
        lines.append(f"| `{t['env_id']}` | " + " | ".join(cells) + " |")
    return lines


def _spread(s: dict[str, Any]) -> str:
    """``"+1.2 (+0.4 to +3.0), 5"``: median (interquartile range), seeds with a gap; ``"-, 2"``
    where the median has no gap."""
    if s["median"] is None:
        return f"-, {s['with_gap']}"
    return f"{_pct(s['median'])} ({_pct(s['q25'])} to {_pct(s['q75'])}), {s['with_gap']}"


def _curve_table(t: dict[str, Any]) -> list[str]:
    lines = ["The gap's median and interquartile range over the seeds (\"-\": a seed without a gap "
             "is past it), the seeds with a gap, the median violation frequency, the points "
             "without an estimate (a mode with too few steps), whose evaluation failed or "
             "diverged, the fallbacks used, and the median identification errors.", "",
             "| env steps | episodes | gap %, median (IQR) | seeds with a gap | violation (median) "
             "| no estimate / failed / diverged | fallbacks | [A B] error | P error |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for c in t["learner"]["curve"]:
        iqr = "" if c["median"] is None else f" ({_pct(c['q25'])} to {_pct(c['q75'])})"
        viol = "-" if c["violation_median"] is None else f"{c['violation_median']:.3f}"
        ab = "-" if c["error_AB_median"] is None else f"{c['error_AB_median']:.3f}"
        p = "-" if c["error_P_median"] is None else f"{c['error_P_median']:.3f}"
        lines.append(
            f"| {fmt_steps(c['steps'])} | {c['steps'] // t['horizon']} | {_pct(c['median'])}{iqr} "
            f"| {c['with_gap']}/{c['seeds']} | {viol} | {c['no_estimate']} / {c['failed']} / "
            f"{c['diverged']} | {c['fallbacks']} | {ab} | {p} |"
        )
    return lines


def _budget_table(t: dict[str, Any]) -> list[str]:
    lines = [f"| configuration | budget | agent: final gap %, median (IQR), seeds with a gap | "
             f"{LEARNER} at that budget: gap %, median (IQR), seeds with a gap |",
             "|---|---|---|---|"]  # fmt: skip
    for config, a in t["agents"].items():
        at = a["learner_at_budget"]
        mine = "-" if at is None else _spread(at)
        lines.append(f"| {config} | {fmt_steps(a['budget'])} | {_spread(a['final'])} | {mine} |")
    return lines


def _sentence(t: dict[str, Any]) -> str:
    """The task's reading, every number from the tables."""
    w = t["learner"]["within"]["kept"]
    if w["median"] is None:
        mine = f"is not within +{WITHIN:g}% for most seeds ({w['within']} of {w['seeds']})"
    else:
        mine = (f"is within +{WITHIN:g}% from {fmt_steps(w['median'])} steps on (median over "
                f"seeds; {fmt_steps(w['low'])} to {fmt_steps(w['high'])}, {w['within']} of "
                f"{w['seeds']} seeds)")  # fmt: skip
    others = []
    for config, a in t["agents"].items():
        aw = a["within"]["kept"]
        others.append(f"{config} {fmt_steps(aw['median'])}" if aw["median"] is not None
                      else f"{config} not within {fmt_steps(a['budget'])}")  # fmt: skip
    last = t["learner"]["curve"][-1]
    oracle = t["true_model_design"]["gap"]
    return (f"On `{t['env_id']}`, {LEARNER} {mine}; the agents (same rule): {', '.join(others)}. "
            f"At {fmt_steps(last['steps'])} steps its median gap is {_pct(last['median'])}%; the "
            f"same design on the true model scores {_pct(oracle)}%.")  # fmt: skip


def _overall(tasks: list[dict[str, Any]]) -> str:
    """Across tasks: where the learner needs fewer steps than every agent configuration (rule
    kept; an agent not within counts as never)."""
    fewer, exceptions = 0, []
    for t in tasks:
        mine = t["learner"]["within"]["kept"]["median"]
        better = [
            (c, a["within"]["kept"]["median"])
            for c, a in t["agents"].items()
            if a["within"]["kept"]["median"] is not None
            and (mine is None or a["within"]["kept"]["median"] <= mine)
        ]
        if mine is not None and not better:
            fewer += 1
        else:
            who = ", ".join(f"{c} ({fmt_steps(m)})" for c, m in better) or "no agent either"
            exceptions.append(f"`{t['env_id']}`: {who}")
    text = (f"By the rule kept, {LEARNER} comes within +{WITHIN:g}% in fewer steps than every "
            f"agent configuration on {fewer} of {len(tasks)} task(s)")  # fmt: skip
    if exceptions:
        text += "; as few or fewer: " + "; ".join(exceptions)
    return text + "."


def _learner_lines(opts: dict[str, Any]) -> list[str]:
    explo = ", ".join(f"{k.removeprefix('SDJLS-').removesuffix('-v0')} ({s:g}, {m:g})"
                      for k, (s, m) in EXPLORATION.items())  # fmt: skip
    return [
        "## The learner",
        "",
        "- **Explore**: whole episodes of the task's raw environment under "
        "`u = K_theta x + mean + std * eps` (`controllers.ExplorationPolicy`, the task's "
        f"pre-stabilizing gains K), (std, mean) per task: {explo}; environment noise seed "
        f"{EXPLORATION_SEED_OFFSET} + seed, input noise `default_rng([seed, 12345])`. A budget "
        "of a seed is the first episodes of that seed's exploration of the largest budget.",
        "- **Identify**: `controllers.identify` (least squares per mode, Dirichlet-mean "
        "transition rows with one pseudo-count, uniform prior) from the designer's template "
        "(the task's region, weights and start; placeholders for A, B, noise, P_in, P_out).",
        "- **Design**: `RecedingHorizonController.from_model` on the estimate: K by "
        "Proposition 2, Psi the estimate's MJLS LQ value matrices (Proposition 2's Lyapunov "
        "matrices where those fail), the task's xi, constraint, alpha and nu_bound. Fallbacks "
        f"where Proposition 2 has no solution, in order: {', '.join(FALLBACKS[1:])} (the task's "
        "K with the estimate's LQ matrices, then with Psi_i = I).",
        f"- **Score**: `benchmarks.core.evaluate.evaluate` on {opts['episodes']} episodes of the "
        f"raw environment, evaluation seeds {tuple(opts['eval_seeds'])}: the paired gap to the "
        "task's one-step RHC curve (the true-model controller swept over xi) at the learner's "
        "own violation frequency, % of the curve's cost. The agents' gaps are their "
        f"learning-curve points' (100 episodes each, {AGENT_CURVE_POINTS} per run after 0 "
        "steps) from the suite comparison's summary.",
        "- **Grid**: the 1-2-5 sequence of episodes from the fewest identify can accept "
        "(N (n + m + 1) steps) to the task's largest agent budget, and every agent "
        "learning-curve budget, in whole episodes.",
        "",
    ]


def write_report(out: Path, summary: dict[str, Any]) -> str:
    """``REPORT.md`` from the summary's dict; returns the text."""
    tasks = summary["tasks"]
    lines = [
        "# Learn the model, then control",
        "",
        f"Generated by `{summary['command']}`: {len(tasks)} task(s), "
        f"{len(summary['options']['seeds'])} seed(s), {summary['points']} points, "
        f"{summary['cpu_s'] / 60:.1f} CPU-minutes (the points' sum, across resumed runs). "
        f"Agents read from `{summary['agents_source']}`.",
        "",
        *_learner_lines(summary["options"]),
        f"## Steps to come within +{WITHIN:g}% of the true-model controller at equal risk",
        "",
        f"A point is within where its gap is at most +{WITHIN:g}% (cheaper counts; no gap "
        "does not). Rule **kept**: " + RULE_WORDS["kept"] + ". Each cell: the median over the "
        "seeds (a seed never within counts as never), the fewest to the most steps of the seeds "
        'within, and how many are; "not within B" when fewer than half are, by the budget B.',
        "",
        *steps_table(tasks, "kept"),
        "",
        _overall(tasks),
        "",
        "Rule **first**: " + RULE_WORDS["first"] + ".",
        "",
        *steps_table(tasks, "first"),
        "",
    ]
    for t in tasks:
        lines += [f"## `{t['env_id']}`", "", _sentence(t), "", *_curve_table(t), "",
                  "At each agent configuration's full budget:", "", *_budget_table(t), ""]  # fmt: skip
    lines += ["![learning curves](fig_learning_curves.png)", "",
              "![identification errors](fig_identification_errors.png)", ""]  # fmt: skip
    text = "\n".join(lines)
    write_atomic(out / "REPORT.md", text)
    return text


def write_summary(out: Path, summary: dict[str, Any]) -> None:
    """``summary.json``, floats at stable precision, atomically."""
    write_atomic(out / "summary.json",
                 json.dumps(stable_floats(jsonable(summary)), indent=1) + "\n")  # fmt: skip


def write_csv(out: Path, tasks: list[dict[str, Any]]) -> None:
    """``summary.csv``: one row per point of the task summaries (the true-model design with an
    empty seed)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=POINT_FIELDS, lineterminator="\n")
    writer.writeheader()
    for t in tasks:
        writer.writerows(t["points"])
    write_atomic(out / "summary.csv", buf.getvalue())
