"""``REPORT.md`` of the RL comparison on the macro task (:func:`write_report`): the fixed text of
the protocol, then tables made from its :class:`~benchmarks.rl.report.Summary`."""

from __future__ import annotations

from typing import Any

from benchmarks.core.frontier import WORST_GAP
from benchmarks.core.score_table import fmt_steps, table
from benchmarks.core.stats import FLAT_TOL
from benchmarks.rl.claims import (
    conclusions_section,
    headline_sentence,
    run_counts,
    task_sentence,
)
from benchmarks.rl.report import (
    COMPARABLE_MARGIN,
    AgainstCurve,
    ControllerResult,
    RunResult,
    Summary,
    curve_table,
)

__all__ = ["CAPTIONS", "macro_conclusions", "write_report"]


def _signed(x: float) -> str:
    """``+12`` / ``-3``; round-off around 0 reads ``+0``, not ``-0``."""
    return f"{x:+.0f}" if round(x) != 0 else "+0"


CURVE_GAP_HEADER = [
    "| controller | violation frequency | mean episode cost | curve's cost there | "
    "cost minus curve (95% bootstrap) | xi of the curve there |",
    "|---|---|---|---|---|---|",
]


def _gap_row(name: str, violation: float, cost: float, curve_cost: float, mean: float,
             ci95: Any, xi: float | None) -> str:  # fmt: skip
    return (
        f"| {name} | {violation:.3f} | {cost:.4g} | {curve_cost:.4g} | {_signed(mean)} "
        f"({_signed(ci95[0])} to {_signed(ci95[1])}) | {'-' if xi is None else f'{xi:.3f}'} |"
    )


def _curve_gap_table(rows: list[ControllerResult | RunResult]) -> list[str]:
    lines = list(CURVE_GAP_HEADER)
    for r in rows:
        g = r.score.curve_gap
        if g is not None:
            lines.append(_gap_row(r.name, g.violation, r.score.cost_mean, g.curve_cost, g.mean,
                                  g.ci95, g.xi))  # fmt: skip
    return lines


def _against_curve_sections(against: dict[str, list[AgainstCurve]]) -> list[str]:
    lines = []
    for family, rows in against.items():
        lines += [
            f"## Against the {family} curve",
            "",
            f"Cost minus the curve of the {family} controller over xi, interpolated at the "
            "controller's own violation frequency, paired over the common episodes (rows without "
            "a diverged episode, inside the curve's range).",
            "",
            *CURVE_GAP_HEADER,
            *(
                _gap_row(d.name, d.violation, d.cost_mean, d.curve_cost, d.mean, d.ci95, d.xi)
                for d in rows
            ),
            "",
        ]
    return lines


CAPTIONS = {
    "fig_cost_violation.png": "Mean episode cost against violation frequency: the model-based "
    "curves over xi, one point per other controller (trained agents: seeds pooled), 95% interval "
    "bars; hollow markers: agents whose learning curve is not flat by the test",
    "fig_learning_curves.png": "Learning curves: median evaluation cost and violation frequency "
    "against training steps (mean over seeds, band from min to max)",
    "fig_lagrangian_beta.png": "Lagrangian variant: beta, and the violation frequency it is "
    "updated from (the deterministic policy's, solid; the exploring policy's, dashed)",
    "fig_income.png": "Incomes under the RHC (individual, xi = 0.85) and under the best agent "
    "(see Best agent)",
}


def macro_conclusions(summary: Summary, reference: str) -> list[str]:
    """The macro comparison's conclusion: per configuration, its seeds against the ``reference``
    curve at equal risk (:func:`benchmarks.rl.claims.run_counts`)."""
    groups: dict[str, list[RunResult]] = {}
    for r in sorted(summary.rl_runs, key=lambda r: r.name):
        groups.setdefault(f"{r.run.algo}_{r.run.variant}", []).append(r)
    counts = []
    for config, runs in groups.items():
        bounded = [r.score.bounded_gap for r in runs]
        counts.append(run_counts(config, [r.score.curve_gap for r in runs],
                                 [WORST_GAP if b is None else b for b in bounded]))  # fmt: skip
    return [headline_sentence("SDJLS-Macro-v0", reference, counts),
            task_sentence("SDJLS-Macro-v0", reference, counts)]  # fmt: skip


def write_report(summary: Summary, xi: float, reference: str) -> str:
    """REPORT.md: the fixed text of the protocol, then tables; ``reference`` is the family of
    the curve the gaps are measured against (its own points are left out: 0 by construction)."""
    target = 1 - xi
    lines = [
        *_protocol_lines(summary),
        *conclusions_section(macro_conclusions(summary, reference)),
        *_results_lines(summary, xi, reference),
        *_best_agent_lines(summary, target),
        *_check_lines(summary, target),
        *_training_time_lines(summary),
        *_figure_lines(summary.figures),
        "## The model-based controllers",
        "",
        *table(summary.model_based),
        "",
        "## Every trained run",
        "",
        *table(summary.rl_runs),
        "",
    ]
    return "\n".join(lines) + "\n"


