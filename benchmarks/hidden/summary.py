"""The hidden setting's numbers summed up: agent configurations over their seeds, rliable's
aggregate across tasks, and the sentences of the report, generated from the numbers.

Every run counts: each run (a controller's evaluation, an agent's kept seed) has its *bounded
gap* (:attr:`benchmarks.hidden.score.DesignScore.bounded_gap`,
:func:`benchmarks.core.frontier.bounded_gap`): its gap to the oracle's curve at equal risk where
there is one, clipped to ``[-100, 100]``; ``+100`` for a run with a diverged episode or riskier
than the curve; for a run safer than the curve, its cost against the curve's strictest
efficient level.

* :func:`config_summaries`: per task and agent configuration, the median over its kept seeds of
  the mean cost, the violation frequency, the diverged episodes and the bounded gap (over every
  kept seed), the median gap at equal risk over the seeds that have one, and how many seeds
  kept every episode bounded;
* :func:`across_tasks`: per design, rliable's IQM of its bounded gaps across the tasks
  (:func:`benchmarks.core.aggregate.aggregate_gaps`) on a (seeds, tasks) table of every kept
  run: no task is left out because a run has no gap at equal risk; only missing runs are (a
  task without a kept run, a seed not kept on every task);
* :func:`task_sentences`, :func:`overall_sentences`: which designs kept every episode bounded,
  the price of the hidden mode per design (its gap at equal risk where there is one, its
  bounded gap where that does not say it all), the bounded design with the smallest bounded
  gap, and the tasks no design kept bounded.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from benchmarks.core.aggregate import AGGREGATE_RESAMPLES, SuiteAggregate, aggregate_gaps
from benchmarks.hidden.score import CONTROLLERS, DesignScore, TaskResult

__all__ = [
    "ConfigSummary",
    "DesignAcross",
    "across_tasks",
    "bounded_designs",
    "bounded_text",
    "config_summaries",
    "gap_text",
    "overall_sentences",
    "price_text",
    "task_sentences",
    "unbounded_tasks",
]


@dataclass(frozen=True)
class ConfigSummary:
    """One design on one task: a controller (one "seed") or an agent configuration over its
    kept seeds (medians over the seeds; ``gap`` over the ``gap_seeds`` seeds that have one,
    ``bounded_gap`` over all of them, ``bounded_gap_rules`` the rule of each seed's)."""

    configuration: str
    kind: str
    seeds: int
    cost_mean: float
    violation: float
    diverged: float
    bounded_seeds: int
    gap: float | None
    gap_seeds: int
    bounded_gap: float
    episodes: int
    bounded_gap_rules: tuple[str, ...] = ()
    filter_top_share: float | None = None
    filter_true_probability: float | None = None

    @property
    def bounded(self) -> bool:
        """Every evaluation episode of every kept seed bounded."""
        return self.seeds > 0 and self.bounded_seeds == self.seeds


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def summarize(configuration: str, kind: str, rows: Sequence[DesignScore]) -> ConfigSummary:
    """:class:`ConfigSummary` of ``rows``, the seeds of one design on one task."""
    gaps = [r.gap for r in rows if r.gap is not None]
    tops = [r.filter.top_share for r in rows if r.filter is not None]
    trues = [r.filter.true_probability for r in rows if r.filter is not None]
    return ConfigSummary(
        configuration=configuration, kind=kind, seeds=len(rows),
        cost_mean=float(np.median([r.cost_mean for r in rows])),
        violation=float(np.median([r.violation for r in rows])),
        diverged=float(np.median([r.diverged for r in rows])),
        bounded_seeds=sum(r.bounded for r in rows), gap=_median(gaps), gap_seeds=len(gaps),
        bounded_gap=float(np.median([r.bounded_gap for r in rows])), episodes=rows[0].episodes,
        bounded_gap_rules=tuple(r.bounded_gap_rule for r in rows),
        filter_top_share=_median(tops), filter_true_probability=_median(trues),
    )  # fmt: skip


def config_summaries(result: TaskResult) -> list[ConfigSummary]:
    """The oracle, the controllers and each agent configuration of ``result``, in that order."""
    out = [summarize(d.configuration, d.kind, [d]) for d in result.designs if d.kind != "agent"]
    agents = result.of("agent")
    for config in dict.fromkeys(d.configuration for d in agents):
        out.append(summarize(config, "agent", [d for d in agents if d.configuration == config]))
    return out


# ----------------------------------------------------------------------------- across tasks
@dataclass(frozen=True)
class DesignAcross:
    """One design across the tasks: rliable's statistics of the bounded gaps of its kept runs
    (None when no run is left), the tasks and seeds used, the missing runs left out, and how
    many of the table's runs each rule of the bounded gap scored (``rules``: ``"gap"``,
    ``"diverged"``, ...)."""

    configuration: str
    aggregate: SuiteAggregate | None
    tasks: tuple[str, ...]
    seeds: tuple[int, ...]
    left_out: tuple[str, ...]
    rules: dict[str, int] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """Plain JSON types (the aggregate as its ``to_dict``)."""
        out = asdict(self)
        out["aggregate"] = None if self.aggregate is None else self.aggregate.to_dict()
        return out


def _table(
    cells: dict[str, dict[int, DesignScore]],
) -> tuple[np.ndarray | None, tuple[str, ...], tuple[int, ...], tuple[str, ...], dict[str, int]]:
    """The (seeds, tasks) table of the bounded gaps of ``cells`` (task -> seed -> run): every
    task with a kept run, the seeds kept on all of them; what is left out (missing runs only)
    and the count of each rule in the table."""
    left = [f"{task}: no kept run" for task, rows in cells.items() if not rows]
    tasks = tuple(task for task, rows in cells.items() if rows)
    if not tasks:
        return None, (), (), tuple(left), {}
    seeds = sorted(set.intersection(*(set(cells[t]) for t in tasks)))
    for s in sorted(set().union(*(set(cells[t]) for t in tasks)) - set(seeds)):
        lacking = [t for t in tasks if s not in cells[t]]
        left.append(f"seed {s}: not kept on {', '.join(lacking)}")
    if not seeds:
        return None, (), (), tuple(left), {}
    table = np.array([[cells[t][s].bounded_gap for t in tasks] for s in seeds], dtype=np.float64)
    rules = Counter(cells[t][s].bounded_gap_rule for t in tasks for s in seeds)
    return table, tasks, tuple(seeds), tuple(left), dict(sorted(rules.items()))


def across_tasks(results: Sequence[TaskResult], configurations: Sequence[str],
                 resamples: int = AGGREGATE_RESAMPLES) -> list[DesignAcross]:  # fmt: skip
    """Per design (the controllers, then ``configurations``), rliable's aggregate of the bounded
    gaps of its kept runs across ``results``' tasks (every kept run counts; see the module)."""
    out = []
    for config in (*CONTROLLERS, *configurations):
        cells = {r.env_id: {(-1 if d.seed is None else d.seed): d for d in r.designs
                            if d.configuration == config} for r in results}  # fmt: skip
        table, tasks, seeds, left, rules = _table(cells)
        agg = None if table is None else aggregate_gaps(table, resamples)
        out.append(DesignAcross(config, agg, tasks, tuple(s for s in seeds if s >= 0), left,
                                rules))  # fmt: skip
    return out


# ----------------------------------------------------------------------------- sentences
def gap_text(gap: float | None) -> str:
    """A gap in percent as the report writes it (``+3.2%``), or ``no gap``."""
    return "no gap" if gap is None else f"{gap:+.1f}%"


def bounded_text(s: ConfigSummary) -> str:
    """The bounded gap of design ``s`` as the report writes it, with the rules other than the
    gap at equal risk that gave it: ``+100.0% (diverged)`` for a controller, ``+4.0% (median
    of 5 seeds; 1 of 5 diverged)`` for an agent configuration."""
    others = Counter(rule for rule in s.bounded_gap_rules if rule != "gap")
    text = f"{s.bounded_gap:+.1f}%"
    if s.kind == "agent":
        notes = [f"median of {s.seeds} seed(s)"]
        if others:
            notes.append(", ".join(f"{n} of {s.seeds} {rule}" for rule, n in others.items()))
        return f"{text} ({'; '.join(notes)})"
    return f"{text} ({', '.join(others)})" if others else text


def price_text(s: ConfigSummary, oracle: ConfigSummary) -> str:
    """The price of the hidden mode of design ``s`` in words: its gap to the oracle's curve
    (:func:`gap_text`); without one, why, against the oracle at the task's xi: diverged
    episodes, or both costlier and riskier than the oracle (the cost ratio), or outside the
    curve's range (riskier or safer than every efficient level) at a lower cost."""
    if s.gap is not None:
        return gap_text(s.gap)
    if s.diverged > 0:
        return "no gap: episodes diverged"
    where = f"violation {s.violation:.3f} against {oracle.violation:.3f}"
    if s.cost_mean >= oracle.cost_mean and s.violation >= oracle.violation:
        ratio = s.cost_mean / oracle.cost_mean if oracle.cost_mean > 0 else float("inf")
        return f"no gap: costlier and riskier than the oracle (cost x{ratio:.2f}, {where})"
    side = "riskier" if s.violation > oracle.violation else "safer"
    return f"no gap: {side} than the oracle's curve reaches ({where})"


def bounded_designs(summaries: Sequence[ConfigSummary]) -> tuple[list[str], list[str]]:
    """The designs other than the oracle that kept every evaluation episode bounded (agents:
    on every kept seed), and those that did not."""
    designs = [s for s in summaries if s.kind != "oracle" and s.seeds > 0]
    return ([s.configuration for s in designs if s.bounded],
            [s.configuration for s in designs if not s.bounded])  # fmt: skip


def _names(names: Sequence[str]) -> str:
    names = list(names)
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _diverged(s: ConfigSummary) -> str:
    if s.kind == "agent":
        return (f"{s.configuration} on {s.seeds - s.bounded_seeds} of {s.seeds} seed(s), "
                f"median {s.diverged:g} of {s.episodes} episodes")  # fmt: skip
    return f"{s.configuration} in {s.diverged:g} of {s.episodes} episodes"


def _price(s: ConfigSummary, oracle: ConfigSummary) -> str:
    """A design's price in the sentence of prices: its gap at equal risk (an agent's: the
    median over the seeds that have one), and its bounded gap where that says something else
    (some seed has no gap, or the gap is clipped)."""
    text = f"{s.configuration} {price_text(s, oracle)}"
    if s.kind == "agent" and s.gap is not None:
        text += f" (median of {s.gap_seeds} of {s.seeds} seeds)"
    if s.gap is None or s.gap_seeds < s.seeds or s.bounded_gap != s.gap:
        text += f", bounded gap {bounded_text(s)}"
    return text


def task_sentences(env_id: str, summaries: Sequence[ConfigSummary]) -> list[str]:
    """The conclusions on one task, from its :func:`config_summaries`: which designs kept every
    episode bounded, the price of the hidden mode of each design (the gap to the oracle's curve
    at equal risk where there is one, and the bounded gap where some run has none), and the
    bounded design with the smallest bounded gap."""
    by = {s.configuration: s for s in summaries}
    oracle = next(s for s in summaries if s.kind == "oracle")
    bounded, unbounded = bounded_designs(summaries)
    lines = []
    if not bounded:
        lines.append(f"No design kept every episode bounded on {env_id} with the mode hidden "
                     f"(diverged: {'; '.join(_diverged(by[c]) for c in unbounded)}); the oracle "
                     f"diverged in {oracle.diverged:g} of {oracle.episodes}.")  # fmt: skip
    else:
        text = (f"On {env_id}, {_names(bounded)} kept every one of the {oracle.episodes} "
                "evaluation episodes bounded" + (" (agents: on every seed)" if any(
                    by[c].kind == "agent" for c in bounded) else ""))  # fmt: skip
        if unbounded:
            text += f"; diverged: {'; '.join(_diverged(by[c]) for c in unbounded)}"
        lines.append(text + ".")
    priced = [s for s in summaries if s.kind != "oracle" and s.seeds > 0]
    lines.append("The price of not seeing the mode, the cost above the oracle's curve at equal "
                 f"risk: {'; '.join(_price(s, oracle) for s in priced)}.")  # fmt: skip
    if bounded:
        best = min((by[c] for c in bounded), key=lambda s: s.bounded_gap)
        lines.append(f"The cheapest design that kept every episode bounded, by its bounded gap: "
                     f"{best.configuration} ({bounded_text(best)}; at equal risk: "
                     f"{price_text(best, oracle)}).")  # fmt: skip
    return lines


def unbounded_tasks(per_task: Mapping[str, Sequence[ConfigSummary]]) -> list[str]:
    """The tasks where no design (controller or agent configuration) kept every episode
    bounded."""
    return [task for task, s in per_task.items() if not bounded_designs(s)[0]]


def _best_line(task: str, summaries: Sequence[ConfigSummary]) -> str | None:
    """The sentence of ``task``'s bounded design with the smallest bounded gap (None without a
    bounded design), and the prices of all of them if none has a gap at equal risk."""
    oracle = next(s for s in summaries if s.kind == "oracle")
    bounded = [s for s in summaries if s.configuration in bounded_designs(summaries)[0]]
    if not bounded:
        return None
    best = min(bounded, key=lambda s: s.bounded_gap)
    line = (f"{task}: the smallest bounded gap of a design that kept every episode bounded is "
            f"{bounded_text(best)} ({best.configuration}; at equal risk: "
            f"{price_text(best, oracle)}).")  # fmt: skip
    if all(s.gap is None for s in bounded):
        line += (" No bounded design has a gap to the oracle's curve at equal risk: "
                 + "; ".join(f"{s.configuration}: {price_text(s, oracle)}" for s in bounded)
                 + ".")  # fmt: skip
    return line


def overall_sentences(per_task: Mapping[str, Sequence[ConfigSummary]]) -> list[str]:
    """The conclusions across tasks: the tasks no design kept bounded, and per task the design
    with the smallest bounded gap among those that kept every episode bounded (with its gap at
    equal risk)."""
    lost = unbounded_tasks(per_task)
    lines = [f"No design kept every episode bounded with the mode hidden on {_names(lost)}."
             if lost else "On every task some design kept every episode bounded with the mode "
             "hidden."]  # fmt: skip
    for task, summaries in per_task.items():
        line = _best_line(task, summaries)
        if line is not None:
            lines.append(line)
    return lines
