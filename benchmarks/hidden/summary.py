"""The hidden setting's numbers summed up: agent configurations over their seeds, rliable's
aggregate across tasks, and the sentences of the report, generated from the numbers.

* :func:`config_summaries`: per task and agent configuration, the median over its kept seeds of
  the mean cost, the violation frequency, the diverged episodes and the gap to the oracle's curve
  (over the seeds that have one), and how many seeds kept every episode bounded;
* :func:`across_tasks`: per design, rliable's IQM of its gaps across the tasks
  (:func:`benchmarks.core.aggregate.aggregate_gaps`), on a (seeds, tasks) table; a task where a
  kept seed has no gap is left out whole (not the seed: that would keep the lucky seeds), and of
  the other tasks the seeds kept on all of them are used;
* :func:`task_sentences`, :func:`overall_sentences`: which designs kept every episode bounded,
  the price of the hidden mode per design, and the tasks no design kept bounded.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from benchmarks.core.aggregate import AGGREGATE_RESAMPLES, SuiteAggregate, aggregate_gaps
from benchmarks.hidden.score import CONTROLLERS, DesignScore, TaskResult

__all__ = [
    "ConfigSummary",
    "DesignAcross",
    "across_tasks",
    "bounded_designs",
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
    kept seeds (medians over the seeds; ``gap`` over the ``gap_seeds`` seeds that have one)."""

    configuration: str
    kind: str
    seeds: int
    cost_mean: float
    violation: float
    diverged: float
    bounded_seeds: int
    gap: float | None
    gap_seeds: int
    episodes: int
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
        episodes=rows[0].episodes, filter_top_share=_median(tops),
        filter_true_probability=_median(trues),
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
    """One design across the tasks: rliable's statistics of its gaps to the oracle's curves
    (None when no task is left), the tasks and seeds used, and what was left out."""

    configuration: str
    aggregate: SuiteAggregate | None
    tasks: tuple[str, ...]
    seeds: tuple[int, ...]
    left_out: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["aggregate"] = None if self.aggregate is None else self.aggregate.to_dict()
        return out


def _table(
    cells: dict[str, dict[int, DesignScore]],
) -> tuple[np.ndarray | None, tuple, tuple, tuple]:
    tasks, left = [], []
    for task, rows in cells.items():
        if not rows:
            left.append(f"{task}: no kept run")
            continue
        bad = [f"seed {s}: {r.gap_reason or 'no gap'}" if r.seed is not None
               else (r.gap_reason or "no gap") for s, r in sorted(rows.items()) if r.gap is None]  # fmt: skip
        if bad:
            left.append(f"{task}: " + "; ".join(bad))
        else:
            tasks.append(task)
    seeds = sorted(set.intersection(*(set(cells[t]) for t in tasks))) if tasks else []
    extra = sorted(set().union(*(set(cells[t]) for t in tasks)) - set(seeds)) if tasks else []
    if extra:
        left.append(f"seed(s) {', '.join(map(str, extra))}: not kept on every task used")
    if not seeds:
        return None, (), (), tuple(left)
    table = np.array([[cells[t][s].gap for t in tasks] for s in seeds], dtype=np.float64)
    return table, tuple(tasks), tuple(seeds), tuple(left)


def across_tasks(results: Sequence[TaskResult], configurations: Sequence[str],
                 resamples: int = AGGREGATE_RESAMPLES) -> list[DesignAcross]:  # fmt: skip
    """Per design (the controllers, then ``configurations``), rliable's aggregate of its gaps
    across ``results``' tasks (see the module for the rule of the cells without a gap)."""
    out = []
    for config in (*CONTROLLERS, *configurations):
        cells = {r.env_id: {(-1 if d.seed is None else d.seed): d for d in r.designs
                            if d.configuration == config} for r in results}  # fmt: skip
        table, tasks, seeds, left = _table(cells)
        agg = None if table is None else aggregate_gaps(table, resamples)
        out.append(DesignAcross(config, agg, tasks, tuple(s for s in seeds if s >= 0), left))
    return out


