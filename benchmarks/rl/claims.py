"""The conclusion sentences of the RL reports, written from the numbers.

A reader takes a report's sentences, not its tables; so the sentences are made here from the
same records the tables are (never typed by hand), and each says only what its numbers show:

* :func:`run_counts`: of one configuration's seeds on one task, how many are cheaper than the
  reference at equal risk (the 95% interval of the gap entirely below 0), how many costlier
  (entirely above), how many undecided, and how many have no gap (a diverged episode, riskier
  or safer than the whole curve);
* :func:`headline_sentence`: one task's conclusion in a line (which configurations are cheaper
  on every seed, on some, and how many have no gap on any seed);
* :func:`task_sentence`: one task's sentence over its configurations, each with its counts;
* :func:`across_sentence`: the sentence across tasks, from rliable's IQM of the bounded gaps
  (every run counts): a configuration "beats" the reference only where the interval of its IQM
  lies below 0, "loses" where it lies above, and is "not distinguishable" otherwise.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from benchmarks.core.stats import CurveGap

__all__ = [
    "RunCounts",
    "conclusions_section",
    "across_sentence",
    "headline_sentence",
    "run_counts",
    "task_sentence",
    "verdict",
]


@dataclass(frozen=True)
class RunCounts:
    """One configuration's seeds on one task against a reference curve (see the module)."""

    config: str
    seeds: int
    cheaper: int  # the gap's 95% interval entirely below 0
    costlier: int  # entirely above 0
    undecided: int  # the interval covers 0
    no_gap: int  # diverged, or outside the curve's range
    median_bounded: float  # the median of the seeds' bounded gaps, %

    def phrase(self) -> str:
        """``"PPO residual: 2 of 5 seeds cheaper, 1 costlier, ..."``."""
        parts = [f"{self.cheaper} of {self.seeds} seed(s) cheaper at equal risk"]
        if self.costlier:
            parts.append(f"{self.costlier} costlier")
        if self.undecided:
            parts.append(f"{self.undecided} within noise")
        if self.no_gap:
            parts.append(f"{self.no_gap} without a gap")
        return (
            f"{self.config}: "
            + ", ".join(parts)
            + f" (median bounded gap {self.median_bounded:+.1f}%)"
        )


def _median(values: Sequence[float]) -> float:
    ordered = sorted(values)
    mid = len(ordered) // 2
    return ordered[mid] if len(ordered) % 2 else 0.5 * (ordered[mid - 1] + ordered[mid])


def run_counts(config: str, gaps: Sequence[CurveGap | None], bounded: Sequence[float]) -> RunCounts:
    """:class:`RunCounts` of one configuration's seeds from their gaps at equal risk (None: no
    gap) and their bounded gaps (%)."""
    if len(gaps) != len(bounded) or not gaps:
        raise ValueError(f"{config}: {len(gaps)} gaps and {len(bounded)} bounded gaps; expected "
                         "one of each per seed, at least one seed")  # fmt: skip
    cheaper = costlier = undecided = none = 0
    for g in gaps:
        if g is None or g.relative_ci95 is None:
            none += 1
        elif g.relative_ci95[1] < 0:
            cheaper += 1
        elif g.relative_ci95[0] > 0:
            costlier += 1
        else:
            undecided += 1
    return RunCounts(config, len(gaps), cheaper, costlier, undecided, none, _median(bounded))


def task_sentence(env_id: str, reference: str, counts: Sequence[RunCounts]) -> str:
    """One task's sentence: per configuration, its seeds against ``reference``."""
    if not counts:
        return f"On {env_id}, no agent is kept."
    winners = [c.config for c in counts if c.cheaper and c.cheaper == c.seeds]
    lead = (f"every seed of {', '.join(winners)} is cheaper than the {reference} at equal risk"
            if winners else f"no configuration is cheaper than the {reference} on every seed")  # fmt: skip
    return f"On {env_id}, {lead}: " + "; ".join(c.phrase() for c in counts) + "."


def _names(configs: Sequence[str]) -> str:
    return ", ".join(configs) if configs else "none"


def headline_sentence(env_id: str, reference: str, counts: Sequence[RunCounts]) -> str:
    """One task's conclusion against ``reference`` in a line, from its configurations' counts."""
    if not counts:
        return f"On {env_id}, no agent is kept."
    every = [c.config for c in counts if c.cheaper == c.seeds]
    some = [c.config for c in counts if 0 < c.cheaper < c.seeds]
    none = [c.config for c in counts if c.no_gap == c.seeds]
    return (f"On {env_id}, cheaper than the {reference} at equal risk on every seed: "
            f"{_names(every)}; on some seeds: {_names(some)}; without a gap on any seed "
            f"(diverged, or outside the curve's range): {len(none)} of {len(counts)} "
            "configuration(s).")  # fmt: skip


def verdict(iqm_ci95: tuple[float, float]) -> str:
    """``"beats"``, ``"loses to"`` or ``"is not distinguishable from"`` the reference, by
    where the 95% interval of a (lower-is-better) IQM lies against 0."""
    lo, hi = iqm_ci95
    if hi < 0:
        return "beats"
    if lo > 0:
        return "loses to"
    return "is not distinguishable from"


def across_sentence(reference: str, rows: Sequence[tuple[str, Any]]) -> str:
    """The sentence across tasks from ``(config, SuiteAggregate of its bounded gaps)`` rows."""
    parts = []
    for config, a in rows:
        if a is None:
            parts.append(f"{config} has no run kept")
            continue
        lo, hi = a.iqm_gap_ci95
        parts.append(f"{config} {verdict((lo, hi))} it (IQM {a.iqm_gap:+.1f}%, 95% interval "
                     f"{lo:+.1f} to {hi:+.1f}, {a.runs} seeds x {a.tasks} tasks)")  # fmt: skip
    return f"Every run counted, against the {reference}: " + "; ".join(parts) + "."


def conclusions_section(sentences: Sequence[str]) -> list[str]:
    """A report's ``## Conclusions`` section (Markdown lines) of ``sentences``."""
    return ["## Conclusions", "", "Written by the report's code from the tables below "
            "(`benchmarks/rl/claims.py`).", "", *[f"- {line}" for line in sentences], ""]  # fmt: skip