def _protocol_lines(summary: Summary) -> list[str]:
    """The title, the command, the versions and how every controller is scored."""
    o = summary.options
    return [
        "# The receding-horizon controller against RL agents (SDJLS-Macro-v0)",
        "",
        f"Generated by `{summary.command}`. Versions: "
        + ", ".join(f"{k} {v}" for k, v in summary.versions.items())
        + ".",
        "",
        f"Every controller is scored by `benchmarks.evaluate.evaluate` on the same "
        f"{o['eval_episodes']} episodes of 20 steps from each of {o.get('eval_seeds', 1)} noise "
        f"seed(s) from {o['seed']} (pooled; common random numbers), every controller and agent "
        "within the agents' action bound |u| <= 60 (the RHC is clipped there as the agents "
        "are). Episode cost: the sum of x'Qx + u'Ru; mean with a 95% Student-t interval over "
        "episodes (aggregates of trained seeds: over the seeds' means; cut at 0) and median "
        "(aggregates: median of the seeds' medians). Violation frequency: share of steps whose "
        "state leaves the band G x <= H_k, with a 95% Wilson interval (aggregates: pooled over "
        "seeds). Diverged: episodes with |x| > 1e6; such an episode ends there and its remaining "
        "steps count as violated. Decision time: per state, batched over 1000 visited states and "
        "one state at a time. Training time: mean wall time per run on one CPU thread, with the "
        "evaluations made during training. Agents learn from -log(1 + c / 100) of the penalized "
        "per-step cost c; every number here is the true cost. Hyperparameters and budgets: "
        "`benchmarks/rl_hyperparams.py`; how they were chosen: `HISTORY.md`.",
        "",
    ]


def _results_lines(summary: Summary, xi: float, reference: str) -> list[str]:
    """The table of results, and every controller against the curves."""
    mb = summary.model_based
    main_mb = [r for r in mb if r.xi in (None, xi)]
    runs_by = sorted(summary.rl_runs, key=lambda r: r.name)
    return [
        "## Results",
        "",
        *table(main_mb + summary.rl_aggregates),
        "",
        "## Against the RHC curve",
        "",
        "Cost minus the curve of the RHC with individual constraints over xi, interpolated at the "
        "controller's own violation frequency, paired over the common episodes (rows without "
        "a diverged episode, inside the curve's range).",
        "",
        *_curve_gap_table([r for r in mb if r.family != reference] + runs_by),
        "",
        *_against_curve_sections(summary.against_curves),
    ]


def _best_agent_lines(summary: Summary, target: float) -> list[str]:
    """The cheapest comparable configuration, and the model-based controllers against it."""
    return [
        "## Best agent",
        "",
        f"Comparable: no diverged episode and violation frequency <= {target + COMPARABLE_MARGIN:.2f}. "
        f"Cheapest comparable configuration: {summary.best_config or '-'}"
        + ("" if summary.best_config_comparable else " (none comparable: fewest diverged)")
        + f"; its seed with the median cost: {summary.best_agent or '-'}.",
        "",
        "| controller | cost minus the best agent's (95% bootstrap) |",
        "|---|---|",
        *(
            f"| {d.name} | {_signed(d.mean)} ({_signed(d.ci95[0])} to {_signed(d.ci95[1])}) |"
            for d in summary.against_best_agent
        ),
        "",
    ]


def _check_lines(summary: Summary, target: float) -> list[str]:
    """The checks: empty tightened bands, the Lagrangian agents' frequencies, the violation
    intervals, the flatness of the learning curves."""
    return [
        "## Tightened band",
        "",
        "| controller | share of (mode, k) with an empty tightened band |",
        "|---|---|",
        *(
            f"| {r.name} | {r.tightened_band_empty:.2f} |"
            for r in summary.model_based
            if r.tightened_band_empty is not None
        ),
        "",
        "## Lagrangian agents",
        "",
        "| agent | final beta (mean of seeds) | violation frequency | seeds' range | target |",
        "|---|---|---|---|---|",
        *(
            f"| {a.name} | {a.final_beta:.4g} | {a.violation:.3f} | "
            f"{a.violation_seed_range[0]:.3f}-{a.violation_seed_range[1]:.3f} | {target:.2f} |"
            for a in summary.rl_aggregates
            if a.variant == "lagrangian"
        ),
        "",
        "## Violation intervals",
        "",
        "Ratio of the width of a Student-t interval over the episodes' shares of violated steps "
        "to the Wilson interval's width, largest per group.",
        "",
        "| group | rows | largest ratio | row |",
        "|---|---|---|---|",
        *(
            f"| {part} | {c.rows} | {c.max_ratio:.2f} | {c.name} |"
            for part, c in (summary.violation_interval_check or {}).items()
            if c is not None
        ),
        "",
        "## Learning curves",
        "",
        f"Late window: the points after 70% of training, against as many points before it. Flat: "
        f"violation change < {FLAT_TOL['violation']:g}, diverged-share change < "
        f"{FLAT_TOL['diverged']:g} and, where the median episode does not diverge, median cost "
        f"change < {100 * FLAT_TOL['cost_rel']:g}%.",
        "",
        *curve_table(summary.learning_curves),
        "",
    ]


def _training_time_lines(summary: Summary) -> list[str]:
    """Every run's training time."""
    return [
        "## Training time",
        "",
        "| run | training steps | wall time (s) | CPU time (s) | of it evaluations (s) |",
        "|---|---|---|---|---|",
        *(
            f"| {r.name} | {fmt_steps(r.run.timesteps)} | {r.run.train_time_s:.0f} | "
            + ("-" if r.run.cpu_time_s is None else f"{r.run.cpu_time_s:.0f}")
            + " | "
            + ("-" if r.run.eval_time_s is None else f"{r.run.eval_time_s:.0f}")
            + " |"
            for r in sorted(summary.rl_runs, key=lambda r: r.name)
        ),
        "",
    ]


def _figure_lines(figures: list[str]) -> list[str]:
    """The figures with their captions."""
    lines = ["## Figures", ""]
    for name in figures:
        lines += [f"![{CAPTIONS[name]}]({name})", "", f"*{CAPTIONS[name]}*", ""]
    return lines