# ----------------------------------------------------------------------------- sentences
def gap_text(gap: float | None) -> str:
    """A gap in percent as the report writes it (``+3.2%``), or ``no gap``."""
    return "no gap" if gap is None else f"{gap:+.1f}%"


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


def task_sentences(env_id: str, summaries: Sequence[ConfigSummary]) -> list[str]:
    """The conclusions on one task, from its :func:`config_summaries`: which designs kept every
    episode bounded, the price of the hidden mode (the gap to the oracle's curve at equal risk)
    of each design, and the cheapest bounded design."""
    by = {s.configuration: s for s in summaries}
    oracle = next(s for s in summaries if s.kind == "oracle")
    bounded, unbounded = bounded_designs(summaries)
    lines = []
    episodes = oracle.episodes

    def diverged(s: ConfigSummary) -> str:
        if s.kind == "agent":
            return (f"{s.configuration} on {s.seeds - s.bounded_seeds} of {s.seeds} seed(s), "
                    f"median {s.diverged:g} of {s.episodes} episodes")  # fmt: skip
        return f"{s.configuration} in {s.diverged:g} of {s.episodes} episodes"

    if not bounded:
        lines.append(f"No design kept every episode bounded on {env_id} with the mode hidden "
                     f"(diverged: {'; '.join(diverged(by[c]) for c in unbounded)}); the oracle "
                     f"diverged in {oracle.diverged:g} of {episodes}.")  # fmt: skip
    else:
        text = (f"On {env_id}, {_names(bounded)} kept every one of the {episodes} evaluation "
                "episodes bounded" + (" (agents: on every seed)" if any(
                    by[c].kind == "agent" for c in bounded) else ""))  # fmt: skip
        if unbounded:
            text += f"; diverged: {'; '.join(diverged(by[c]) for c in unbounded)}"
        lines.append(text + ".")
    priced = [s for s in summaries if s.kind != "oracle" and s.seeds > 0]
    parts = []
    for s in priced:
        seeds = f" (median of {s.gap_seeds} of {s.seeds} seeds)" if s.kind == "agent" else ""
        parts.append(f"{s.configuration} {price_text(s, oracle)}"
                     f"{seeds if s.gap is not None else ''}")  # fmt: skip
    lines.append("The price of not seeing the mode, the cost above the oracle's curve at equal "
                 f"risk: {'; '.join(parts)}.")  # fmt: skip
    cheapest = [by[c] for c in bounded if by[c].gap is not None]
    if cheapest:
        best = min(cheapest, key=lambda s: float(s.gap))  # type: ignore[arg-type]
        lines.append(f"The cheapest design that kept every episode bounded, at equal risk: "
                     f"{best.configuration} ({gap_text(best.gap)}).")  # fmt: skip
    return lines


def unbounded_tasks(per_task: Mapping[str, Sequence[ConfigSummary]]) -> list[str]:
    """The tasks where no design (controller or agent configuration) kept every episode
    bounded."""
    return [task for task, s in per_task.items() if not bounded_designs(s)[0]]


def overall_sentences(per_task: Mapping[str, Sequence[ConfigSummary]]) -> list[str]:
    """The conclusions across tasks: the tasks no design kept bounded, and per task the design
    with the smallest price among those that kept every episode bounded."""
    lost = unbounded_tasks(per_task)
    lines = [f"No design kept every episode bounded with the mode hidden on {_names(lost)}."
             if lost else "On every task some design kept every episode bounded with the mode "
             "hidden."]  # fmt: skip
    for task, summaries in per_task.items():
        oracle = next(s for s in summaries if s.kind == "oracle")
        bounded = [s for s in summaries if s.configuration in bounded_designs(summaries)[0]]
        priced = [s for s in bounded if s.gap is not None]
        if priced:
            best = min(priced, key=lambda s: float(s.gap))  # type: ignore[arg-type]
            lines.append(f"{task}: the smallest price of a bounded design is "
                         f"{gap_text(best.gap)} ({best.configuration}).")  # fmt: skip
        elif bounded:
            lines.append(f"{task}: no bounded design has a gap to the oracle's curve; "
                         + "; ".join(f"{s.configuration}: {price_text(s, oracle)}"
                                     for s in bounded) + ".")  # fmt: skip
    return lines
